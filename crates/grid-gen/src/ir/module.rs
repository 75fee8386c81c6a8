//! The IR module: the one value every backend reads. [`lower`] runs the chosen kernels'
//! algorithms over a model into graphs, freezes each (dead nodes removed, ids renumbered)
//! and validates it; the result carries the robot's metadata and the gravity it was
//! lowered with, so nothing downstream needs the [`Model`].

use super::dynamics::Dynamics;
use super::graph::{Buffer, Graph, Id, Input, Node, Op};
use super::kernel::{Gradient, KernelKind, Shape, Solve};
use super::validate::{validate, ValidationError};
use crate::model::{CoordIndex, QIndex};
use crate::model::{JointType, Model};

/// Default node limit of one kernel's graph: about 1 GB while lowering, and far beyond
/// what any backend compiles in reasonable time (Atlas's `fd_grad` has 0.2 million).
pub const DEFAULT_MAX_NODES: usize = 10_000_000;

/// How to lower.
#[derive(Clone, Debug, PartialEq)]
pub struct LowerOptions {
    /// Fold constants, share identical subexpressions and snap model constants within
    /// 1e-15 of 0 and ±1 (see `ir::spatial::SNAP`). Off: the algorithm as a general
    /// library runs it, for the "before" op counts.
    pub fold: bool,
    /// Build gradient columns only where the tree says they can be nonzero. Off: every
    /// column, as a dense implementation computes them.
    pub sparse: bool,
    /// Which kernels, emitted in [`KernelKind::ALL`] order whatever the order here.
    pub kernels: Vec<KernelKind>,
    /// Most nodes one kernel's graph may have; past it lowering stops with
    /// [`LowerError::TooLarge`] instead of exhausting memory.
    pub max_nodes: usize,
    /// The RNEA gradient's formulation (`rnea_grad`, `fd_grad`).
    pub gradient: Gradient,
    /// How `fd_grad` gets q̈ and applies M⁻¹, and how `minv` forms it.
    pub solve: Solve,
    /// Which kernels call other kernels of their module ([`Call`]).
    pub calls: Calls,
}

/// Which kernels call other kernels of their module instead of holding their work
/// ([`Call`]): less code to compile, and less sharing between the parts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Calls {
    /// Where calling costs no speed: a step kernel calls its contact kernel. And where a
    /// module is too large to load in 30 s whole (its `contact_fd_grad` has at least
    /// [`CALLS_RNEA_GRAD_MIN_OPS`] operations: a humanoid on its feet), what
    /// [`Calls::RneaGrad`] does, for a few per cent on `fd_grad`.
    #[default]
    Auto,
    /// Also `fd_grad` calls `fd` and `rnea_grad`, and `contact_fd_grad` `contact_fd` and
    /// `rnea_grad`, where they factorise M ([`Solve::Ltdl`] or [`Solve::Crba`]): a
    /// humanoid's library loaded in 30 s instead of 42 s (2026-11-29), with its `fd_grad`
    /// 1.12x to 1.14x and its contact gradients 1.08x to 1.11x slower (2026-12-01; the
    /// book, Compile time).
    All,
    /// `fd_grad` and `contact_fd_grad` compute q̈ (and λ) themselves and call `rnea_grad`
    /// at them, where [`Calls::All`] would call: their work before the call and after it
    /// share their values, and they read the transforms, velocities and composite inertias
    /// that `rnea_grad`'s first parts compute ([`Call::shared`]): the humanoid's library
    /// loads in 0.57x to 0.81x the time of [`Calls::Auto`]'s, its `fd_grad` 0.97x to 1.06x
    /// the time, `contact_fd_grad` and `step_grad` 1.00x to 1.02x (2026-12-01; the book,
    /// Compile time).
    #[cfg_attr(feature = "clap", value(name = "rnea_grad"))]
    RneaGrad,
}

impl Calls {
    pub fn name(self) -> &'static str {
        match self {
            Calls::Auto => "auto",
            Calls::All => "all",
            Calls::RneaGrad => "rnea_grad",
        }
    }

    pub fn parse(name: &str) -> Option<Calls> {
        [Calls::Auto, Calls::All, Calls::RneaGrad].into_iter().find(|c| c.name() == name)
    }
}

impl Default for LowerOptions {
    fn default() -> Self {
        LowerOptions {
            fold: true,
            sparse: true,
            kernels: KernelKind::ALL.to_vec(),
            max_nodes: DEFAULT_MAX_NODES,
            gradient: Gradient::Auto,
            solve: Solve::Auto,
            calls: Calls::Auto,
        }
    }
}

impl LowerOptions {
    /// The general dense algorithm: no folding, no sharing, every gradient column.
    pub fn general() -> Self {
        LowerOptions {
            fold: false,
            sparse: false,
            gradient: Gradient::Columns,
            solve: Solve::Minv,
            ..LowerOptions::default()
        }
    }
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LowerError {
    #[error("gravity must be finite, got {0:?}")]
    Gravity([f64; 3]),
    #[error(
        "robot `{robot}` ({nv} joints): kernel `{kernel}` needs more than {limit} IR nodes (the limit); \
         its code would be too large to compile. Generate fewer kernels, or a model with fewer joints"
    )]
    TooLarge { robot: String, nv: usize, kernel: KernelKind, limit: usize },
    #[error("robot `{robot}`: a constant of the dynamics overflows f64 ({value}); check the URDF for huge masses, inertias or lengths")]
    NotFinite { robot: String, value: f64 },
    #[error("robot `{robot}`: kernel `{kernel}` needs M⁻¹, and M is singular (joint `{joint}` moves no inertia)")]
    Singular { robot: String, kernel: KernelKind, joint: String },
    #[error("internal error: kernel `{kernel}` failed IR validation: {error}")]
    Invalid { kernel: KernelKind, error: ValidationError },
}

