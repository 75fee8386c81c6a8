//! The kernels grid-gen generates: each [`KernelKind`] owns its name, inputs, output
//! shapes and documentation, so that no other file matches on kernel names.

use super::dynamics::{transpose, Dynamics, Mat, Scalar};
use super::graph::{Id, Input};

/// A robot's sizes, which the kernels' inputs and outputs are measured in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Dims {
    /// Entries of q.
    pub nq: usize,
    /// Coordinates: entries of q̇, q̈ and τ.
    pub nv: usize,
    /// Actuated coordinates: entries of the step kernels' τ.
    pub nu: usize,
    /// Requested frames.
    pub nframes: usize,
    /// Bodies that take an external force (`fext` has 6 entries per body).
    pub nfext: usize,
    /// Entries of the contact forces λ.
    pub nlambda: usize,
    /// Entries of the contact mask `active` (one per contact; 0 without a mask).
    pub ncontacts: usize,
    /// Contacts with Baumgarte gains (every contact when the scene stabilises them, else 0).
    pub nbaumgarte: usize,
    /// Entries of `contact_ref`: 3 per point contact, 7 per wrench contact, when stabilised.
    pub ncontact_ref: usize,
}

/// What sizes WGSL's `u` per state ([`KernelKind::u_len`]), as a shader's header gives them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UPacking {
    pub nv: usize,
    /// Entries of q (a second configuration, `difference`'s q1, is packed into u).
    pub nq: usize,
    /// The step kernels' actuated τ.
    pub nu: usize,
    /// The model's force entries: 6 per fext body, then λ's.
    pub forces: usize,
    /// λ's entries alone.
    pub lambda: usize,
    /// The contact mask's entries (0 without one).
    pub active: usize,
    /// Contacts with Baumgarte gains (2 gains each).
    pub baumgarte: usize,
    /// Their references' entries (3 per point contact, 7 per wrench contact).
    pub contact_ref: usize,
    /// Whether the step kernels take `dt`.
    pub runtime_dt: bool,
}

/// The shape of a kernel output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// One value per joint.
    Vector,
    /// `nv x nv`, row-major, `[i][j] = ∂out_i/∂in_j`.
    Matrix,
    /// This many values per requested frame, frame-major.
    PerFrame(usize),
    /// A `rows x nv` matrix per requested frame, frame-major, each row-major: a Jacobian
    /// (6 rows, [linear; angular] in Pinocchio's order) or a derivative of a 3-vector.
    FrameMatrix(usize),
    /// A configuration, nq entries (the step's q⁺).
    Config,
    /// `2nv x 2nv`, row-major, rows and columns `[δq; δq̇]` (the step's A).
    StateMatrix,
    /// `2nv x nu`, row-major (the step's B).
    StateInput,
    /// `nv x 6 nfext`, row-major: a derivative with respect to `fext`.
    ByFext,
    /// `nv x nlambda`, row-major: a derivative with respect to λ.
    ByLambda,
    /// The contact forces, nlambda entries (contact by contact, 3 or 6 each).
    Lambda,
    /// `nlambda x nv`, row-major: a derivative of λ.
    LambdaBy,
    /// `nlambda x 2nv`, row-major, columns `[δq; δq̇]`: λ's derivative by the state.
    LambdaByState,
    /// `nlambda x nu`, row-major: λ's derivative by the actuated τ.
    LambdaByInput,
}

impl Shape {
    /// The dimensions for a robot of sizes `d`, outermost first (a C or NumPy user's
    /// indexing: `[nv]`, `[nv, nv]`, `[nframes, rows, nv]`, ...).
    pub fn dims(self, d: &Dims) -> Vec<usize> {
        match self {
            Shape::Vector => vec![d.nv],
            Shape::Matrix => vec![d.nv, d.nv],
            Shape::PerFrame(k) => vec![d.nframes, k],
            Shape::FrameMatrix(r) => vec![d.nframes, r, d.nv],
            Shape::Config => vec![d.nq],
            Shape::StateMatrix => vec![2 * d.nv, 2 * d.nv],
            Shape::StateInput => vec![2 * d.nv, d.nu],
            Shape::ByFext => vec![d.nv, 6 * d.nfext],
            Shape::ByLambda => vec![d.nv, d.nlambda],
            Shape::Lambda => vec![d.nlambda],
            Shape::LambdaBy => vec![d.nlambda, d.nv],
            Shape::LambdaByState => vec![d.nlambda, 2 * d.nv],
            Shape::LambdaByInput => vec![d.nlambda, d.nu],
        }
    }

    /// Number of scalars for a robot of sizes `d`.
    pub fn len(self, d: &Dims) -> usize {
        self.dims(d).iter().product()
    }

