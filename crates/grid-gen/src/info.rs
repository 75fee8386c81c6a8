//! The model summary behind `grid-gen info`, in a stable JSON shape (documented in the
//! book; fields are only ever added).

use serde::Serialize;

use crate::back::verilog::{
    plan, Arch, FdGradPartition, FormatChoice, NetlistStats, VerilogOptions, DEFAULT_ADDERS,
    DEFAULT_KERNELS, DEFAULT_MAX_ERROR, DEFAULT_MULTIPLIERS, DEFAULT_STAGE_DEPTH,
};
use crate::back::wgsl::{emit_with_stats, EntryMeta, WgslOptions};
use crate::ir::{self, KernelStats, Skipped};
use crate::model::JointIndex;
use crate::model::{Count, JointType, Model, DEFAULT_GRAVITY};

#[derive(Clone, Debug, Serialize)]
pub struct Mimic {
    pub joint: String,
    pub mimics: String,
    pub multiplier: f64,
    pub offset: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Sparsity {
    /// ∂v/∂q, ∂v/∂q̇, ∂a/∂q, ∂a/∂q̇ per body and joint: nonzero when the joint is an
    /// ancestor of the body or its own (GRiD's count: iiwa 28 of 49).
    pub dv_dq: Count,
    /// ∂f/∂q per body and ∂c/∂q, ∂c/∂q̇ per joint pair: nonzero when the two lie on one
    /// root-to-leaf path.
    pub dc_dq: Count,
}

/// What one RNEA-gradient formulation costs this robot, in [`Info`]: `rnea_grad`'s
/// operations after specialisation, and what it adds to `rnea`'s per (joint, ancestor or
/// self) pair, the unit the formulations' costs grow with (Singh, Russell & Wensing 2022
/// count the same way).
#[derive(Clone, Debug, Serialize)]
pub struct GradientCost {
    pub gradient: ir::Gradient,
    pub ops: usize,
    pub per_pair: f64,
}

/// A contact the dynamics kernels take a force λ at, in [`Info`].
#[derive(Clone, Debug, Serialize)]
pub struct ContactInfo {
    pub frame: String,
    #[serde(rename = "type")]
    pub kind: crate::model::ContactKind,
    /// Entries of λ: 3 for a point, 6 for a wrench.
    pub entries: usize,
}

/// One spherical joint in [`Info`].
#[derive(Clone, Debug, Serialize)]
pub struct SphericalInfo {
    pub joint: String,
    /// Where its quaternion `[qx, qy, qz, qw]` starts in q.
    pub q_index: usize,
}

/// One frame (URDF link) in [`Info`].
#[derive(Clone, Debug, Serialize)]
pub struct FrameInfo {
    pub name: String,
    /// The joint whose body carries the link (a free-flyer's or spherical joint's own name,
    /// as Pinocchio names it); `null` for the fixed root body.
    pub parent_joint: Option<String>,
    /// The link's origin in that joint's frame.
    pub translation: [f64; 3],
    /// The link's axes in that joint's frame (rows of the rotation matrix).
    pub rotation: [[f64; 3]; 3],
}

#[derive(Clone, Debug, Serialize)]
pub struct Info {
    pub robot: String,
    pub root_link: String,
    pub nv: usize,
    /// Entries of q: nv, plus one with a floating base (position and quaternion
    /// `[x, y, z, qx, qy, qz, qw]` first, Pinocchio's layout) and one per spherical joint.
    pub nq: usize,
    /// Spherical joints: each one's name and where its quaternion `[qx, qy, qz, qw]` is in q
    /// (its coordinates are `<name>_wx`, `_wy`, `_wz`, its angular velocity in its frame).
    pub spherical: Vec<SphericalInfo>,
    /// Every URDF link the model keeps, as a frame of the body that carries it.
    pub frames: Vec<FrameInfo>,
    /// The frames the frame kernels compute (`--frames`, `[frames] names`), and their
    /// reference frame.
    pub selected_frames: Vec<String>,
    pub reference_frame: crate::model::ReferenceFrame,
    /// The step the step kernels take (`--step`, `[step]`), if any; `dt` null when the kernels take it at run time.
    pub step: Option<crate::model::StepSpec>,
    /// The actuated joints: the step's τ and B's columns, in model order.
    pub actuated: Vec<String>,
    /// The joints whose bodies take an external force: `fext` of rnea, rnea_grad, fd and
    /// fd_grad, 6 entries each, in this order (empty: no `fext` input).
    pub fext: Vec<String>,
    /// The contacts whose forces λ those kernels take, in this order.
    pub contacts: Vec<ContactInfo>,
    /// The contacts are candidates: the contact kernels and the step take `active`, one 0
    /// or 1 per contact (`contact_mask`).
    pub contact_mask: bool,
    /// The contacts are stabilised as Pinocchio's Baumgarte corrector: the contact kernels
    /// and the step take `gains` and `contact_ref` (`baumgarte`).
    pub baumgarte: bool,
    /// A floating base: joints 0 to 5 are the free-flyer's velocity coordinates (linear,
    /// then angular, in the base frame).
    pub floating_base: bool,
    /// Gravity in the root frame (m/s²) the op counts and netlists were built with.
    pub gravity: [f64; 3],
    /// The scene's `round_angles`: how many `<origin rpy>` angles it read as multiples of
    /// π/2, and the largest change (absent when the scene does not round).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rounded_angles: Option<crate::model::RoundedAngles>,
    /// Movable joints in model order (depth-first pre-order, children in document order),
    /// one per coordinate.
    pub joint_names: Vec<String>,
    pub joint_types: Vec<JointType>,
    /// Index of each joint's parent joint, `null` for children of the fixed root.
    pub parents: Vec<Option<usize>>,
    /// Joint (coordinate) indices at each tree depth.
    pub levels: Vec<Vec<usize>>,
    /// Joints with a `<mimic>`: independent joints by default (as urdfdom and Pinocchio's
    /// default), coupled when `mimic_coupled`.
    pub mimic: Vec<Mimic>,
    /// `--mimic coupled`: every mimic joint whose target is movable follows it and has no
    /// coordinate, so `joint_names` (and nv) leave it out.
    pub mimic_coupled: bool,
    pub sparsity: Sparsity,
    /// The scene's `static = true`: q̇ = 0 assumed, `qd` ignored by every kernel.
    #[serde(rename = "static")]
    pub static_velocity: bool,
    /// The scene's `[gradient]` rows and columns (joint names; `null`: all), the only
    /// gradient entries computed.
    pub gradient_rows: Option<Vec<String>>,
    pub gradient_columns: Option<Vec<String>>,
    /// Operations of every generated kernel before specialisation (the general dense
    /// algorithm, as a library runs it) and after (constants folded, structural zeros and
    /// shared subexpressions removed), with the critical-path depth; with `gravity`.
    /// Each graph is built under a node limit ([`ir::STATS_MAX_NODES`]), so the summary
    /// costs bounded time and memory on any robot; kernels over it are in `ops_skipped`.
    pub ops: Vec<KernelStats>,
    /// Kernels left out of `ops`, each with the reason.
    pub ops_skipped: Vec<Skipped>,
    /// `rnea_grad` in every formulation `--gradient auto` chooses from (empty when
    /// `rnea_grad` is over the node limit).
    pub gradient_costs: Vec<GradientCost>,
    /// The Verilog netlists `--backend verilog` builds with default options (format by
    /// `--fixed auto --max-error 1e-3`, or `info --fixed`'s), in both architectures: units,
    /// registers, cycles, format and analysed error bound.
    pub verilog: Vec<NetlistStats>,
    /// Why `verilog` is empty, when it is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub verilog_skipped: Option<String>,
    /// Why `verilog` lacks `fd_grad`'s host partition (`--fd-grad-netlist host`), when it does.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub verilog_fd_grad_skipped: Option<String>,
    /// Why `verilog` lacks `fd_grad`'s chip partition (`--fd-grad-netlist chip`), when it does.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub verilog_fd_grad_chip_skipped: Option<String>,
    /// Each entry point `--backend wgsl` writes with default options (f32, both strategies):
    /// statements, functions, workgroup size and bytes, phases, scratch words.
    pub wgsl: Vec<EntryMeta>,
    /// Why `wgsl` is empty or lacks kernels, when it does.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wgsl_skipped: Option<String>,
    /// The generated Rust each counted kernel adds to a module (`--backend rust`, default
    /// options: the portable and `fma` copies), what rustc has to compile.
    pub rust_size: Vec<RustSize>,
    /// The `--calls` the sizes in [`Info::rust_size`] were generated with.
    pub calls: ir::Calls,
}

/// One kernel's generated Rust, in [`Info`]: what the module grows by with it.
#[derive(Clone, Debug, Serialize)]
pub struct RustSize {
    pub kernel: ir::KernelKind,
    pub bytes: usize,
    pub lines: usize,
    /// Whether the batch entry points (`--backend c`, Python) run this kernel on several
    /// states per call in SIMD lanes under `--batch-lanes auto`, which compiles it a second
    /// time ([`crate::back::c::lanes_pay`]).
    pub batch_lanes: bool,
    /// The kernels this one calls instead of holding their work, under [`Info::calls`]
    /// ([`ir::Call`]); its lines are its own work and the calls.
    pub calls: Vec<ir::KernelKind>,
}

/// The most operations of a specialised kernel whose general graph is over the node limit
/// that `info` still emits as Rust to size it. The humanoid's `contact_fd_grad` (279,530
/// operations, 7.9 MB of Rust with both copies) and `step_grad` add 3 s and 140 MB to its
/// `info` on this project's machine (4.1 -> 7.1 s); larger kernels are left out, so that
/// `info` stays bounded on any robot.
pub const RUST_SIZE_MAX_OPS: usize = 500_000;

/// The most operations × depth per kernel that `info` plans WGSL entry points for
/// (Atlas's `fd_grad`: 2.1e7).
pub const WGSL_STATS_MAX_WORK: usize = 50_000_000;

impl Info {
    /// The summary with default gravity and the gradient formulation picked by op count.
    pub fn new(model: &Model) -> Self {
        Info::with_options(
            model,
            DEFAULT_GRAVITY,
            ir::Gradient::Auto,
            ir::Solve::Auto,
            ir::Calls::Auto,
            DEFAULT_STAGE_DEPTH,
            FormatChoice::Auto { max_error: DEFAULT_MAX_ERROR },
        )
    }