/// What the backends need to know about the robot.
#[derive(Clone, Debug, PartialEq)]
pub struct Robot {
    /// The URDF's robot name, verbatim (backends escape it).
    pub name: String,
    /// The URDF's file name (see [`Model::source`]).
    pub source: String,
    /// Movable joints in model order, one per coordinate (coupled mimic joints have none).
    pub joint_names: Vec<String>,
    pub joint_types: Vec<JointType>,
    /// Parent joint of each joint, `None` for children of the fixed root.
    pub parents: Vec<Option<usize>>,
    /// `<limit lower upper>` of each joint, when given (the fixed-point range analysis
    /// bounds prismatic positions with it).
    pub limits: Vec<Option<(f64, f64)>>,
    /// `<limit velocity>` of each joint, when given and positive.
    pub velocity_limits: Vec<Option<f64>>,
    /// What the scene fixes: q̇ = 0, the gradient entries computed.
    pub specialisation: crate::model::Specialisation,
    /// Coupled mimic joints (`--mimic coupled`), which have no coordinate.
    pub coupled: Vec<CoupledJoint>,
    /// A floating base: joints 0..6 are the free-flyer and q has nv + 1 entries
    /// (`[x, y, z, qx, qy, qz, qw, …]`, see [`crate::model::Model::floating`]).
    pub floating: bool,
    /// Spherical joints (see [`crate::model::Model::spherical`]).
    pub spherical: Vec<SphericalJoint>,
    /// The coordinate whose position each entry of q holds; `None` for the floating
    /// base's pose and the quaternions.
    pub q_coordinates: Vec<Option<usize>>,
    /// The frames the frame kernels compute, in output order (link names).
    pub frames: Vec<String>,
    /// The reference frame of the frame kernels' Jacobian, velocity and acceleration.
    pub reference: crate::model::ReferenceFrame,
    /// The actuated coordinates, the entries of the step kernels' τ.
    pub actuated: Vec<usize>,
    /// The joints (Pinocchio's names) whose bodies take `fext`, in its order.
    pub fext: Vec<String>,
    /// The contacts, in λ's order.
    pub contacts: Vec<Contact>,
    /// The `<origin rpy>` angles the scene's `round_angles` read as multiples of π/2.
    pub rounded_angles: Option<crate::model::RoundedAngles>,
    /// Per coordinate, a lower bound on M's LTDL pivot over all configurations
    /// ([`Model::pivot_floor`]; empty with coupled mimic joints): what `fd_grad`'s chip
    /// partition divides by.
    pub pivot_floor: Vec<f64>,
    /// Per coordinate, a lower bound on 1 / M⁻¹ᵢᵢ over all configurations
    /// ([`Model::minv_floor`]; zero where none is known, empty with coupled mimic joints).
    pub minv_floor: Vec<f64>,
}

/// A coupled mimic joint: no coordinate of its own, its position
/// `multiplier · q[follows] + offset`.
#[derive(Clone, Debug, PartialEq)]
pub struct CoupledJoint {
    pub joint: String,
    /// The joint it follows.
    pub follows: String,
    pub multiplier: f64,
    pub offset: f64,
}

/// A spherical joint: its URDF name and where its quaternion `[qx, qy, qz, qw]` starts
/// in q.
#[derive(Clone, Debug, PartialEq)]
pub struct SphericalJoint {
    pub name: String,
    pub q_start: usize,
}

/// A contact at a frame: the frame's (link's) name and what force it takes.
#[derive(Clone, Debug, PartialEq)]
pub struct Contact {
    pub frame: String,
    pub kind: crate::model::ContactKind,
}

impl Robot {
    pub fn of(model: &Model) -> Robot {
        // One entry per coordinate: coupled mimic joints have none.
        let joints: Vec<&crate::model::Joint> =
            model.coordinate_joints().into_iter().map(|i| model.joint(i)).collect();
        Robot {
            name: model.name.clone(),
            source: model.source.clone(),
            joint_names: joints.iter().map(|j| j.name.clone()).collect(),
            joint_types: joints.iter().map(|j| j.joint_type).collect(),
            parents: model.coordinate_parents(),
            limits: joints.iter().map(|j| j.limit).collect(),
            velocity_limits: joints.iter().map(|j| j.velocity_limit).collect(),
            specialisation: model.specialisation.clone(),
            coupled: (0..model.njoints())
                .filter_map(|i| {
                    model.coupling(i).map(|c| CoupledJoint {
                        joint: model.joints[i].name.clone(),
                        follows: model.joints[c.of].name.clone(),
                        multiplier: c.multiplier,
                        offset: c.offset,
                    })
                })
                .collect(),
            floating: model.floating,
            spherical: model
                .spherical
                .iter()
                .map(|&s| SphericalJoint {
                    name: model.joint_name(s.0).to_string(),
                    q_start: model.group_q(s).0,
                })
                .collect(),
            pivot_floor: model.pivot_floor(),
            minv_floor: model.minv_floor(),
            q_coordinates: {
                let mut at = vec![None; model.nq()];
                for k in 0..model.nv() {
                    if let Some(QIndex(i)) = model.q_index(CoordIndex(k)) {
                        at[i] = Some(k);
                    }
                }
                at
            },
            frames: model.selected_frames().map(|f| f.name.clone()).collect(),
            reference: model.specialisation.reference,
            actuated: model.actuated(),
            fext: model
                .specialisation
                .fext
                .iter()
                .map(|&b| model.joint_name(b).to_string())
                .collect(),
            contacts: model
                .specialisation
                .contacts
                .iter()
                .map(|c| Contact { frame: model.frames[c.frame].name.clone(), kind: c.kind })
                .collect(),
            rounded_angles: model.rounded_angles,
        }
    }

    /// Actuated coordinates: entries of the step kernels' τ.
    pub fn nu(&self) -> usize {
        self.actuated.len()
    }

    /// The robot's sizes.
    pub fn dims(&self) -> crate::ir::Dims {
        crate::ir::Dims {
            nq: self.nq(),
            nv: self.nv(),
            nu: self.nu(),
            nframes: self.nframes(),
            nfext: self.specialisation.fext.len(),
            nlambda: self.nlambda(),
            ncontacts: self.specialisation.active_len(),
            nbaumgarte: self.specialisation.baumgarte_len(),
            ncontact_ref: self.specialisation.contact_ref_len(),
        }
    }

    /// Entries of the contact forces λ.
    pub fn nlambda(&self) -> usize {
        self.specialisation.contacts.iter().map(|c| c.kind.dim()).sum()
    }

    /// Frames the frame kernels compute.
    pub fn nframes(&self) -> usize {
        self.frames.len()
    }

    pub fn nv(&self) -> usize {
        self.joint_names.len()
    }

    /// The joint at the top of `j`'s branch: the child of the fixed root it hangs from.
    /// Joints under different ones share no body, so M and M⁻¹ never couple them.
    pub fn root_of(&self, mut j: usize) -> usize {
        while let Some(p) = self.parents[j] {
            j = p;
        }
        j
    }

    /// Entries of q (nv, plus one for a floating base and one per spherical joint).
    pub fn nq(&self) -> usize {
        self.nv() + usize::from(self.floating) + self.spherical.len()
    }

    /// The name of q's entry `k`: its joint's, the base's `base_x` … `base_qw`, or a
    /// spherical joint's `<name>_qx` … `<name>_qw`.
    pub fn q_name(&self, k: usize) -> String {
        const BASE: [&str; 7] =
            ["base_x", "base_y", "base_z", "base_qx", "base_qy", "base_qz", "base_qw"];
        const QUATERNION: [&str; 4] = ["qx", "qy", "qz", "qw"];
        if let Some(c) = self.q_coordinates[k] {
            return self.joint_names[c].clone();
        }
        if self.floating && k < BASE.len() {
            return BASE[k].to_string();
        }
        let joint = self
            .spherical
            .iter()
            .find(|s| (s.q_start..s.q_start + 4).contains(&k))
            .expect("every q entry has an owner");
        format!("{}_{}", joint.name, QUATERNION[k - joint.q_start])
    }

    /// Entries of one input: q has nq, the step's τ nu, the others nv.
    /// Where each stabilised wrench contact's reference quaternion `[qx, qy, qz, qw]`
    /// starts in `contact_ref` (none without `baumgarte`).
    pub fn reference_quaternions(&self) -> Vec<usize> {
        let spec = &self.specialisation;
        (0..self.contacts.len())
            .filter(|&c| {
                spec.baumgarte && self.contacts[c].kind == crate::model::ContactKind::Wrench
            })
            .map(|c| spec.contact_ref_at(c) + 3)
            .collect()
    }