    /// The index of each dimension of entry `flat`, outermost first (`[i]`, `[i][j]` or
    /// `[frame][i]`, `[frame][row][column]`), as backends that keep the shape index it.
    pub fn index(self, flat: usize, d: &Dims) -> Vec<usize> {
        let nv = d.nv;
        match self {
            Shape::Vector | Shape::Config | Shape::Lambda => vec![flat],
            Shape::LambdaBy => vec![flat / nv.max(1), flat % nv.max(1)],
            Shape::LambdaByState => vec![flat / (2 * nv).max(1), flat % (2 * nv).max(1)],
            Shape::LambdaByInput => vec![flat / d.nu.max(1), flat % d.nu.max(1)],
            Shape::StateMatrix => vec![flat / (2 * nv), flat % (2 * nv)],
            Shape::StateInput => vec![flat / d.nu.max(1), flat % d.nu.max(1)],
            Shape::ByFext => vec![flat / (6 * d.nfext).max(1), flat % (6 * d.nfext).max(1)],
            Shape::ByLambda => vec![flat / d.nlambda.max(1), flat % d.nlambda.max(1)],
            Shape::Matrix => vec![flat / nv, flat % nv],
            Shape::PerFrame(k) => vec![flat / k, flat % k],
            Shape::FrameMatrix(r) => vec![flat / (r * nv), (flat / nv) % r, flat % nv],
        }
    }
}

/// A named output of a kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutputSpec {
    pub name: &'static str,
    pub shape: Shape,
}

/// How the IR builds the RNEA gradient (and so `fd_grad`'s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Gradient {
    /// Whichever of the three has fewer operations for this robot and kernel.
    #[default]
    Auto,
    /// One RNEA-like pass per gradient column (Carpentier & Mansard 2018): cheapest on
    /// short, branchy trees.
    Columns,
    /// IDSVA (Singh, Russell & Wensing 2022), per-joint work done once and four force
    /// vectors per (joint, ancestor) pair: cheapest on long chains.
    Idsva,
    /// IDSVA in world coordinates, as the paper writes it (and as Pinocchio's
    /// `computeRNEADerivatives` works): every joint's vectors turned into the world once, so a
    /// (joint, ancestor) pair costs six dot products and no transform; cheapest on deep,
    /// branchy trees whose joints are not axis-aligned.
    World,
}

impl Gradient {
    pub fn name(self) -> &'static str {
        match self {
            Gradient::Auto => "auto",
            Gradient::Columns => "columns",
            Gradient::Idsva => "idsva",
            Gradient::World => "world",
        }
    }

    pub fn parse(name: &str) -> Option<Gradient> {
        [Gradient::Auto, Gradient::Columns, Gradient::Idsva, Gradient::World]
            .into_iter()
            .find(|g| g.name() == name)
    }

    /// Whether a kernel's graph holds the RNEA gradient.
    pub fn applies_to(kind: KernelKind) -> bool {
        matches!(
            kind,
            KernelKind::RneaGrad
                | KernelKind::FdGrad
                | KernelKind::StepGrad
                | KernelKind::ContactFdGrad
        )
    }
}

/// How `fd_grad` gets q̈ and forms `−M⁻¹ ∂c/∂u`, and how `minv` forms M⁻¹ (`Minv`, or
/// `Ltdl` and `Crba` alike: M's factorisation solved for each column of the identity).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Solve {
    /// Whichever has fewer operations for this robot, `Ltdl` only on trees at most
    /// [`super::LTDL_MAX_DEPTH`] joints deep and `Crba` at most [`super::CRBA_MAX_DEPTH`]
    /// (see there: both trade accuracy for operations on deep chains).
    #[default]
    Auto,
    /// q̈ by ABA; the direct M⁻¹ (shared with ABA's articulated inertias), then a dense
    /// product: n² + 2n³ multiplications on a chain, what Pinocchio does.
    Minv,
    /// q̈ by ABA; M's branch-induced sparse factorisation M = Lᵀ D L and two sparse
    /// triangular solves per column (Featherstone, "Efficient factorization of the
    /// joint-space inertia matrix for branched kinematic trees", IJRR 2005): the work
    /// follows each joint's depth, so a branched tree (Atlas's limbs, HyQ's legs) pays
    /// for its limbs separately; on a chain it is the same count as `Minv`.
    Ltdl,
    /// As `Ltdl`, and q̈ too from the factorisation, `q̈ = M⁻¹ (τ − c(q, q̇, 0))` with c by
    /// RNEA (whose velocities the gradient's RNEA shares): no ABA. Fewer operations, and
    /// a q̈ that loses accuracy with cond(M) where ABA's does not.
    Crba,
}

impl Solve {
    pub fn name(self) -> &'static str {
        match self {
            Solve::Auto => "auto",
            Solve::Minv => "minv",
            Solve::Ltdl => "ltdl",
            Solve::Crba => "crba",
        }
    }

    /// How a kernel recorded with this solve gets q̈ and M⁻¹, for its doc comment.
    pub fn doc(self) -> &'static str {
        match self {
            Solve::Auto | Solve::Minv => "qdd by the articulated-body algorithm, M^-1 by the direct recursion.",
            Solve::Ltdl => "qdd by the articulated-body algorithm, M^-1 applied through M's sparse factorisation `M = L^T D L`.",
            Solve::Crba => "qdd and M^-1 both from M's sparse factorisation `M = L^T D L` (CRBA; no articulated-body pass).",
        }
    }
}