    /// The summary of the kernels generated with this gravity, gradient formulation, solve
    /// and calls, and the Verilog netlists in this format (the pipelined ones at this stage
    /// depth).
    pub fn with_options(
        model: &Model,
        gravity: [f64; 3],
        gradient: ir::Gradient,
        solve: ir::Solve,
        calls: ir::Calls,
        stage_depth: u32,
        format: FormatChoice,
    ) -> Self {
        let coordinates = model.coordinate_joints();
        let names = |set: &Option<Vec<usize>>| {
            set.as_ref()
                .map(|v| v.iter().map(|&k| model.joint(coordinates[k]).name.clone()).collect())
        };
        Info {
            robot: model.name.clone(),
            root_link: model.root_link.clone(),
            nv: model.nv(),
            nq: model.nq(),
            floating_base: model.floating,
            rounded_angles: model.rounded_angles,
            spherical: crate::ir::Robot::of(model)
                .spherical
                .into_iter()
                .map(|s| SphericalInfo { joint: s.name, q_index: s.q_start })
                .collect(),
            frames: model
                .frames
                .iter()
                .map(|f| FrameInfo {
                    name: f.name.clone(),
                    parent_joint: f.body.map(|b| model.joint_name(b).to_string()),
                    translation: f.placement.pos,
                    rotation: f.placement.rot,
                })
                .collect(),
            selected_frames: model.selected_frames().map(|f| f.name.clone()).collect(),
            reference_frame: model.specialisation.reference,
            step: model.specialisation.step,
            actuated: model
                .actuated()
                .iter()
                .map(|&c| model.joint(model.coordinate_joints()[c]).name.clone())
                .collect(),
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
                .map(|c| ContactInfo {
                    frame: model.frames[c.frame].name.clone(),
                    kind: c.kind,
                    entries: c.kind.dim(),
                })
                .collect(),
            contact_mask: model.specialisation.contact_mask,
            baumgarte: model.specialisation.baumgarte,
            gravity,
            joint_names: model
                .coordinate_joints()
                .iter()
                .map(|&i| model.joint(i).name.clone())
                .collect(),
            joint_types: model
                .coordinate_joints()
                .iter()
                .map(|&i| model.joint(i).joint_type)
                .collect(),
            parents: model.coordinate_parents(),
            levels: model
                .levels()
                .into_iter()
                .map(|level| {
                    level
                        .into_iter()
                        .filter(|&i| model.coupling(i).is_none())
                        .map(|i| model.coordinate_of(JointIndex(i)).0)
                        .collect()
                })
                .collect(),
            mimic_coupled: model.has_coupled(),
            mimic: model
                .joints
                .iter()
                .filter_map(|j| {
                    j.mimic.as_ref().map(|(m, mult, off)| Mimic {
                        joint: j.name.clone(),
                        mimics: m.clone(),
                        multiplier: *mult,
                        offset: *off,
                    })
                })
                .collect(),
            sparsity: Sparsity { dv_dq: model.motion_sparsity(), dc_dq: model.force_sparsity() },
            static_velocity: model.specialisation.static_velocity,
            gradient_rows: names(&model.specialisation.rows),
            gradient_columns: names(&model.specialisation.columns),
            ops: Vec::new(),
            ops_skipped: Vec::new(),
            gradient_costs: Vec::new(),
            verilog: Vec::new(),
            verilog_skipped: None,
            verilog_fd_grad_skipped: None,
            verilog_fd_grad_chip_skipped: None,
            wgsl: Vec::new(),
            wgsl_skipped: None,
            rust_size: Vec::new(),
            calls,
        }
        .with_ops(ir::stats(model, gravity, gradient, solve, calls, ir::STATS_MAX_NODES))
        .with_gradient_costs(model, gravity)
        .with_verilog(model, gravity, (gradient, solve, calls), stage_depth, format)
        .with_wgsl(model, gravity, gradient, solve, calls)
        .with_rust_size(model, gravity, gradient, solve, calls)
    }