    pub fn input_len(&self, input: Input) -> usize {
        input.len(&self.dims())
    }
}

/// A named output of a function: the nodes holding its values (matrices row-major).
#[derive(Clone, Debug, PartialEq)]
pub struct Output {
    pub name: &'static str,
    pub shape: Shape,
    pub ids: Vec<Id>,
}

/// One frozen kernel: every node is live, ids are dense and in topological order.
#[derive(Clone, Debug, PartialEq)]
pub struct Function {
    pub kind: KernelKind,
    /// The RNEA gradient's formulation, for the kernels that hold one.
    pub gradient: Option<Gradient>,
    /// How `fd_grad` got q̈ and applied M⁻¹ (`None` for the other kernels).
    pub solve: Option<Solve>,
    /// The arguments, in order ([`KernelKind::inputs_for`]).
    pub inputs: Vec<Input>,
    /// The robot's sizes, which the inputs and outputs are measured in.
    pub dims: crate::ir::Dims,
    pub nodes: Vec<Node>,
    pub outputs: Vec<Output>,
    /// `fd_grad`'s `∂q̈/∂u = −M⁻¹ ∂c/∂u`, as its operands: the graph holds the product
    /// itself (the `Combine` stage), which every backend may run as it is; a backend may
    /// instead multiply these matrices (the Rust backend's vectorised loop). `None` where a
    /// scene selects entries.
    pub product: Option<DenseProduct>,
    /// Outputs that are the same short program run once per column (`contact_fd_grad`'s
    /// combination of `fd_grad` with the contacts' Schur complement), as its operands and
    /// steps: the graph holds every column's statements, which every backend may run as they
    /// are; a backend may instead run the program with the columns innermost (the Rust
    /// backend's vectorised loops). `None` where a scene selects entries.
    pub program: Option<ColumnProgram>,
    /// A kernel that a backend may run as other kernels of its module, called, then
    /// `rest`. The graph holds the whole kernel, which every backend may run as it is.
    pub call: Option<Box<Call>>,
}

/// What a kernel shares with other kernels of its module: the callees run in order, then
/// `rest`, the kernel's own work, whose inputs are the kernel's and then the callees'
/// outputs that it reads ([`Input::Called`]). A callee takes the kernel's inputs of the
/// same name, a step's actuated τ spread over the coordinates (`called_tau`), and what the
/// kernel does not take (`qdd`, `lambda`) from an earlier callee, or from the rest itself
/// when [`Call::ahead`] is set.
/// - `step` calls `contact_fd` and `step_grad` `contact_fd_grad`: a quarter of a
///   humanoid's library, and almost half of a quadruped's gait library (the book, Compile
///   time).
/// - With [`Calls::All`], `fd_grad` calls `fd` for q̈ and `rnea_grad` for ∂c/∂u there,
///   and keeps M's factorisation and the solves; `contact_fd_grad` calls `contact_fd` for
///   q̈ and λ and `rnea_grad` at them, and keeps J, K and the columns.
/// - With [`Calls::RneaGrad`], both compute q̈ (and λ) and call `rnea_grad` there.
///
/// The Rust backend calls the callees instead of repeating them.
#[derive(Clone, Debug, PartialEq)]
pub struct Call {
    pub callees: Vec<KernelKind>,
    pub rest: Function,
    /// Empty where the callees run first. Otherwise the rest computes the callees'
    /// arguments that the kernel does not take (its outputs `qdd`, `lambda`), and this
    /// marks, per node of the rest, the nodes those depend on: they run, then the callees,
    /// then the other nodes, which read both ([`Calls::RneaGrad`]).
    pub ahead: Vec<bool>,
    /// Where the rest calls `rnea_grad` between its parts: each node of the rest that
    /// `rnea_grad` computes too before q̈ enters (a transform, a velocity, a composite
    /// inertia), paired with the callee's node, where the rest reads it. The callee computes
    /// these first and keeps them, and the rest reads them instead of computing them again
    /// (`ir::share`). The rest's graph still holds them. Empty elsewhere.
    pub shared: Vec<(Id, Id)>,
}

/// A program over a small register file of rows, run over many columns at once: each
/// block starts its rows from `init` (one operand per row and column), runs `steps` on
/// every column alike, and stores rows into outputs.
#[derive(Clone, Debug, PartialEq)]
pub struct ColumnProgram {
    pub rows: usize,
    pub blocks: Vec<ColumnBlock>,
    /// The graph's straight-line operations that the program replaces, where a backend
    /// may run them instead when they are few (`fd_grad`'s solves: which is faster depends
    /// on the instruction cache, a backend's choice); `None` where the program is the
    /// cheaper form everywhere (the contact and step combinations).
    pub replaces: Option<usize>,
}

/// One set of columns of a [`ColumnProgram`].
#[derive(Clone, Debug, PartialEq)]
pub struct ColumnBlock {
    /// `init[row][column]`.
    pub init: Vec<Vec<Operand>>,
    pub steps: Vec<ColumnStep>,
    pub stores: Vec<ColumnStore>,
}

/// One step of a [`ColumnBlock`], the same for every column.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColumnStep {
    /// `row[dst] −= coef · row[src]`.
    Sub { dst: usize, coef: Operand, src: usize },
    /// `row[dst] *= coef`.
    Mul { dst: usize, coef: Operand },
}

impl ColumnStep {
    /// The row the step writes.
    pub fn dst(&self) -> usize {
        match *self {
            ColumnStep::Sub { dst, .. } | ColumnStep::Mul { dst, .. } => dst,
        }
    }
}

/// Row `row` of every column of a block goes to output `output` at `flat[column]`
/// (negated when `negate`).
#[derive(Clone, Debug, PartialEq)]
pub struct ColumnStore {
    pub row: usize,
    /// A name of [`Function::outputs`].
    pub output: &'static str,
    pub flat: Vec<usize>,
    pub negate: bool,
}

impl ColumnBlock {
    /// How many columns the block runs.
    pub fn columns(&self) -> usize {
        self.init.first().map_or(0, Vec::len)
    }
}

impl ColumnProgram {
    /// Every operand the program reads.
    pub fn operands(&self) -> impl Iterator<Item = Operand> + '_ {
        self.blocks.iter().flat_map(|b| {
            b.init.iter().flatten().copied().chain(b.steps.iter().map(|s| match *s {
                ColumnStep::Sub { coef, .. } | ColumnStep::Mul { coef, .. } => coef,
            }))
        })
    }

    /// The same program with each operand mapped (`None` if one cannot be).
    fn try_map(&self, f: impl Fn(Operand) -> Option<Operand>) -> Option<ColumnProgram> {
        let blocks = self
            .blocks
            .iter()
            .map(|b| {
                let init = b
                    .init
                    .iter()
                    .map(|row| row.iter().map(|&o| f(o)).collect::<Option<Vec<_>>>())
                    .collect::<Option<Vec<_>>>()?;
                let steps = b
                    .steps
                    .iter()
                    .map(|s| {
                        Some(match *s {
                            ColumnStep::Sub { dst, coef, src } => {
                                ColumnStep::Sub { dst, coef: f(coef)?, src }
                            }
                            ColumnStep::Mul { dst, coef } => {
                                ColumnStep::Mul { dst, coef: f(coef)? }
                            }
                        })
                    })
                    .collect::<Option<Vec<_>>>()?;
                Some(ColumnBlock { init, steps, stores: b.stores.clone() })
            })
            .collect::<Option<Vec<_>>>()?;
        Some(ColumnProgram { rows: self.rows, blocks, replaces: self.replaces })
    }
}