/// One generated function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum), value(rename_all = "snake_case"))]
pub enum KernelKind {
    Rnea,
    RneaGrad,
    MassMatrix,
    Minv,
    Fd,
    FdGrad,
    FramePlacement,
    FrameJacobian,
    FrameVelocity,
    FrameAcceleration,
    FrameAccelerationGrad,
    Step,
    StepGrad,
    ContactFd,
    ContactFdGrad,
    Integrate,
    // Pinocchio's names, lower-cased (`dIntegrate`), in JSON and on the command line too.
    #[serde(rename = "dintegrate")]
    #[cfg_attr(feature = "clap", value(name = "dintegrate"))]
    DIntegrate,
    Difference,
    #[serde(rename = "ddifference")]
    #[cfg_attr(feature = "clap", value(name = "ddifference"))]
    DDifference,
}

impl KernelKind {
    /// Every kernel, in the order backends emit them. The frame kernels exist only for a
    /// model with requested frames ([`KernelKind::is_frame`]), the step kernels only for one
    /// with a step ([`KernelKind::is_step`]), the contact kernels only for one with
    /// contacts ([`KernelKind::is_contact`]); the Lie-group kernels come last.
    pub const ALL: [KernelKind; 19] = [
        KernelKind::Rnea,
        KernelKind::RneaGrad,
        KernelKind::MassMatrix,
        KernelKind::Minv,
        KernelKind::Fd,
        KernelKind::FdGrad,
        KernelKind::FramePlacement,
        KernelKind::FrameJacobian,
        KernelKind::FrameVelocity,
        KernelKind::FrameAcceleration,
        KernelKind::FrameAccelerationGrad,
        KernelKind::Step,
        KernelKind::StepGrad,
        KernelKind::ContactFd,
        KernelKind::ContactFdGrad,
        KernelKind::Integrate,
        KernelKind::DIntegrate,
        KernelKind::Difference,
        KernelKind::DDifference,
    ];

    /// The dynamics kernels, those every robot has.
    pub const DYNAMICS: [KernelKind; 6] = [
        KernelKind::Rnea,
        KernelKind::RneaGrad,
        KernelKind::MassMatrix,
        KernelKind::Minv,
        KernelKind::Fd,
        KernelKind::FdGrad,
    ];

    /// The kernels a model has, in [`KernelKind::ALL`] order: the dynamics kernels, and the
    /// frame kernels when it asks for frames.
    pub fn for_model(model: &crate::model::Model) -> Vec<KernelKind> {
        KernelKind::ALL.into_iter().filter(|k| k.exists_for(&model.specialisation)).collect()
    }

    /// Whether a model so specialised has this kernel: the frame kernels need frames, the
    /// step kernels a step, the contact kernels contacts.
    pub fn exists_for(self, spec: &crate::model::Specialisation) -> bool {
        (!self.is_frame() || !spec.frames.is_empty())
            && (!self.is_step() || spec.step.is_some())
            && (!self.is_contact() || !spec.contacts.is_empty())
    }

    /// Whether the kernel solves rigid-contact dynamics (and so exists only with contacts).
    pub fn is_contact(self) -> bool {
        matches!(self, KernelKind::ContactFd | KernelKind::ContactFdGrad)
    }

    /// Whether the kernel is one of the configuration space's Lie-group operations
    /// (`integrate`, `difference` and their Jacobians), which take no dynamics.
    pub fn is_lie(self) -> bool {
        matches!(
            self,
            KernelKind::Integrate
                | KernelKind::DIntegrate
                | KernelKind::Difference
                | KernelKind::DDifference
        )
    }

    /// The kernel's place in [`Self::ALL`], the order of a module's functions.
    pub fn position(self) -> usize {
        Self::ALL.iter().position(|&k| k == self).expect("every kernel is in ALL")
    }

    /// Whether the kernel takes a discrete step (and so exists only when one is asked for).
    pub fn is_step(self) -> bool {
        matches!(self, KernelKind::Step | KernelKind::StepGrad)
    }

    /// Whether the kernel's graph holds `fd_grad`'s (and so its choice of solve).
    pub fn holds_fd_grad(self) -> bool {
        matches!(
            self,
            KernelKind::FdGrad
                | KernelKind::StepGrad
                | KernelKind::ContactFd
                | KernelKind::ContactFdGrad
        )
    }

    /// Whether the kernel computes frame quantities (and so exists only when frames are asked for).
    pub fn is_frame(self) -> bool {
        matches!(
            self,
            KernelKind::FramePlacement
                | KernelKind::FrameJacobian
                | KernelKind::FrameVelocity
                | KernelKind::FrameAcceleration
                | KernelKind::FrameAccelerationGrad
        )
    }