    /// The Rust each kernel `ops` counted adds to a module: the module with that kernel
    /// alone, less the module with none (the constants and helpers every module has).
    /// Kernels whose general graph is over the node limit are sized too where their
    /// specialised one has at most [`RUST_SIZE_MAX_OPS`] operations: what rustc compiles is
    /// the specialised one (a humanoid's contact step, whose general graph no one builds).
    fn with_rust_size(
        mut self,
        model: &Model,
        gravity: [f64; 3],
        gradient: ir::Gradient,
        solve: ir::Solve,
        calls: ir::Calls,
    ) -> Self {
        let kernels: Vec<ir::KernelKind> = self
            .ops
            .iter()
            .filter(|k| k.before.is_some() || k.after.total() <= RUST_SIZE_MAX_OPS)
            .map(|k| k.kernel)
            .collect();
        let lower = ir::LowerOptions {
            kernels,
            max_nodes: ir::STATS_MAX_NODES,
            gradient,
            solve,
            calls,
            ..ir::LowerOptions::default()
        };
        let Ok(module) = ir::lower(model, gravity, &lower) else { return self };
        self.calls = calls;
        let options = crate::back::rust::RustOptions::default();
        let size = |functions: Vec<ir::Function>| {
            let m = ir::Module { functions, ..module.clone() };
            crate::back::rust::emit(&m, &options)
                .ok()
                .map(|f| (f.contents.len(), f.contents.lines().count()))
        };
        let Some((base_bytes, base_lines)) = size(Vec::new()) else { return self };
        for f in &module.functions {
            if let Some((bytes, lines)) = size(vec![f.clone()]) {
                self.rust_size.push(RustSize {
                    kernel: f.kind,
                    bytes: bytes.saturating_sub(base_bytes),
                    lines: lines.saturating_sub(base_lines),
                    batch_lanes: crate::back::c::lanes_pay(f, crate::back::c::BatchLanes::Auto),
                    calls: f.call.as_ref().map_or(Vec::new(), |c| c.callees.clone()),
                });
            }
        }
        self
    }