/// The operands of a dense product `out_k = −minv · dc_k` over the outputs `outputs[k]`
/// (row-major nv x nv matrices).
#[derive(Clone, Debug, PartialEq)]
pub struct DenseProduct {
    pub minv: Vec<Operand>,
    pub dc: Vec<Vec<Operand>>,
    /// The output each product is, in the order of `dc` (a name of [`Function::outputs`]).
    pub outputs: Vec<&'static str>,
}

/// One entry of a [`DenseProduct`] operand: a node's value, its negation, or a constant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Operand {
    Node(Id),
    Neg(Id),
    Const(f64),
}

/// The lowered robot: every backend's only input.
#[derive(Clone, Debug, PartialEq)]
pub struct Module {
    pub robot: Robot,
    pub gravity: [f64; 3],
    pub functions: Vec<Function>,
}

impl Function {
    /// `name(inputs) -> outputs`, as the API summaries write it (this function's outputs).
    pub fn signature(&self) -> String {
        let args: Vec<&str> = self.inputs().iter().map(|i| i.name()).collect();
        let outs: Vec<&str> = self.outputs.iter().map(|o| o.name).collect();
        let ret =
            if outs.len() == 1 { outs[0].to_string() } else { format!("({})", outs.join(", ")) };
        format!("{}({}) -> {ret}", self.kind.name(), args.join(", "))
    }

    /// Where input `which`'s entry `j` sits when the inputs after q and q̇ are packed into
    /// one `u` per state (q̈, τ or the step's actuated τ, then `fext`, then λ, then the
    /// step's run-time `dt`: the inputs' order), as the WGSL kernels read them.
    pub fn packed_u(&self, which: Input, j: usize) -> usize {
        let before: usize = self
            .inputs
            .iter()
            .take_while(|&&i| i != which)
            .filter(|i| i.buffer() == Buffer::U)
            .map(|i| i.len(&self.dims))
            .sum();
        match which.buffer() {
            Buffer::Q | Buffer::Qd => j,
            Buffer::U => before + j,
        }
    }

    /// Entries of the packed `u` ([`Self::packed_u`]) per state.
    pub fn packed_u_len(&self) -> usize {
        self.inputs.iter().filter(|i| i.buffer() == Buffer::U).map(|i| i.len(&self.dims)).sum()
    }
}

impl Module {
    pub fn function(&self, kind: KernelKind) -> Option<&Function> {
        self.functions.iter().find(|f| f.kind == kind)
    }
}

/// Lowers the requested kernels of `model`.
pub fn lower(
    model: &Model,
    gravity: [f64; 3],
    options: &LowerOptions,
) -> Result<Module, LowerError> {
    let robot = Robot::of(model);
    let mut functions: Vec<Function> = Vec::new();
    // No frames asked, no frame kernels; no step, no step kernels.
    // One kernel at a time: lowering on every core measured 10 % faster on a humanoid
    // (2.8 s against 3.1 s) but held two graphs of up to `max_nodes` at once, which a
    // 1000-link chain under 2 GiB cannot afford (cli.rs, huge_chains_stay_within_two_gib).
    let mut kinds: Vec<KernelKind> = KernelKind::ALL
        .into_iter()
        .filter(|k| options.kernels.contains(k) && k.exists_for(&model.specialisation))
        .collect();
    lowering_order(&mut kinds);
    for kind in kinds {
        let routes =
            |c: KernelKind| functions.iter().find(|f| f.kind == c).map(|f| (f.gradient, f.solve));
        let pinned = options_after_callee(model, kind, options, routes);
        match lower_function(model, gravity, kind, pinned.as_ref().unwrap_or(options)) {
            Ok(f) => functions.push(f),
            // A singular M leaves out the kernels that need M⁻¹ (the load warning says so).
            Err(LowerError::Singular { .. }) => {}
            Err(e) => return Err(e),
        }
    }
    functions.sort_by_key(|f| f.kind.position());
    if calls_rnea_grad_by_size(&functions, options) {
        let options = LowerOptions { calls: Calls::RneaGrad, ..options.clone() };
        for f in functions.iter_mut().filter(|f| {
            matches!(f.kind, KernelKind::FdGrad | KernelKind::ContactFdGrad) && f.call.is_none()
        }) {
            f.call = shared_call(model, gravity, f, &options)?.map(Box::new);
        }
    }
    super::share::share_callee_values(&mut functions);
    Ok(Module { robot, gravity, functions })
}

/// The fewest operations of a module's `contact_fd_grad` from which [`Calls::Auto`] does
/// what [`Calls::RneaGrad`] does: `fd_grad` and `contact_fd_grad` call `rnea_grad`. Such a
/// module is a humanoid's on its feet (floating Atlas on two 6-D feet: 268,497), whose
/// library took 35 to 71 s to load with both gradients whole, over the 30 s a user should
/// wait, and 0.57x to 0.81x that time with the calls (`scripts/build_cost.py`, 2026-12-01),
/// for `fd_grad` at 0.98x to 1.05x its time and the contact gradients at 1.00x to 1.02x
/// (`scripts/compare_libraries.py`; the book, Compile time). Below it (a standing HyQ's
/// 80,027, whose `contact_fd_grad` is in the README's speed table and loads within the
/// budget; every fixed base; a floating base without contacts, such as floating Atlas,
/// whose `fd_grad` is in the table too) a kernel keeps its work whole. The bound lies
/// between the two measured modules, at about their geometric mean.
pub const CALLS_RNEA_GRAD_MIN_OPS: usize = 150_000;

/// Whether [`Calls::Auto`] calls `rnea_grad` from the gradients of these functions
/// ([`CALLS_RNEA_GRAD_MIN_OPS`]).
fn calls_rnea_grad_by_size(functions: &[Function], options: &LowerOptions) -> bool {
    options.calls == Calls::Auto
        && functions.iter().any(|f| {
            f.kind == KernelKind::ContactFdGrad && f.counts().total() >= CALLS_RNEA_GRAD_MIN_OPS
        })
}