    /// The function's name in every backend.
    pub fn name(self) -> &'static str {
        match self {
            KernelKind::Rnea => "rnea",
            KernelKind::RneaGrad => "rnea_grad",
            KernelKind::MassMatrix => "mass_matrix",
            KernelKind::Minv => "minv",
            KernelKind::Fd => "fd",
            KernelKind::FdGrad => "fd_grad",
            KernelKind::FramePlacement => "frame_placement",
            KernelKind::FrameJacobian => "frame_jacobian",
            KernelKind::FrameVelocity => "frame_velocity",
            KernelKind::FrameAcceleration => "frame_acceleration",
            KernelKind::FrameAccelerationGrad => "frame_acceleration_grad",
            KernelKind::Step => "step",
            KernelKind::StepGrad => "step_grad",
            KernelKind::ContactFd => "contact_fd",
            KernelKind::ContactFdGrad => "contact_fd_grad",
            KernelKind::Integrate => "integrate",
            KernelKind::DIntegrate => "dintegrate",
            KernelKind::Difference => "difference",
            KernelKind::DDifference => "ddifference",
        }
    }

    pub fn parse(name: &str) -> Option<KernelKind> {
        KernelKind::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The inputs, in argument order ([`Input::len`] says their lengths).
    pub fn inputs(self) -> &'static [Input] {
        use Input::*;
        match self {
            KernelKind::Rnea | KernelKind::RneaGrad => &[Q, Qd, Qdd],
            KernelKind::MassMatrix
            | KernelKind::Minv
            | KernelKind::FramePlacement
            | KernelKind::FrameJacobian => &[Q],
            KernelKind::Fd | KernelKind::FdGrad => &[Q, Qd, Tau],
            KernelKind::FrameVelocity => &[Q, Qd],
            KernelKind::FrameAcceleration | KernelKind::FrameAccelerationGrad => &[Q, Qd, Qdd],
            KernelKind::Step | KernelKind::StepGrad => &[Q, Qd, TauActuated],
            KernelKind::ContactFd | KernelKind::ContactFdGrad => &[Q, Qd, Tau],
            KernelKind::Integrate | KernelKind::DIntegrate => &[Q, V],
            KernelKind::Difference | KernelKind::DDifference => &[Q, Q1],
        }
    }

    /// The outputs, in return order.
    pub fn outputs(self) -> &'static [OutputSpec] {
        use Shape::*;
        match self {
            KernelKind::Rnea => &[OutputSpec { name: "c", shape: Vector }],
            KernelKind::RneaGrad => &[
                OutputSpec { name: "dc_dq", shape: Matrix },
                OutputSpec { name: "dc_dqd", shape: Matrix },
            ],
            KernelKind::MassMatrix => &[OutputSpec { name: "m", shape: Matrix }],
            KernelKind::Minv => &[OutputSpec { name: "minv", shape: Matrix }],
            KernelKind::Fd => &[OutputSpec { name: "qdd", shape: Vector }],
            KernelKind::FdGrad => &[
                OutputSpec { name: "qdd", shape: Vector },
                OutputSpec { name: "dqdd_dq", shape: Matrix },
                OutputSpec { name: "dqdd_dqd", shape: Matrix },
            ],
            KernelKind::FramePlacement => &[
                OutputSpec { name: "translation", shape: PerFrame(3) },
                OutputSpec { name: "rotation", shape: PerFrame(9) },
            ],
            KernelKind::FrameJacobian => &[OutputSpec { name: "jacobian", shape: FrameMatrix(6) }],
            KernelKind::FrameVelocity => &[OutputSpec { name: "velocity", shape: PerFrame(6) }],
            KernelKind::FrameAcceleration => {
                &[OutputSpec { name: "acceleration", shape: PerFrame(3) }]
            }
            KernelKind::FrameAccelerationGrad => &[
                OutputSpec { name: "dacc_dq", shape: FrameMatrix(3) },
                OutputSpec { name: "dacc_dqd", shape: FrameMatrix(3) },
                OutputSpec { name: "dacc_dqdd", shape: FrameMatrix(3) },
            ],
            KernelKind::Step => &[
                OutputSpec { name: "q_next", shape: Config },
                OutputSpec { name: "qd_next", shape: Vector },
            ],
            KernelKind::StepGrad => &[
                OutputSpec { name: "q_next", shape: Config },
                OutputSpec { name: "qd_next", shape: Vector },
                OutputSpec { name: "a", shape: StateMatrix },
                OutputSpec { name: "b", shape: StateInput },
            ],
            KernelKind::ContactFd => &[
                OutputSpec { name: "qdd", shape: Vector },
                OutputSpec { name: "lambda", shape: Lambda },
            ],
            KernelKind::ContactFdGrad => &[
                OutputSpec { name: "qdd", shape: Vector },
                OutputSpec { name: "lambda", shape: Lambda },
                OutputSpec { name: "dqdd_dq", shape: Matrix },
                OutputSpec { name: "dqdd_dqd", shape: Matrix },
                OutputSpec { name: "dqdd_dtau", shape: Matrix },
                OutputSpec { name: "dlambda_dq", shape: LambdaBy },
                OutputSpec { name: "dlambda_dqd", shape: LambdaBy },
                OutputSpec { name: "dlambda_dtau", shape: LambdaBy },
            ],
            KernelKind::Integrate => &[OutputSpec { name: "q_next", shape: Config }],
            KernelKind::DIntegrate => &[
                OutputSpec { name: "dq", shape: Matrix },
                OutputSpec { name: "dv", shape: Matrix },
            ],
            KernelKind::Difference => &[OutputSpec { name: "v", shape: Vector }],
            KernelKind::DDifference => &[
                OutputSpec { name: "dq", shape: Matrix },
                OutputSpec { name: "dq1", shape: Matrix },
            ],
        }
    }

    /// The outputs of the kernel of a model so specialised: [`Self::outputs`], then
    /// `fd_grad`'s `dqdd_dtau` when [`crate::model::Specialisation::fd_grad_minv`] asks,
    /// then the derivatives with respect to the forces the kernel takes.
    pub fn outputs_for(self, spec: &crate::model::Specialisation) -> Vec<OutputSpec> {
        let mut out = self.outputs().to_vec();
        if self == KernelKind::FdGrad && spec.fd_grad_minv {
            out.push(OutputSpec { name: "dqdd_dtau", shape: Shape::Matrix });
        }
        let (fext, lambda) =
            (!spec.fext.is_empty() && !spec.no_fext_derivatives, !spec.contacts.is_empty());
        match self {
            KernelKind::RneaGrad => {
                out.extend(fext.then_some(OutputSpec { name: "dc_dfext", shape: Shape::ByFext }));
                out.extend(
                    lambda.then_some(OutputSpec { name: "dc_dlambda", shape: Shape::ByLambda }),
                );
            }
            KernelKind::FdGrad => {
                out.extend(fext.then_some(OutputSpec { name: "dqdd_dfext", shape: Shape::ByFext }));
                out.extend(
                    lambda.then_some(OutputSpec { name: "dqdd_dlambda", shape: Shape::ByLambda }),
                );
            }
            // The step's contact forces at the knot's state (its first stage under RK4).
            KernelKind::Step if lambda => {
                out.push(OutputSpec { name: "lambda", shape: Shape::Lambda });
            }
            KernelKind::StepGrad if lambda => out.extend([
                OutputSpec { name: "lambda", shape: Shape::Lambda },
                OutputSpec { name: "dlambda_dx", shape: Shape::LambdaByState },
                OutputSpec { name: "dlambda_du", shape: Shape::LambdaByInput },
            ]),
            _ => {}
        }
        out
    }

    /// Whether the kernel takes the external and contact forces a model declares (the
    /// contact and step kernels take `fext` and solve for λ).
    pub fn takes_forces(self) -> bool {
        matches!(
            self,
            KernelKind::Rnea | KernelKind::RneaGrad | KernelKind::Fd | KernelKind::FdGrad
        ) || self.solves_contacts()
    }

    /// Whether the kernel holds the model's contacts rigid and solves for their forces
    /// (rather than taking them as the `lambda` input): the contact kernels, and the step
    /// kernels, which step with `contact_fd` when contacts are declared.
    pub fn solves_contacts(self) -> bool {
        self.is_contact() || self.is_step()
    }

    /// The inputs of the kernel of a model so specialised: [`Self::inputs`], then `fext`
    /// and `lambda` when the model declares them and the kernel takes forces, then a step
    /// kernel's `dt` when the scene leaves it to run time.
    pub fn inputs_for(self, spec: &crate::model::Specialisation) -> Vec<Input> {
        let mut inputs = self.inputs().to_vec();
        if self.takes_forces() {
            inputs.extend((!spec.fext.is_empty()).then_some(Input::Fext));
            inputs.extend(
                (!spec.contacts.is_empty() && !self.solves_contacts()).then_some(Input::Lambda),
            );
        }
        if self.solves_contacts() && spec.contact_mask && !spec.contacts.is_empty() {
            inputs.push(Input::Active);
        }
        if self.solves_contacts() && spec.baumgarte && !spec.contacts.is_empty() {
            inputs.extend([Input::Gains, Input::ContactRef]);
        }
        if self.is_step() && spec.step.is_some_and(|s| s.runtime_dt()) {
            inputs.push(Input::Dt);
        }
        inputs
    }

    /// Entries per state of WGSL's `u` buffer, which packs every input after q and q̇:
    /// the first (q̈, τ or the actuated τ), then the forces the kernel takes, then the
    /// contact mask and Baumgarte's inputs, then a step kernel's run-time `dt`.
    pub fn u_len(self, p: &UPacking) -> usize {
        if self.is_lie() {
            // `v` rides in the `qd` buffer; `difference`'s q1 is all of u.
            return if self.inputs().contains(&Input::Q1) { p.nq } else { 0 };
        }
        let first = if self.is_step() { p.nu } else { p.nv };
        let dt = usize::from(self.is_step() && p.runtime_dt);
        let mask =
            if self.solves_contacts() { p.active + 2 * p.baumgarte + p.contact_ref } else { 0 };
        dt + mask
            + match (self.takes_forces(), self.solves_contacts()) {
                (false, _) => first,
                (true, false) => first + p.forces,
                (true, true) => first + p.forces.saturating_sub(p.lambda),
            }
    }

    /// One sentence for the function's doc comment.
    pub fn doc(self) -> &'static str {
        match self {
            KernelKind::Rnea => "Inverse dynamics (RNEA): joint forces `c = M(q) qdd + C(q, qd) qd + g(q)`.",
            KernelKind::RneaGrad => "Analytical gradient of RNEA: `(dc/dq, dc/dqd)`, row-major `[i][j] = dc_i/du_j`.",
            KernelKind::MassMatrix => "The joint-space inertia matrix M(q) (CRBA).",
            KernelKind::Minv => "M(q)^-1 by the direct O(nv^2) recursion; M is never formed or inverted.",
            KernelKind::Fd => "Forward dynamics `qdd = M^-1 (tau - c(q, qd, 0))` by the O(nv) articulated-body algorithm (M^-1 is never formed).",
            KernelKind::FdGrad => "Forward dynamics and its gradient: `(qdd, dqdd/dq, dqdd/dqd)`, `dqdd/du = -M^-1 dc/du` at that qdd.",
            KernelKind::FramePlacement => "Each frame's world placement: translation, and rotation (frame axes in world coordinates, row-major), as Pinocchio's `framesForwardKinematics`.",
            KernelKind::FrameJacobian => "Each frame's Jacobian, 6 x nv, rows [linear; angular], in the module's `REFERENCE_FRAME` (Pinocchio's `getFrameJacobian`).",
            KernelKind::FrameVelocity => "Each frame's spatial velocity [linear; angular] in the module's `REFERENCE_FRAME` (Pinocchio's `getFrameVelocity`).",
            KernelKind::FrameAcceleration => "Each frame's classical acceleration (linear, with `w x v`) in the module's `REFERENCE_FRAME` (Pinocchio's `getFrameClassicalAcceleration`); at qdd = 0, the drift `dJ/dt qd`.",
            KernelKind::FrameAccelerationGrad => "The classical acceleration's derivatives `(dacc/dq, dacc/dqd, dacc/dqdd)`, 3 x nv per frame, row-major, `dq` in the tangent space (forward-mode differentiation of `frame_acceleration`'s graph).",
            KernelKind::Step => "One step of `STEP_SCHEME` over `DT` seconds from `(q, qd)` under the actuated joints' forces `tau` (`ACTUATED`): `(q_next, qd_next)`, q on the manifold (Pinocchio's `integrate`); with `CONTACTS`, then `lambda`, their forces at `(q, qd)` under `tau` (the first stage's under RK4) as `contact_fd`'s.",
            KernelKind::StepGrad => "The step and its linearisation: `(q_next, qd_next, A, B)`, A = d(q_next, qd_next)/d(q, qd) (2NV x 2NV), B = d(q_next, qd_next)/d tau (2NV x NU), row-major, rows and columns `[dq; dqd]` in the tangent space (Pinocchio's `dIntegrate`); with `CONTACTS`, then `(lambda, dlambda/dx, dlambda/du)` as `step`'s.",
            KernelKind::ContactFd => "Rigid-contact forward dynamics `(qdd, lambda)`: every contact of `CONTACTS` held (a point's classical acceleration, a wrench's spatial acceleration, zero in world axes at the frame), lambda the contacts' forces in world axes at their frames (Pinocchio's `constraintDynamics` with `CONTACT_3D` / `CONTACT_6D` in `LOCAL_WORLD_ALIGNED`, `lambda_c`), through the contact Schur complement `J M^-1 J^T`.",
            KernelKind::ContactFdGrad => "Rigid-contact forward dynamics and its derivatives `(qdd, lambda, dqdd/dq, dqdd/dqd, dqdd/dtau, dlambda/dq, dlambda/dqd, dlambda/dtau)`, q in the tangent space (Pinocchio's `computeConstraintDynamicsDerivatives`); fext, if any, held in the bodies' frames.",
            KernelKind::Integrate => "The configuration `q (+) v` reached from q along the tangent v in unit time (Pinocchio's `integrate`): scalar coordinates add, a spherical joint turns by `exp3`, a free-flyer moves by `exp6` in its own frame; quaternions renormalised to first order.",
            KernelKind::DIntegrate => "The Jacobians of `integrate` in the tangent space: `(d(q (+) v)/dq, d(q (+) v)/dv)`, NV x NV each, row-major (Pinocchio's `dIntegrate` with `ARG0`, `ARG1`).",
            KernelKind::Difference => "The tangent v with `q (+) v = q1` (Pinocchio's `difference(q0 = q, q1)`): `q1 - q` on scalar coordinates, the logarithm of `q^-1 q1` on a spherical joint (`log3`, angle at most pi) and a free-flyer (`log6`).",
            KernelKind::DDifference => "The Jacobians of `difference` in the tangent space: `(dv/dq, dv/dq1)`, NV x NV each, row-major (Pinocchio's `dDifference` with `ARG0`, `ARG1`).",
        }
    }

    /// What the function computes, for the API summary at the top of generated files
    /// (the text after `name(inputs) -> outputs: `; continuation lines are indented).
    pub fn summary(self) -> &'static str {
        match self {
            KernelKind::Rnea => "inverse dynamics `c = M(q) qdd + C(q, qd) qd + g(q)`.",
            KernelKind::RneaGrad => "its analytical gradient.",
            KernelKind::MassMatrix => "the joint-space inertia matrix M(q).",
            KernelKind::Minv => "M(q)^-1 (the function's doc says how it is formed).",
            KernelKind::Fd => "forward dynamics `qdd = M^-1 (tau - c(q, qd, 0))`,\n  by the O(nv) articulated-body algorithm.",
            KernelKind::FdGrad => "forward dynamics and its gradient `-M^-1 dc/du`\n  at that qdd (the function's doc says how qdd and M^-1 are formed).",
            KernelKind::FramePlacement => "each frame's world translation and rotation.",
            KernelKind::FrameJacobian => "each frame's 6 x nv Jacobian in `REFERENCE_FRAME`.",
            KernelKind::FrameVelocity => "each frame's spatial velocity in `REFERENCE_FRAME`.",
            KernelKind::FrameAcceleration => "each frame's classical acceleration in `REFERENCE_FRAME`.",
            KernelKind::FrameAccelerationGrad => "its derivatives, 3 x nv per frame.",
            KernelKind::Step => "one step of `STEP_SCHEME` over `DT` seconds, q on the manifold.",
            KernelKind::StepGrad => "the step and its linearisation `[A | B]` in the tangent space.",
            KernelKind::ContactFd => "rigid-contact forward dynamics: qdd and the contact forces lambda.",
            KernelKind::ContactFdGrad => "their derivatives with respect to q, qd and tau.",
            KernelKind::Integrate => "`q (+) v`, q on the manifold (Pinocchio's `integrate`).",
            KernelKind::DIntegrate => "its Jacobians with respect to q and v, in the tangent space.",
            KernelKind::Difference => "the tangent v with `q (+) v = q1` (Pinocchio's `difference`).",
            KernelKind::DDifference => "its Jacobians with respect to q and q1, in the tangent space.",
        }
    }

    /// Whether the kernel needs M⁻¹, so cannot exist for a robot whose M is singular.
    pub fn needs_minv(self) -> bool {
        matches!(
            self,
            KernelKind::Minv
                | KernelKind::Fd
                | KernelKind::FdGrad
                | KernelKind::Step
                | KernelKind::StepGrad
        ) || self.is_contact()
    }

    /// Kernels whose graph contains this one's (a superset of its work): if this kernel is
    /// too large to lower, so are they.
    pub fn contained_in(self) -> &'static [KernelKind] {
        use KernelKind::*;
        match self {
            Rnea => &[RneaGrad, Fd, FdGrad, Step, StepGrad, ContactFd, ContactFdGrad],
            RneaGrad => &[FdGrad, StepGrad, ContactFdGrad],
            MassMatrix => &[],
            Minv => &[Fd, FdGrad, Step, StepGrad, ContactFd, ContactFdGrad],
            Fd => &[FdGrad, Step, StepGrad, ContactFd, ContactFdGrad],
            FdGrad => &[StepGrad, ContactFdGrad],
            Step => &[StepGrad],
            // A step under contacts holds its contact kernel's graph (the only step that
            // exists beside a contact kernel is one under those contacts).
            ContactFd => &[ContactFdGrad, Step, StepGrad],
            Integrate => &[DIntegrate],
            Difference => &[DDifference],
            DIntegrate | DDifference => &[],
            ContactFdGrad => &[StepGrad],
            StepGrad
            | FramePlacement
            | FrameJacobian
            | FrameVelocity
            | FrameAcceleration
            | FrameAccelerationGrad => &[],
        }
    }

    /// Records the kernel's algorithm into `d`'s graph; one node list per output.
    pub(crate) fn record(self, d: &mut Dynamics) -> Vec<Vec<Id>> {
        use Input::*;
        fn flat(m: Mat) -> Vec<Id> {
            m.into_iter().flatten().collect()
        }
        // Inputs and outputs are per coordinate; the recursions run per joint. `expand`
        // and `reduce` map between the two (the identity unless mimic joints are coupled).
        if self.takes_forces() {
            d.load_forces(if self.solves_contacts() {
                super::dynamics::LambdaSource::Unknown
            } else {
                super::dynamics::LambdaSource::Inputs
            });
        }
        match self {
            KernelKind::Rnea => {
                let (qd, qdd) = (d.inputs(Qd), d.inputs(Qdd));
                let (qd, qdd) = (d.expand(&qd), d.expand(&qdd));
                let c = d.rnea(&qd, &qdd).c;
                vec![d.reduce(&c)]
            }
            KernelKind::RneaGrad => {
                let (qd, qdd) = (d.inputs(Qd), d.inputs(Qdd));
                // Coordinates; the recursions below run per joint (more with coupled mimics).
                let nv = qd.len();
                let (qd, qdd) = (d.expand(&qd), d.expand(&qdd));
                let r = d.rnea(&qd, &qdd);
                let (dq, dqd) = d.rnea_grad(&r, &qd);
                let mut out = vec![flat(d.reduce_matrix(dq)), flat(d.reduce_matrix(dqd))];
                let (by_fext, by_lambda) = d.force_grad_columns();
                out.extend(d.wants_fext_grads().then(|| flat(transpose(by_fext, nv))));
                out.extend(d.declares_contacts().then(|| flat(transpose(by_lambda, nv))));
                out
            }
            KernelKind::MassMatrix => {
                let m = d.mass_matrix();
                vec![flat(d.reduce_matrix(m))]
            }
            KernelKind::Minv => vec![flat(d.minv_coordinates())],
            KernelKind::Fd => {
                let (qd, tau) = (d.inputs(Qd), d.inputs(Tau));
                vec![d.fd(&qd, &tau)]
            }
            KernelKind::FdGrad => {
                let (qd, tau) = (d.inputs(Qd), d.inputs(Tau));
                let nv = qd.len();
                let all: Vec<usize> =
                    if d.wants_fd_grad_minv() { (0..nv).collect() } else { Vec::new() };
                // ∂q̈/∂(fext, λ) = −M⁻¹ ∂c/∂(fext, λ), by the route that forms ∂q̈/∂u.
                let (mut rhs, by_lambda) = d.force_grad_columns();
                let nfext = rhs.len();
                rhs.extend(by_lambda);
                let (qdd, dq, dqd, minv, mut solved) = d.fd_grad(&qd, &tau, &all, &rhs);
                let mut out = vec![qdd, flat(dq), flat(dqd)];
                out.extend(d.wants_fd_grad_minv().then(|| flat(minv)));
                let by_lambda = solved.split_off(nfext);
                out.extend(d.wants_fext_grads().then(|| flat(transpose(solved, nv))));
                out.extend(d.declares_contacts().then(|| flat(transpose(by_lambda, nv))));
                out
            }
            KernelKind::FramePlacement => {
                let (t, r) = d.frame_placements();
                vec![t, r]
            }
            KernelKind::FrameJacobian => vec![d.frame_jacobians()],
            KernelKind::FrameVelocity => {
                let qd = d.inputs(Qd);
                let qd = d.expand(&qd);
                vec![d.frame_velocities(&qd)]
            }
            KernelKind::FrameAcceleration => {
                let (qd, qdd) = (d.inputs(Qd), d.inputs(Qdd));
                let (qd, qdd) = (d.expand(&qd), d.expand(&qdd));
                vec![d.frame_accelerations(&qd, &qdd)]
            }
            KernelKind::FrameAccelerationGrad => {
                let (qd, qdd) = (d.inputs(Qd), d.inputs(Qdd));
                let (xqd, xqdd) = (d.expand(&qd), d.expand(&qdd));
                let acc = d.frame_accelerations(&xqd, &xqdd);
                let (dq, dqd, dqdd) = d.frame_acceleration_grads(&acc);
                vec![dq, dqd, dqdd]
            }
            KernelKind::Step | KernelKind::StepGrad => {
                let step = d.step_spec();
                let (qd, tau) = (d.inputs(Qd), d.actuated_inputs());
                let dt = match step.dt {
                    Some(dt) => Scalar::Const(dt),
                    None => Scalar::node(d.g.input(Dt, 0)),
                };
                if self == KernelKind::Step {
                    let (q, v, lambda) = d.step(&qd, &tau, step.scheme, dt);
                    [q, v].into_iter().chain(lambda).collect()
                } else {
                    let (q, v, a, b, lambda) = d.step_grad(&qd, &tau, step.scheme, dt);
                    let lambda = lambda.map(|l| [l.by_state(), l.by_input(), l.lambda]);
                    let [dx, du, lambda] = lambda.map_or([None, None, None], |l| l.map(Some));
                    [Some(q), Some(v), Some(a), Some(b), lambda, dx, du]
                        .into_iter()
                        .flatten()
                        .collect()
                }
            }
            KernelKind::ContactFd => {
                let (qd, tau) = (d.inputs(Qd), d.inputs(Tau));
                let c = d.contact_fd(&qd, &tau);
                vec![c.qdd, c.lambda]
            }
            KernelKind::ContactFdGrad => {
                let (qd, tau) = (d.inputs(Qd), d.inputs(Tau));
                let all: Vec<usize> = (0..qd.len()).collect();
                d.contact_fd_grad(&qd, &tau, &all)
                    .into_iter()
                    .map(|x| x.into_iter().flatten().collect())
                    .collect()
            }
            KernelKind::Integrate => vec![d.lie_integrate()],
            KernelKind::DIntegrate => {
                let (dq, dv) = d.lie_d_integrate();
                vec![flat(dq), flat(dv)]
            }
            KernelKind::Difference => vec![d.difference()],
            KernelKind::DDifference => {
                let (dq, dq1) = d.d_difference();
                vec![flat(dq), flat(dq1)]
            }
        }
    }
}

impl std::fmt::Display for KernelKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