    /// Only the kernels `ops` counted: the others are over the node limit already, and
    /// lowering them again to find out would cost the time the limit exists to bound.
    /// Kernels whose operations times depth exceed [`WGSL_STATS_MAX_WORK`] are left out too
    /// (`--backend wgsl` still writes them): set when the cooperative strategy was planned by
    /// the IR's list scheduler, whose cost grew with depth (a 400-link chain's `rnea` took
    /// 19 s); its level schedule is linear now, and the bound stays as a cap on `info`'s time.
    fn with_wgsl(
        mut self,
        model: &Model,
        gravity: [f64; 3],
        gradient: ir::Gradient,
        solve: ir::Solve,
        calls: ir::Calls,
    ) -> Self {
        // Kernels whose general graph is over the node limit are larger still.
        let (kernels, large): (Vec<&KernelStats>, Vec<&KernelStats>) =
            self.ops.iter().partition(|k| {
                k.before.is_some() && k.after.total() * k.after.depth <= WGSL_STATS_MAX_WORK
            });
        let mut left_out: Vec<String> = self
            .ops_skipped
            .iter()
            .map(|k| format!("{} (see ops_skipped)", k.kernel.name()))
            .collect();
        left_out.extend(large.iter().map(|k| {
            format!(
                "{} (operations × depth over {WGSL_STATS_MAX_WORK:e}; `--backend wgsl` writes it)",
                k.kernel.name()
            )
        }));
        if !left_out.is_empty() {
            self.wgsl_skipped = Some(left_out.join(", "));
        }
        let kernels: Vec<ir::KernelKind> = kernels.iter().map(|k| k.kernel).collect();
        if kernels.is_empty() {
            return self;
        }
        let lower = ir::LowerOptions {
            kernels,
            max_nodes: ir::STATS_MAX_NODES,
            gradient,
            solve,
            calls,
            ..ir::LowerOptions::default()
        };
        let result =
            ir::lower(model, gravity, &lower).map_err(|e| e.to_string()).and_then(|module| {
                emit_with_stats(&module, &WgslOptions::default()).map_err(|e| e.to_string())
            });
        match result {
            Ok((_, stats)) => self.wgsl = stats,
            Err(e) => self.wgsl_skipped = Some(e),
        }
        self
    }