/// Lowers one kernel.
pub fn lower_function(
    model: &Model,
    gravity: [f64; 3],
    kind: KernelKind,
    options: &LowerOptions,
) -> Result<Function, LowerError> {
    if gravity.iter().any(|g| !g.is_finite()) {
        return Err(LowerError::Gravity(gravity));
    }
    if let (Some(joint), true) = (&model.singular, kind.needs_minv()) {
        return Err(LowerError::Singular {
            robot: model.name.clone(),
            kernel: kind,
            joint: joint.clone(),
        });
    }
    // Every candidate formulation is recorded and the one with the fewest nodes kept
    // (the first on a tie: columns before idsva before world; minv before ltdl before crba).
    let gradients: &[Gradient] = match options.gradient {
        Gradient::Auto if Gradient::applies_to(kind) => {
            &[Gradient::Columns, Gradient::Idsva, Gradient::World]
        }
        Gradient::Auto | Gradient::Columns => &[Gradient::Columns],
        Gradient::Idsva => &[Gradient::Idsva],
        Gradient::World => &[Gradient::World],
    };
    let depth = model.joints.iter().map(|j| j.level + 1).max().unwrap_or(0);
    let solves: &[Solve] = match options.solve {
        // `minv` by the direct recursion, or by M's factorisation where that may be faster
        // and has fewer operations; `crba` has no q̈ to take from it here.
        _ if kind == KernelKind::Minv => match options.solve {
            Solve::Auto if minv_may_factorise(depth) => &[Solve::Minv, Solve::Ltdl],
            Solve::Auto | Solve::Minv => &[Solve::Minv],
            Solve::Ltdl | Solve::Crba => &[Solve::Ltdl],
        },
        _ if !picks_solve(kind, &model.specialisation) => &[Solve::Minv],
        Solve::Auto if crba_depth(model) <= CRBA_MAX_DEPTH => {
            &[Solve::Minv, Solve::Ltdl, Solve::Crba]
        }
        Solve::Auto if depth <= LTDL_MAX_DEPTH => &[Solve::Minv, Solve::Ltdl],
        Solve::Auto | Solve::Minv => &[Solve::Minv],
        Solve::Ltdl => &[Solve::Ltdl],
        Solve::Crba => &[Solve::Crba],
    };
    let candidates: Vec<(Gradient, Solve)> =
        gradients.iter().flat_map(|&g| solves.iter().map(move |&s| (g, s))).collect();
    let record = |&(gradient, solve): &(Gradient, Solve)| {
        record(model, gravity, kind, options, gradient, solve)
    };
    // The first candidate alone: where its graph came near the node limit (a chain of
    // hundreds of links), the others follow one at a time, so that two such graphs are
    // never held at once (cli.rs, huge_chains_stay_within_two_gib); else they are recorded
    // on every core. Which is kept does not depend on timing: the fewest nodes, the first
    // candidate on a tie.
    let mut pick = Pick::default();
    let first = candidates.first().map(record).expect("at least one candidate");
    let small = matches!(&first, Ok((_, graph)) if *graph <= options.max_nodes / 4);
    pick.merge(0, first);
    let threads = if small { crate::parallel::cores() } else { 1 };
    let rest = &candidates[1..];
    let pick =
        crate::parallel::fold_in_parallel(rest, threads, pick, record, |p, i, r| p.merge(i + 1, r));
    let f = match pick {
        Pick { best: Some((_, f)), .. } => f,
        Pick { best: None, error: Some((_, e)) } => return Err(e),
        Pick { best: None, error: None } => unreachable!("at least one candidate is recorded"),
    };
    for node in &f.nodes {
        if let Op::Const(c) = node.op {
            if !c.is_finite() {
                return Err(LowerError::NotFinite { robot: model.name.clone(), value: c });
            }
        }
    }
    validate(&f, &Robot::of(model).dims())
        .map_err(|error| LowerError::Invalid { kernel: kind, error })?;
    let mut f = f;
    f.call = shared_call(model, gravity, &f, options)?.map(Box::new);
    Ok(f)
}

/// Whether `kind` records a route per [`Solve`] and keeps the one with the fewest
/// operations: the kernels that hold `fd_grad`'s graph, and a step under contacts, whose
/// graph holds `contact_fd`'s. The step's Rust code calls `contact_fd` (which picks its
/// own route), while WGSL, `eval` and `info`'s counts read the step's whole graph; until
/// 2026-11-30 that graph kept the direct M⁻¹ (the humanoid's `step`: 49,445 operations,
/// where its `contact_fd` takes 23,095 by M's factorisation).
fn picks_solve(kind: KernelKind, spec: &crate::model::Specialisation) -> bool {
    kind.holds_fd_grad() || (kind == KernelKind::Step && !spec.contacts.is_empty())
}

/// The [`Call`] of a kernel whose callees the module holds too, with the rest folded and
/// sparse (the general graphs are for counting) and no selected entries.
/// - A step kernel calls its contact kernel: with contacts, a scheme other than RK4 (whose
///   stages run at other states), and callee outputs that input indices can address.
/// - With [`Calls::All`], `fd_grad` calls `fd` and `rnea_grad`, and `contact_fd_grad`
///   `contact_fd` and `rnea_grad`; with [`Calls::RneaGrad`] both call `rnea_grad` alone;
///   where they factorise M, with q̈ by ABA ([`Solve::Ltdl`]) or from the factorisation
///   ([`Solve::Crba`]), and have no coupled mimic joints.
fn shared_call(
    model: &Model,
    gravity: [f64; 3],
    f: &Function,
    options: &LowerOptions,
) -> Result<Option<Call>, LowerError> {
    let spec = &model.specialisation;
    let kind = f.kind;
    let nv = model.nv();
    let holds = |k: &KernelKind| options.kernels.contains(k) && k.exists_for(spec);
    let common = options.fold && options.sparse && !spec.selects();
    let callees = match kind {
        KernelKind::Step | KernelKind::StepGrad => match contact_callee(model, kind, options) {
            Some(callee) => vec![callee],
            None => return Ok(None),
        },
        KernelKind::FdGrad | KernelKind::ContactFdGrad => {
            let first =
                if kind == KernelKind::FdGrad { KernelKind::Fd } else { KernelKind::ContactFd };
            let callees = match options.calls {
                Calls::Auto => return Ok(None),
                Calls::RneaGrad => vec![KernelKind::RneaGrad],
                Calls::All => vec![first, KernelKind::RneaGrad],
            };
            if !matches!(f.solve, Some(Solve::Ltdl | Solve::Crba))
                || !common
                || model.has_coupled()
                || !callees.iter().all(holds)
                || nv * nv > usize::from(u16::MAX)
            {
                return Ok(None);
            }
            callees
        }
        _ => return Ok(None),
    };
    // The rest computes the callees' arguments itself when its first callee is not `fd`
    // or `contact_fd` (the step's contact kernel, or `fd` under `Calls::All`).
    let own = callees[0] == KernelKind::RneaGrad;
    let mut d = Dynamics::new(model, gravity, true, true, options.max_nodes);
    d.called = true;
    d.own_qdd = own;
    if let Some(gradient) = f.gradient {
        d.gradient = gradient;
    }
    if let Some(solve) = f.solve {
        d.solve = solve;
    }
    let outputs = kind.record(&mut d);
    if d.g.exhausted() {
        return Err(LowerError::TooLarge {
            robot: model.name.clone(),
            nv,
            kernel: kind,
            limit: options.max_nodes,
        });
    }
    let program = d.program.take();
    let mut rest = freeze(kind, &kind.outputs_for(spec), &d.g, outputs, None, program);
    rest.inputs = kind.inputs_for(spec);
    for callee in &callees {
        rest.inputs.extend(callee.outputs().iter().filter_map(|o| Input::called(*callee, o.name)));
    }
    rest.dims = Robot::of(model).dims();
    validate(&rest, &rest.dims).map_err(|error| LowerError::Invalid { kernel: kind, error })?;
    let ahead = if own { ahead_of_call(&rest, &callees, spec) } else { Vec::new() };
    if own && ahead.is_empty() {
        return Ok(None);
    }
    Ok(Some(Call { callees, rest, ahead, shared: Vec::new() }))
}