    /// Like [`Self::with_wgsl`], only for kernels `ops` counted: one over the node limit
    /// is reported without lowering it a second time.
    fn with_verilog(
        mut self,
        model: &Model,
        gravity: [f64; 3],
        (gradient, solve, calls): (ir::Gradient, ir::Solve, ir::Calls),
        stage_depth: u32,
        format: FormatChoice,
    ) -> Self {
        if let Some(k) = self.ops_skipped.iter().find(|k| DEFAULT_KERNELS.contains(&k.kernel)) {
            self.verilog_skipped =
                Some(format!("kernel `{}` was not counted: {}", k.kernel.name(), k.reason));
            return self;
        }
        let partial =
            self.ops.iter().find(|k| k.before.is_none() && DEFAULT_KERNELS.contains(&k.kernel));
        if let Some(k) = partial {
            self.verilog_skipped = Some(format!(
                "kernel `{}`'s general graph is over the op-count limit",
                k.kernel.name()
            ));
            return self;
        }
        let lower = ir::LowerOptions {
            // minv: the sampled bound on fd_grad's host partition's M⁻¹ input; rnea: the
            // chip partition's bias forces.
            kernels: [&DEFAULT_KERNELS[..], &[ir::KernelKind::Minv, ir::KernelKind::Rnea]].concat(),
            max_nodes: ir::STATS_MAX_NODES,
            gradient,
            solve,
            calls,
            ..ir::LowerOptions::default()
        };
        let mut fd_grad_skipped = None;
        let mut chip_skipped = None;
        let result =
            ir::lower(model, gravity, &lower).map_err(|e| e.to_string()).and_then(|module| {
                let mut all = Vec::new();
                let archs = [
                    Arch::Pipelined { stage_depth },
                    Arch::Shared { multipliers: DEFAULT_MULTIPLIERS, adders: DEFAULT_ADDERS },
                ];
                for arch in archs {
                    let netlists = plan(
                        &module,
                        &VerilogOptions { arch, format, ..VerilogOptions::default() },
                    )
                    .map_err(|e| e.to_string())?;
                    all.extend(netlists.iter().map(|n| n.stats()));
                }
                // fd_grad's partitions, where a format is found (a note says why not).
                for (partition, skipped) in [
                    (FdGradPartition::Host, &mut fd_grad_skipped),
                    (FdGradPartition::Chip, &mut chip_skipped),
                ] {
                    for arch in archs {
                        let options = VerilogOptions {
                            arch,
                            format,
                            kernels: Vec::new(),
                            fd_grad: Some(partition),
                            ..VerilogOptions::default()
                        };
                        match plan(&module, &options) {
                            Ok(netlists) => all.extend(netlists.iter().map(|n| n.stats())),
                            Err(e) => {
                                *skipped = Some(e.to_string());
                                break;
                            }
                        }
                    }
                }
                Ok(all)
            });
        match result {
            Ok(v) => self.verilog = v,
            Err(e) => self.verilog_skipped = Some(e),
        }
        self.verilog_fd_grad_skipped = fd_grad_skipped;
        self.verilog_fd_grad_chip_skipped = chip_skipped;
        self
    }

    fn with_ops(mut self, stats: ir::Stats) -> Self {
        self.ops = stats.ops;
        self.ops_skipped = stats.skipped;
        self
    }