/// Puts kernels in the order [`lower`] (and [`super::stats`]) lowers them: a module's
/// ([`KernelKind::ALL`]), but a step kernel after the contact kernel it may call, whose
/// routes it takes ([`options_after_callee`]).
pub(crate) fn lowering_order(kinds: &mut [KernelKind]) {
    let order = |k: &KernelKind| match k {
        KernelKind::Step => KernelKind::ContactFd.position(),
        KernelKind::StepGrad => KernelKind::ContactFdGrad.position(),
        _ => k.position(),
    };
    kinds.sort_by_key(|k| (order(k), k.is_step()));
}

/// `options` for a step kernel that calls its contact kernel ([`contact_callee`]), with
/// the callee's routes (`routes`: its gradient formulation and solve, where it was
/// lowered) in place of `auto`; `None` for every other kernel.
pub(crate) fn options_after_callee(
    model: &Model,
    kind: KernelKind,
    options: &LowerOptions,
    routes: impl Fn(KernelKind) -> Option<(Option<Gradient>, Option<Solve>)>,
) -> Option<LowerOptions> {
    let (gradient, solve) = routes(contact_callee(model, kind, options)?)?;
    Some(LowerOptions {
        gradient: gradient.unwrap_or(options.gradient),
        solve: solve.unwrap_or(options.solve),
        ..options.clone()
    })
}

/// The contact kernel a step kernel calls (`step` calls `contact_fd`, `step_grad`
/// `contact_fd_grad`): with contacts, a scheme other than RK4 (whose stages run at other
/// states), graphs that are folded, sparse and whole, the callee in the module, and callee
/// outputs that input indices can address. The step kernel then records the callee's
/// routes (its gradient formulation and solve; [`lower`]): its Rust code runs them, and
/// its whole graph, which the other backends read, holds the same; on the humanoid that
/// also takes `step_grad`'s lowering from nine candidates to one.
fn contact_callee(model: &Model, kind: KernelKind, options: &LowerOptions) -> Option<KernelKind> {
    let spec = &model.specialisation;
    let callee = match kind {
        KernelKind::Step => KernelKind::ContactFd,
        KernelKind::StepGrad => KernelKind::ContactFdGrad,
        _ => return None,
    };
    let nv = model.nv();
    let scheme = spec.step.map(|s| s.scheme);
    let calls = !spec.contacts.is_empty()
        && scheme.is_some_and(|s| s != crate::model::Scheme::Rk4)
        && options.fold
        && options.sparse
        && !spec.selects()
        && options.kernels.contains(&callee)
        && callee.exists_for(spec)
        && nv * nv.max(Robot::of(model).nlambda()) <= usize::from(u16::MAX);
    calls.then_some(callee)
}

/// The nodes of `rest` that the callees' arguments among its outputs depend on (what
/// runs before the call, [`Call::ahead`]); empty where one of them reads a callee's output.
fn ahead_of_call(
    rest: &Function,
    callees: &[KernelKind],
    spec: &crate::model::Specialisation,
) -> Vec<bool> {
    let takes = rest.inputs();
    let mut ahead = vec![false; rest.nodes.len()];
    for callee in callees {
        for input in callee.inputs_for(spec) {
            if takes.contains(&input) {
                continue;
            }
            let Some(o) = rest.outputs.iter().find(|o| o.name == input.name()) else {
                return Vec::new();
            };
            for id in &o.ids {
                ahead[id.0 as usize] = true;
            }
        }
    }
    crate::ir::mark_ancestors(&rest.nodes, &mut ahead, |_| false);
    let reads_callee = rest
        .nodes
        .iter()
        .zip(&ahead)
        .any(|(n, &a)| a && matches!(n.op, Op::Input(Input::Called(_), _)));
    if reads_callee {
        return Vec::new();
    }
    ahead
}

/// The most joints on one path from the root for which `fd_grad` may use [`Solve::Ltdl`].
/// Forming M and factorising it loses accuracy with cond(M), which grows with a chain's
/// length, where the direct M⁻¹ (ABA's articulated inertias) does not: measured against
/// double-double values of the same graphs on `chain_urdf(n)` (three random states, the
/// worse of ∂q̈/∂q and ∂q̈/∂q̇, relative max-abs), LTDL's error is the direct route's up
/// to 30 links (1.0e-13 both), 2.2x it at 50 (6.0e-13 against 2.7e-13) and 3.3x at 100
/// (3.0e-12), where it would also lose the comparison with Pinocchio
/// (`forward_dynamics_as_accurate_as_pinocchio_on_a_100_link_chain`).
pub const LTDL_MAX_DEPTH: usize = 50;

/// Whether `minv` may be formed by M's factorisation ([`Solve::Ltdl`]) under
/// [`Solve::Auto`] (then the route with fewer operations is kept): at most
/// [`LTDL_MAX_DEPTH`] joints deep. Measured in one process, the two routes interleaved
/// (fma copy, 2-core Intel Xeon, 2026-11-30), time per call of the factorisation's against
/// the direct recursion's: on a fixed base 0.68x to 0.74x iiwa, 0.63x to 0.67x Panda,
/// 0.62x to 0.65x HyQ, 0.55x to 0.62x Atlas (their operations 0.43x to 0.66x). On a
/// floating base every column's last solve fills every row, and the columns run as one
/// loop (`Dynamics::minv_program`): 0.82x to 0.92x UR5, 0.63x to 0.70x HyQ, 0.75x to 0.82x
/// Go2, 0.62x to 0.80x Atlas, where the operations are 0.88x to 0.95x the direct
/// recursion's; iiwa's are 1.03x, so it keeps the direct recursion (1.02x to 1.11x as a
/// loop). `scripts/solve_ab.py --routes minv,ltdl`; the book, Operations, "M⁻¹ from M's
/// factorisation".
fn minv_may_factorise(depth: usize) -> bool {
    depth <= LTDL_MAX_DEPTH
}

/// The most joints on one path from the root ([`crba_depth`]) for which `fd_grad` may take
/// q̈ from M's factorisation ([`Solve::Crba`]) instead of ABA. `M⁻¹ (τ − c)` loses accuracy with
/// cond(M), ABA does not: measured against double-double values of the same graphs (the
/// worst of 10 random states, relative max-abs), q̈'s error is ABA's on iiwa (4.4e-16),
/// 2.6x to 4x it on HyQ, Atlas and Panda (6.4e-16, 2.8e-15, 2.0e-15), 11x on a 12-link
/// chain (1.0e-14 against 9.4e-16), 20x on 15 links and 70x on 30 to 50 (1.6e-13 at 50);
/// the gradient's error grows less (Atlas ∂q̈/∂q 6.9e-14 against 1.5e-14). At 12 the
/// cost stays at 1e-14, a hundredth of the f64 tolerance.
pub const CRBA_MAX_DEPTH: usize = 12;