    /// `rnea_grad`'s cost in each formulation, beside `rnea`'s as `ops` counted it; left
    /// empty when `ops` has no `rnea_grad` (the model has none, or it is over the node
    /// limit) or a formulation is over the limit.
    fn with_gradient_costs(mut self, model: &Model, gravity: [f64; 3]) -> Self {
        use ir::{Gradient, KernelKind, LowerOptions};
        let total = |kind| self.ops.iter().find(|k| k.kernel == kind).map(|k| k.after.total());
        let (Some(base), Some(_)) = (total(KernelKind::Rnea), total(KernelKind::RneaGrad)) else {
            return self;
        };
        let pairs = self.sparsity.dv_dq.nonzero.max(1) as f64;
        self.gradient_costs = [Gradient::Columns, Gradient::Idsva, Gradient::World]
            .into_iter()
            .map(|gradient| {
                let options = LowerOptions {
                    kernels: vec![KernelKind::RneaGrad],
                    gradient,
                    max_nodes: ir::STATS_MAX_NODES,
                    ..LowerOptions::default()
                };
                let f = ir::lower_function(model, gravity, KernelKind::RneaGrad, &options).ok()?;
                let ops = f.counts().total();
                Some(GradientCost {
                    gradient,
                    ops,
                    per_pair: ops.saturating_sub(base) as f64 / pairs,
                })
            })
            .collect::<Option<Vec<_>>>()
            .unwrap_or_default();
        self
    }