/// The depth [`CRBA_MAX_DEPTH`] bounds: the joints on the longest path from the root, a
/// free-flyer's six coordinates and a spherical joint's three each counted as one joint,
/// as the algorithms treat them (Pinocchio's `JointModelFreeFlyer` and
/// `JointModelSpherical`; [`Model::group`]). What `M⁻¹ (τ − c)` loses grows with the joints
/// in series, not with a base's coordinates: measured against double-double values of the
/// same graphs (`accuracy::random_states`, 20 states, seed 1, q̈'s relative max-abs
/// error, 2026-11-30), `crba` against ABA on a floating base: Atlas 2.0e-12 against
/// 3.6e-12, iiwa 6.1e-14 against 6.4e-14, UR5 8.3e-14 against 1.4e-13, Panda 1.9e-13
/// against 7.4e-14, HyQ 1.4e-14 against 1.3e-14; `chain_urdf` with a 2 kg base on a
/// floating base, 1.4x at 11 links (6.1e-14) and 2.6x at 12 (9.2e-14), as on a fixed base
/// (the gradients' errors the same to two digits). Until 2026-12-01 every coordinate
/// counted under [`Calls::All`] and [`Calls::RneaGrad`], whose calls applied only where q̈
/// was ABA's; they now apply under either factorisation ([`shared_call`]).
fn crba_depth(model: &Model) -> usize {
    let mut depth = vec![0usize; model.joints.len()];
    for (i, j) in model.joints.iter().enumerate() {
        let above = j.parent.map_or(0, |p| depth[p]);
        let member = model.group(i).is_some_and(|g| g.start != i);
        depth[i] = above + usize::from(!member);
    }
    depth.into_iter().max().unwrap_or(0)
}

/// The candidate a kernel keeps: the frozen graph with the fewest nodes (the first
/// candidate on a tie), and the first candidate's error where none recorded.
#[derive(Default)]
struct Pick {
    best: Option<(usize, Function)>,
    error: Option<(usize, LowerError)>,
}

impl Pick {
    fn merge(&mut self, i: usize, r: Result<(Function, usize), LowerError>) {
        match r {
            Ok((f, _)) => {
                let key = (f.nodes.len(), i);
                if self.best.as_ref().is_none_or(|(j, b)| key < (b.nodes.len(), *j)) {
                    self.best = Some((i, f));
                }
            }
            Err(e) => {
                if self.error.as_ref().is_none_or(|(j, _)| i < *j) {
                    self.error = Some((i, e));
                }
            }
        }
    }
}

/// Runs one kernel's algorithm with one gradient formulation and M⁻¹ route and freezes
/// its graph; with the nodes its graph held before freezing.
fn record(
    model: &Model,
    gravity: [f64; 3],
    kind: KernelKind,
    options: &LowerOptions,
    gradient: Gradient,
    solve: Solve,
) -> Result<(Function, usize), LowerError> {
    let mut d = Dynamics::new(model, gravity, options.fold, options.sparse, options.max_nodes);
    d.gradient = gradient;
    d.solve = solve;
    let mut outputs = kind.record(&mut d);
    let spec = &model.specialisation;
    if Gradient::applies_to(kind) && spec.selects() {
        // Entries the scene does not read become 0, and freezing drops the work that fed
        // only them.
        let zero = d.g.constant(0.0);
        let nv = model.nv();
        for (ids, out) in outputs.iter_mut().zip(kind.outputs()) {
            if out.shape == Shape::Matrix {
                for (k, id) in ids.iter_mut().enumerate() {
                    if !spec.keeps(k / nv, k % nv) {
                        *id = zero;
                    }
                }
            }
        }
    }
    if d.g.exhausted() {
        return Err(LowerError::TooLarge {
            robot: model.name.clone(),
            nv: model.nv(),
            kernel: kind,
            limit: options.max_nodes,
        });
    }
    let product = if spec.selects() { None } else { d.product.take() };
    let program = if spec.selects() { None } else { d.program.take() };
    let mut f = freeze(kind, &kind.outputs_for(spec), &d.g, outputs, product, program);
    f.inputs = kind.inputs_for(spec);
    f.dims = Robot::of(model).dims();
    f.gradient = Gradient::applies_to(kind).then_some(gradient);
    f.solve = match kind {
        KernelKind::Minv => (d.solve == Solve::Ltdl).then_some(Solve::Ltdl),
        _ => picks_solve(kind, spec).then_some(d.solve),
    };
    debug_assert_ne!(f.solve, Some(Solve::Auto));
    Ok((f, d.g.nodes.len()))
}

/// Keeps the nodes that reach an output, renumbered in their original order.
fn freeze(
    kind: KernelKind,
    specs: &[crate::ir::OutputSpec],
    g: &Graph,
    outputs: Vec<Vec<Id>>,
    product: Option<DenseProduct>,
    program: Option<ColumnProgram>,
) -> Function {
    let mut live = vec![false; g.nodes.len()];
    for id in outputs.iter().flatten() {
        live[id.0 as usize] = true;
    }
    crate::ir::mark_ancestors(&g.nodes, &mut live, |_| false);
    let mut new_id = vec![Id(u32::MAX); g.nodes.len()];
    let mut nodes = Vec::with_capacity(live.iter().filter(|&&l| l).count());
    for (i, node) in g.nodes.iter().enumerate() {
        if !live[i] {
            continue;
        }
        new_id[i] = Id(nodes.len() as u32);
        let m = |id: Id| new_id[id.0 as usize];
        let op = match node.op {
            Op::Add(a, b) => Op::Add(m(a), m(b)),
            Op::Sub(a, b) => Op::Sub(m(a), m(b)),
            Op::Mul(a, b) => Op::Mul(m(a), m(b)),
            Op::Div(a, b) => Op::Div(m(a), m(b)),
            Op::Neg(a) => Op::Neg(m(a)),
            Op::Sin(a) => Op::Sin(m(a)),
            Op::Cos(a) => Op::Cos(m(a)),
            Op::Sqrt(a) => Op::Sqrt(m(a)),
            op @ (Op::Input(..) | Op::Const(_)) => op,
        };
        nodes.push(Node { op, ..*node });
    }
    let outputs = specs
        .iter()
        .zip(outputs)
        .map(|(spec, ids)| Output {
            name: spec.name,
            shape: spec.shape,
            ids: ids.into_iter().map(|id| new_id[id.0 as usize]).collect(),
        })
        .collect();
    // Folding can leave an operand unread (a product with a constant folded, or a negation
    // moved out of the product): a constant keeps its value and a dead negation of a live
    // node becomes that node negated; any other dead operand gives up the descriptor.
    // A negated operand maps as its node does, negated.
    let entry = |o: Operand| -> Option<Operand> {
        let (id, negated) = match o {
            Operand::Node(id) => (id, false),
            Operand::Neg(id) => (id, true),
            Operand::Const(_) => return Some(o),
        };
        let live_id = |id: Id| Some(new_id[id.0 as usize]).filter(|n| n.0 != u32::MAX);
        let mapped = match live_id(id) {
            Some(n) => Operand::Node(n),
            None => match g.nodes[id.0 as usize].op {
                Op::Const(c) => Operand::Const(c),
                Op::Neg(x) => match g.nodes[x.0 as usize].op {
                    Op::Const(c) => Operand::Const(-c),
                    _ => Operand::Neg(live_id(x)?),
                },
                _ => return None,
            },
        };
        Some(match (mapped, negated) {
            (m, false) => m,
            (Operand::Node(n), true) => Operand::Neg(n),
            (Operand::Neg(n), true) => Operand::Node(n),
            (Operand::Const(c), true) => Operand::Const(-c),
        })
    };
    let remap =
        |ids: &[Operand]| -> Option<Vec<Operand>> { ids.iter().map(|&id| entry(id)).collect() };
    let product = product.and_then(|p| {
        let dc = p.dc.iter().map(|m| remap(m)).collect::<Option<Vec<_>>>()?;
        Some(DenseProduct { minv: remap(&p.minv)?, dc, outputs: p.outputs })
    });
    let program = program.and_then(|p| p.try_map(entry));
    let dims = crate::ir::Dims::default();
    Function {
        kind,
        inputs: kind.inputs().to_vec(),
        dims,
        nodes,
        outputs,
        gradient: None,
        solve: None,
        product,
        program,
        call: None,
    }
}

/// The doc sentence of a `minv` formed by M's factorisation ([`Solve::Ltdl`]).
const MINV_BY_LTDL: &str = "M(q)^-1 from M's sparse factorisation `M = L^T D L` (CRBA), one pair of sparse triangular solves per column of the identity.";

/// How the step kernels' docs name a folded time step, and a run-time one.
const RUNTIME_DT: (&str, &str) = ("over `DT` seconds", "over `dt` seconds (an argument)");

impl Function {
    /// The kernel's doc sentence, with how this graph gets q̈ and M⁻¹ where it has a solve,
    /// and, for a step under forces, what it holds.
    pub fn doc(&self) -> String {
        let mut doc = match (self.kind, self.solve) {
            (KernelKind::Minv, Some(_)) => MINV_BY_LTDL.to_string(),
            (_, Some(solve)) => format!("{} {}", self.kind.doc(), solve.doc()),
            (_, None) => self.kind.doc().to_string(),
        };
        if self.inputs.contains(&Input::Dt) {
            doc = doc.replace(RUNTIME_DT.0, RUNTIME_DT.1);
        }
        if self.kind.is_step() && self.dims.nfext > 0 {
            doc.push_str(" `fext` is held over the step (in the bodies' frames).");
        }
        if self.kind.is_step() && self.dims.nlambda > 0 {
            doc.push_str(" The contacts of `CONTACTS` are held rigid: qdd is `contact_fd`'s, lambda solved at each stage's state.");
        }
        doc
    }

    /// The position of the output named `name` in [`Self::outputs`].
    pub fn output_index(&self, name: &str) -> Option<usize> {
        self.outputs.iter().position(|o| o.name == name)
    }

    pub fn inputs(&self) -> &[Input] {
        &self.inputs
    }

    /// The kernel's line in an API summary ([`KernelKind::summary`], with a run-time dt).
    pub fn summary(&self) -> String {
        match self.inputs.contains(&Input::Dt) {
            true => self.kind.summary().replace(RUNTIME_DT.0, RUNTIME_DT.1),
            false => self.kind.summary().to_string(),
        }
    }

    pub fn op(&self, id: Id) -> Op {
        self.nodes[id.0 as usize].op
    }

    /// Whether a node is an operation (not a constant or an input, which backends print
    /// inline).
    pub fn is_operation(&self, id: Id) -> bool {
        !matches!(self.op(id), Op::Const(_) | Op::Input(..))
    }

    /// Interprets the function in f64: `inputs` in the order of [`Function::inputs`],
    /// each of length nv. Returns each output's values (matrices row-major). This checks
    /// the IR itself, and is the oracle every backend's output is compared with.
    pub fn eval(&self, inputs: &[&[f64]]) -> Vec<Vec<f64>> {
        self.eval_as::<f64>(inputs)
    }

    /// The graph in f32, from the f64 inputs rounded to f32, every constant rounded to
    /// f32, in node order: the operations the generated kernels' portable copy runs for
    /// `T = f32` (the `fma` copy fuses some of them).
    pub fn eval_f32(&self, inputs: &[&[f64]]) -> Vec<Vec<f32>> {
        self.eval_as::<f32>(inputs)
    }

    /// Every node's value in f64 (the graph's intermediate values, for the analyses).
    pub fn eval_nodes(&self, inputs: &[&[f64]]) -> Vec<f64> {
        self.node_values::<f64>(inputs)
    }

    /// Where an input sits in the argument list.
    pub(crate) fn input_slot(&self, which: Input) -> usize {
        self.inputs().iter().position(|&x| x == which).expect("validated input")
    }

    /// Interprets the function in any [`EvalNumber`]: f64, f32, or a wider number that a
    /// module beside the IR implements it for (the double-double numbers of the
    /// high-precision reference).
    pub fn eval_as<T: EvalNumber>(&self, inputs: &[&[f64]]) -> Vec<Vec<T>> {
        let val = self.node_values::<T>(inputs);
        self.outputs.iter().map(|o| o.ids.iter().map(|id| val[id.0 as usize]).collect()).collect()
    }

    fn node_values<T: EvalNumber>(&self, inputs: &[&[f64]]) -> Vec<T> {
        let mut val = vec![T::from_f64(0.0); self.nodes.len()];
        for (i, node) in self.nodes.iter().enumerate() {
            let v = |id: Id| val[id.0 as usize];
            val[i] = match node.op {
                Op::Input(which, j) => T::from_f64(inputs[self.input_slot(which)][j as usize]),
                Op::Const(c) => T::from_f64(c),
                Op::Add(a, b) => v(a) + v(b),
                Op::Sub(a, b) => v(a) - v(b),
                Op::Mul(a, b) => v(a) * v(b),
                Op::Div(a, b) => v(a) / v(b),
                Op::Neg(a) => -v(a),
                Op::Sin(a) => v(a).sin(),
                Op::Cos(a) => v(a).cos(),
                Op::Sqrt(a) => v(a).sqrt(),
            };
        }
        val
    }
}

/// The number types the IR interpreter runs in.
pub trait EvalNumber:
    Copy
    + core::ops::Add<Output = Self>
    + core::ops::Sub<Output = Self>
    + core::ops::Mul<Output = Self>
    + core::ops::Div<Output = Self>
    + core::ops::Neg<Output = Self>
{
    fn from_f64(x: f64) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    fn sqrt(self) -> Self;
}

impl EvalNumber for f64 {
    fn from_f64(x: f64) -> Self {
        x
    }
    fn sin(self) -> Self {
        f64::sin(self)
    }
    fn cos(self) -> Self {
        f64::cos(self)
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
}

impl EvalNumber for f32 {
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    fn sin(self) -> Self {
        f32::sin(self)
    }
    fn cos(self) -> Self {
        f32::cos(self)
    }
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
}