    /// A short human-readable summary.
    pub fn to_text(&self) -> String {
        let joints = if self.nv == 1 { "joint" } else { "joints" };
        let mut s = format!(
            "robot `{}`: {} movable {joints}, root link `{}`\n",
            self.robot, self.nv, self.root_link
        );
        let [gx, gy, gz] = self.gravity;
        s.push_str(&format!("gravity: {gx}, {gy}, {gz} m/s²\n"));
        s.push_str("joints (model order):\n");
        // A free-flyer is one joint to a Pinocchio user (`root_joint`), six velocity
        // coordinates to the kernels: one line, naming both.
        let skip = if self.floating_base {
            let name = self.joint_names[0].strip_suffix("_vx").unwrap_or(&self.joint_names[0]);
            s.push_str(&format!(
                "  0-5  {name}  (free-flyer, Pinocchio's JointModelFreeFlyer; velocity coordinates {}, linear then angular in the base frame)\n",
                self.joint_names[..6].join(", ")
            ));
            6
        } else {
            0
        };
        for (i, name) in self.joint_names.iter().enumerate().skip(skip) {
            let parent = self.parents[i].map_or("root".to_string(), |p| format!("{p}"));
            s.push_str(&format!(
                "  {i:>3}  {name}  ({}, parent {parent})\n",
                self.joint_types[i].as_str()
            ));
        }
        s.push_str(&format!(
            "levels: {}\n",
            self.levels.iter().map(|l| format!("{l:?}")).collect::<Vec<_>>().join(" ")
        ));
        let d = &self.sparsity;
        s.push_str(&format!(
            "sparsity: dv/dq {} of {} nonzero, dc/dq {} of {}\n",
            d.dv_dq.nonzero, d.dv_dq.total, d.dc_dq.nonzero, d.dc_dq.total
        ));
        if self.floating_base {
            s.push_str(&format!(
                "floating base: joints 0-5 are the free-flyer (base velocity, linear then angular, in the base frame); q has nq = {} entries, [x, y, z, qx, qy, qz, qw] then joints 6.. at q[j + 1]\n",
                self.nq
            ));
        }
        if let Some(r) = &self.rounded_angles {
            s.push_str(&format!(
                "{r}: the results move by about that much, relative, from the literal file's\n"
            ));
        }
        if !self.spherical.is_empty() {
            let joints: Vec<String> = self
                .spherical
                .iter()
                .map(|s| format!("{} (q[{}..{}])", s.joint, s.q_index, s.q_index + 4))
                .collect();
            s.push_str(&format!(
                "spherical joints: {}; each a quaternion [qx, qy, qz, qw] in q and three coordinates <name>_wx, _wy, _wz; q has nq = {} entries\n",
                joints.join(", "),
                self.nq
            ));
        }
        let frames: Vec<String> = self
            .frames
            .iter()
            .map(|f| format!("{} ({})", f.name, f.parent_joint.as_deref().unwrap_or("root")))
            .collect();
        s.push_str(&format!(
            "frames (links, with the joint whose body carries them): {}\n",
            frames.join(", ")
        ));
        if !self.selected_frames.is_empty() {
            s.push_str(&format!(
                "frame kernels compute: {} (reference frame {})\n",
                self.selected_frames.join(", "),
                self.reference_frame.name()
            ));
        }
        if !self.fext.is_empty() {
            s.push_str(&format!(
                "rnea, rnea_grad, fd, fd_grad and the contact and step kernels take fext (6 per body, joint frame) on: {}\n",
                self.fext.join(", ")
            ));
        }
        if !self.contacts.is_empty() {
            let c: Vec<String> =
                self.contacts.iter().map(|c| format!("{} ({})", c.frame, c.kind.name())).collect();
            s.push_str(&format!("rnea, rnea_grad, fd, fd_grad take contact forces lambda (world axes at the frame) at: {}\n", c.join(", ")));
            if self.contact_mask {
                s.push_str("contact_fd, contact_fd_grad, step and step_grad take `active`, one 0 or 1 per contact in this order (an inactive contact has lambda = 0 and no constraint)\n");
            }
            if self.baumgarte {
                s.push_str("contact_fd, contact_fd_grad, step and step_grad take `gains` ([Kp, Kd] per contact) and `contact_ref` (a world position per contact): Pinocchio's Baumgarte corrector, each contact's acceleration driven to -Kd v - Kp (p - p_ref)\n");
            }
        }
        if let Some(step) = self.step {
            s.push_str(&format!(
                "step kernels: {} over {}; actuated ({}): {}{}{}\n",
                step.scheme.name(),
                match step.dt {
                    Some(dt) => format!("dt = {dt} s"),
                    None => "dt given at run time (their last input)".to_string(),
                },
                self.actuated.len(),
                self.actuated.join(", "),
                if self.fext.is_empty() { "" } else { "; fext held over the step" },
                if self.contacts.is_empty() {
                    ""
                } else {
                    "; the contacts held rigid (contact_fd's q̈, lambda solved)"
                },
            ));
        }
        if self.mimic_coupled {
            let coupled: Vec<String> = self
                .mimic
                .iter()
                .filter(|m| !self.joint_names.contains(&m.joint))
                .map(|m| format!("{} = {} * {} + {}", m.joint, m.multiplier, m.mimics, m.offset))
                .collect();
            s.push_str(&format!(
                "coupled mimic joints (no coordinate of their own): {}\n",
                coupled.join(", ")
            ));
        }
        if self.static_velocity {
            s.push_str("static scene: qd = 0 assumed, velocity terms compiled out, `qd` ignored\n");
        }
        if self.gradient_rows.is_some() || self.gradient_columns.is_some() {
            let show =
                |v: &Option<Vec<String>>| v.as_ref().map_or("all".to_string(), |v| v.join(", "));
            s.push_str(&format!(
                "gradient entries computed: rows {}; columns {} (the rest are 0)\n",
                show(&self.gradient_rows),
                show(&self.gradient_columns)
            ));
        }
        s.push_str(
            "operations per kernel (before -> after specialisation, before \"too big\" where the general graph is over the node limit; add/mul/div/neg/trig after; depth; the gradient formulation and fd_grad's solve picked):\n",
        );
        // Names pad to the longest (12 without frame kernels, whose names are longer).
        let w = self
            .ops
            .iter()
            .map(|k| k.kernel.name().len())
            .chain(self.verilog.iter().map(|v| v.kernel.name().len() + 5))
            .max()
            .unwrap_or(0)
            .max(12);
        for k in &self.ops {
            let a = &k.after;
            s.push_str(&format!(
                "  {:<w$} {:>8} -> {:>7}   {}/{}/{}/{}/{}   depth {}{}\n",
                k.kernel.name(),
                k.before.map_or("too big".to_string(), |b| b.total().to_string()),
                a.total(),
                a.add,
                a.mul,
                a.div,
                a.neg,
                a.trig,
                a.depth,
                k.gradient.map_or(String::new(), |g| format!("   gradient: {}", g.name()))
                    + &k.solve.map_or(String::new(), |m| format!(", solve: {}", m.name()))
            ));
        }
        for k in &self.ops_skipped {
            s.push_str(&format!("  {:<w$} not counted: {}\n", k.kernel.name(), k.reason));
        }
        if !self.rust_size.is_empty() {
            s.push_str(
                "generated Rust per kernel (what rustc compiles; the portable and fma copies):",
            );
            for r in &self.rust_size {
                s.push_str(&format!(
                    " {} {} kB, {} lines;",
                    r.kernel.name(),
                    r.bytes.div_ceil(1000),
                    r.lines
                ));
            }
            s.pop();
            s.push('\n');
            let (lanes, single): (Vec<&RustSize>, Vec<&RustSize>) =
                self.rust_size.iter().partition(|r| r.batch_lanes);
            let names = |v: Vec<&RustSize>| {
                let n: Vec<&str> = v.iter().map(|r| r.kernel.name()).collect();
                if n.is_empty() {
                    "none".to_string()
                } else {
                    n.join(", ")
                }
            };
            s.push_str(&format!(
                "batches in SIMD lanes (--batch-lanes auto; each such kernel compiled twice): {}; one state per call: {}\n",
                names(lanes),
                names(single)
            ));
            let calling: Vec<String> = self
                .rust_size
                .iter()
                .filter(|r| !r.calls.is_empty())
                .map(|r| {
                    let callees: Vec<&str> = r.calls.iter().map(|c| c.name()).collect();
                    format!("{} calls {}", r.kernel.name(), callees.join(" and "))
                })
                .collect();
            s.push_str(&format!(
                "kernels that call others instead of holding their work (--calls {}): {}\n",
                self.calls.name(),
                if calling.is_empty() { "none".to_string() } else { calling.join("; ") }
            ));
        }
        if !self.gradient_costs.is_empty() {
            let pairs = self.sparsity.dv_dq.nonzero;
            s.push_str(&format!(
                "rnea_grad by formulation (operations; beyond rnea's, per (joint, ancestor) pair, {pairs} pairs):"
            ));
            for c in &self.gradient_costs {
                s.push_str(&format!(" {} {} ({:.1})", c.gradient.name(), c.ops, c.per_pair));
            }
            s.push('\n');
        }
        if !self.verilog.is_empty() {
            s.push_str("verilog netlists (default options but --stage-depth; multipliers/adders/registers, cycles per state, latency, format, error bound; pipelined: the slowest stage's cells):\n");
        }
        for v in &self.verilog {
            let name = match v.partition {
                Some(p) => format!("fd_grad_{}", p.name()),
                None => v.kernel.name().to_string(),
            };
            s.push_str(&format!(
                "  {:<w$} {:<9} {:>5}/{:>5}/{:>5}  {:>4} per state  latency {:>4}  {}  {}{}\n",
                name,
                v.arch,
                v.multipliers,
                v.adders,
                v.registers,
                v.cycles_per_state,
                v.latency_cycles,
                v.format,
                match (v.measured_error, &v.proven_format, v.proven_error_bound) {
                    (Some(e), Some(f), Some(b)) => {
                        format!("error {e:.1e} measured (proven <= {b:.1e} at {f})")
                    }
                    (Some(e), _, _) => format!("error {e:.1e} measured (no proven format)"),
                    (None, _, _) => format!("error <= {:.1e}", v.error_bound),
                },
                match &v.stage_path {
                    Some(path) => format!("  stage {}", path.join("-")),
                    None => String::new(),
                }
            ));
        }
        if let Some(why) = &self.verilog_skipped {
            s.push_str(&format!("verilog netlists not planned: {why}\n"));
        }
        if let Some(why) = &self.verilog_fd_grad_skipped {
            s.push_str(&format!("verilog fd_grad_host not planned: {why}\n"));
        }
        if let Some(why) = &self.verilog_fd_grad_chip_skipped {
            s.push_str(&format!("verilog fd_grad_chip not planned: {why}\n"));
        }
        if !self.wgsl.is_empty() {
            s.push_str("wgsl entry points (default options, f32; statements, functions, workgroup size, workgroup bytes, phases, dispatches):\n");
        }
        let ew = self.wgsl.iter().map(|e| e.entry.len()).max().unwrap_or(0).max(20);
        for e in &self.wgsl {
            s.push_str(&format!(
                "  {:<ew$} {:>7} stmts {:>4} fns  workgroup {:>3}  {:>6} bytes  {:>4} phases  {:>2} dispatches\n",
                e.entry, e.statements, e.functions, e.workgroup_size, e.workgroup_bytes, e.phases, e.stages
            ));
        }
        if let Some(why) = &self.wgsl_skipped {
            s.push_str(&format!("wgsl entry points not planned: {why}\n"));
        }
        // Coupled ones were listed above; an independent one is worth a note.
        for m in self.mimic.iter().filter(|m| self.joint_names.contains(&m.joint)) {
            s.push_str(&format!("note: joint `{}` mimics `{}`; it is treated as an independent joint (--mimic coupled couples it)\n", m.joint, m.mimics));
        }
        s
    }
}
