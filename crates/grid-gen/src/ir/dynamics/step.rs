//! The step kernels, recorded symbolically: one discrete step `x⁺ = x ⊕ dt f(x, τ)` and
//! its linearisation `[A | B]` in the tangent space, composed from `fd_grad`'s graph and
//! the configuration space's `integrate` (Pinocchio's conventions, as
//! `reference::step`).
//!
//! The exponentials of a free-flyer and a spherical joint need `sin θ / θ` and its
//! relatives, which have no branch-free closed form at θ = 0 and the IR has no square
//! root. They are instead evaluated by scaling and squaring: the Taylor series at
//! `θ / 2^K`, where nine terms are exact to rounding, then `K = 12` double-angle steps.
//! Every backend runs it as it runs the rest (adds and multiplies), at about 300
//! operations a joint; the result is exact to rounding for rotations of up to `2^K =
//! 4096` rad in one step (a base spinning at 1e3 rad/s over 10 ms turns by 10 rad; a
//! double-angle step doubles the angle's rounding error with the angle, so the error stays
//! that of `θ` itself, about ε θ per step, as in a library `sin`). `integrate`'s Jacobians
//! are written from the same coefficients (`R(ω)ᵀ`, `Jr(ω)`), but for a free-flyer's coupling
//! block, the forward-mode derivative of its translation.

use super::super::graph::{Graph, Id, Input, Stage};
use super::super::module::{ColumnBlock, ColumnProgram, ColumnStep, ColumnStore, Operand};
use super::super::spatial::{self as sp, joint_xform_at, k, V3};
use super::{Dynamics, LambdaSource, Mat, Scalar};
use crate::model::{LieBlock, Scheme};

/// Double-angle steps of the exponentials' scaling and squaring.
const DOUBLINGS: i32 = 12;
/// Terms of each Taylor series at `φ = θ / 2^DOUBLINGS` (up to `y^8`, y = φ²): the first
/// left out, `φ^18 / 19!`, is below 1e-17 of the sum for φ ≤ 1, θ ≤ 4096 rad.
const TERMS: usize = 9;

/// The contact forces a step's kernels return with it: λ at the knot's state `(q, q̇)` under
/// its τ, and its derivatives `∂λ/∂q` (tangent), `∂λ/∂q̇`, `∂λ/∂u` (u the actuated
/// coordinates), one row per entry of λ.
pub struct StepLambda {
    pub lambda: Vec<Id>,
    pub dq: Mat,
    pub dqd: Mat,
    pub du: Mat,
}

/// `step_grad`'s nodes: q⁺, q̇⁺, A and B (flat, row-major), and with contacts λ.
pub type StepGradNodes = (Vec<Id>, Vec<Id>, Vec<Id>, Vec<Id>, Option<StepLambda>);

impl StepLambda {
    /// `∂λ/∂x`, nλ × 2nv, row-major, columns `[δq; δq̇]`.
    pub fn by_state(&self) -> Vec<Id> {
        self.dq.iter().zip(&self.dqd).flat_map(|(a, b)| a.iter().chain(b)).copied().collect()
    }

    pub fn by_input(&self) -> Vec<Id> {
        self.du.iter().flatten().copied().collect()
    }
}

/// `sin φ / φ`, `cos φ`, `(1 − cos φ) / φ²` and `(φ − sin φ) / φ³` at one angle φ.
#[derive(Clone, Copy)]
struct Trig {
    s: Id,
    c: Id,
    b: Id,
    d: Id,
}

/// `Σ_n (−y)^n / (2n + m)!` by Horner's rule.
fn series(g: &mut Graph, y: Id, m: u32) -> Id {
    let factorial = |n: u32| (1..=n).map(f64::from).product::<f64>();
    let mut acc = k(
        g,
        if (TERMS - 1).is_multiple_of(2) { 1.0 } else { -1.0 }
            / factorial(2 * (TERMS as u32 - 1) + m),
    );
    for n in (0..TERMS as u32 - 1).rev() {
        let t = g.mul(acc, y);
        let c = k(g, if n % 2 == 0 { 1.0 } else { -1.0 } / factorial(2 * n + m));
        acc = g.add(c, t);
    }
    acc
}

/// An exponential as [`integrate`](Dynamics::integrate) recorded it: the rotation vector
/// ω, θ² and the nodes that read ω only through it (the half angle's `sin φ / φ`, `cos φ`,
/// the full angle's `b`, `d`; not all of them are used by every block), and a free-flyer's
/// `v` and translation `V v` before q's rotation moves it.
#[derive(Clone, Copy)]
pub(super) struct ExpNodes {
    omega: V3,
    theta2: Id,
    coefs: [Id; 4],
    shift: Option<(V3, V3)>,
}

impl ExpNodes {
    /// `R(ω)ᵀ = cos θ I − (sin θ/θ) [ω]× + b ω ωᵀ` and the right Jacobian
    /// `Jr(ω) = (sin θ/θ) I − b [ω]× + d ω ωᵀ` (Rodrigues; `Jr = I − b [ω]× + d [ω]×²` with
    /// `[ω]×² = ω ωᵀ − θ² I` and `1 − d θ² = sin θ/θ`), the blocks of Pinocchio's
    /// `dIntegrate` (`Jexp3`) without a division.
    fn rotation_and_jacobian(&self, g: &mut Graph) -> ([[Id; 3]; 3], [[Id; 3]; 3]) {
        let [hs, hc, b, d] = self.coefs;
        let w = self.omega;
        let sinc = g.mul(hs, hc);
        let bx = g.mul(b, self.theta2);
        let one = k(g, 1.0);
        let cos = g.sub(one, bx);
        let build = |g: &mut Graph, diag: Id, skew: Id, outer: Id| -> [[Id; 3]; 3] {
            let ow: V3 = w.map(|x| g.mul(outer, x));
            let sw: V3 = w.map(|x| g.mul(skew, x));
            std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    let o = g.mul(ow[r], w[c]);
                    if r == c {
                        return g.add(diag, o);
                    }
                    // −skew [ω]×: [ω]× has ω_m at (m+2, m+1) and −ω_m at (m+1, m+2).
                    let m = 3 - r - c;
                    if r == (m + 2) % 3 {
                        g.sub(o, sw[m])
                    } else {
                        g.add(o, sw[m])
                    }
                })
            })
        };
        (build(g, cos, sinc, b), build(g, sinc, b, d))
    }
}

/// The half angle's [`Trig`] and the full angle's `b`, `d`, for the rotation vector `w`
/// (θ = |w|), by scaling and squaring; and the nodes recorded as [`ExpNodes`].
fn exp_coefficients(g: &mut Graph, w: &V3) -> (Trig, Id, Id, ExpNodes) {
    let x = g.dot(w, w);
    let scale = k(g, 0.25f64.powi(DOUBLINGS));
    let mut y = g.mul(x, scale);
    let mut t =
        Trig { s: series(g, y, 1), c: series(g, y, 0), b: series(g, y, 2), d: series(g, y, 3) };
    let (half, quarter, four) = (k(g, 0.5), k(g, 0.25), k(g, 4.0));
    // sin 2φ/2φ = S C; cos 2φ = C² − φ² S²; (1 − cos 2φ)/4φ² = S²/2;
    // (2φ − sin 2φ)/8φ³ = (D + S B)/4.
    let double = |g: &mut Graph, t: Trig, y: Id| {
        let ss = g.mul(t.s, t.s);
        let cc = g.mul(t.c, t.c);
        let yss = g.mul(y, ss);
        let sb = g.mul(t.s, t.b);
        let dsb = g.add(t.d, sb);
        Trig { s: g.mul(t.s, t.c), c: g.sub(cc, yss), b: g.mul(half, ss), d: g.mul(quarter, dsb) }
    };
    for _ in 0..DOUBLINGS - 1 {
        t = double(g, t, y);
        y = g.mul(four, y);
    }
    let full = double(g, t, y);
    (
        t,
        full.b,
        full.d,
        ExpNodes { omega: *w, theta2: x, coefs: [t.s, t.c, full.b, full.d], shift: None },
    )
}

/// The quaternion product `a ⊗ b`, `[x, y, z, w]`.
pub(super) fn qmul(g: &mut Graph, a: [Id; 4], b: [Id; 4]) -> [Id; 4] {
    let (av, bv) = ([a[0], a[1], a[2]], [b[0], b[1], b[2]]);
    let cr = sp::cross(g, &av, &bv);
    let v: [Id; 3] = std::array::from_fn(|i| {
        let x = g.mul(a[3], bv[i]);
        let y = g.mul(b[3], av[i]);
        let s = g.add(x, y);
        g.add(s, cr[i])
    });
    let d = g.dot(&av, &bv);
    let ww = g.mul(a[3], b[3]);
    [v[0], v[1], v[2], g.sub(ww, d)]
}

/// `r (3 − |r|²) / 2`: Pinocchio's `firstOrderNormalize`, which keeps a rollout's
/// quaternions unit.
fn normalize(g: &mut Graph, r: [Id; 4]) -> [Id; 4] {
    let n2 = g.dot(&r, &r);
    let three = k(g, 3.0);
    let t = g.sub(three, n2);
    let half = k(g, 0.5);
    let f = g.mul(half, t);
    r.map(|x| g.mul(f, x))
}

/// `q ⊗ exp(w)`, normalised: a quaternion turned by the rotation vector `w` in its own frame.
fn turn(g: &mut Graph, q: [Id; 4], w: &V3) -> ([Id; 4], Id, Id, ExpNodes) {
    let (h, b, d, nodes) = exp_coefficients(g, w);
    let half = k(g, 0.5);
    let s = g.mul(half, h.s);
    let e = [g.mul(s, w[0]), g.mul(s, w[1]), g.mul(s, w[2]), h.c];
    let r = qmul(g, q, e);
    (normalize(g, r), b, d, nodes)
}

impl Dynamics<'_> {
    /// The model's step (the step kernels exist only for a model with one).
    pub fn step_spec(&self) -> crate::model::StepSpec {
        self.model
            .specialisation
            .step
            .expect("step kernels are lowered only for a model with a step")
    }

    /// Whether `fd_grad` also returns M⁻¹.
    pub fn wants_fd_grad_minv(&self) -> bool {
        self.model.specialisation.fd_grad_minv
    }

    /// The input nodes of a callee's output ([`Input::Called`]), flat.
    pub(super) fn called_inputs(&mut self, called: Option<Input>) -> Vec<Id> {
        let called = called.expect("a rest takes only outputs in `CALLED`");
        let n = called.len(&crate::ir::Robot::of(self.model).dims());
        (0..n).map(|j| self.g.input(called, j)).collect()
    }

    /// One node per actuated coordinate's force.
    pub fn actuated_inputs(&mut self) -> Vec<Id> {
        (0..self.model.nu()).map(|i| self.g.input(Input::TauActuated, i)).collect()
    }

    /// τ per coordinate from the actuated coordinates' forces: 0 on the others.
    fn actuate(&mut self, tau: &[Id]) -> Vec<Id> {
        let zero = self.g.constant(0.0);
        let mut full = vec![zero; self.model.nv()];
        for (&c, &t) in self.model.actuated().iter().zip(tau) {
            full[c] = t;
        }
        full
    }

    /// `q ⊕ w` (Pinocchio's `integrate`) for the kernel's q and the tangent `w`.
    fn integrate(&mut self, w: &[Id]) -> Vec<Id> {
        self.integrate_recorded(w).0
    }

    /// [`Self::integrate`] and each exponential's [`ExpNodes`], in the order of the model's
    /// Lie blocks, for [`Self::d_integrate`].
    pub(super) fn integrate_recorded(&mut self, w: &[Id]) -> (Vec<Id>, Vec<ExpNodes>) {
        let mut exps = Vec::new();
        let g = &mut self.g;
        let mut out: Vec<Id> = (0..self.model.nq()).map(|i| g.input(Input::Q, i)).collect();
        for block in self.model.lie_blocks() {
            match block {
                LieBlock::Scalar { v, q } => out[q] = g.add(out[q], w[v]),
                LieBlock::FreeFlyer => {
                    let quat = [out[3], out[4], out[5], out[6]];
                    let (lin, ang) = ([w[0], w[1], w[2]], [w[3], w[4], w[5]]);
                    let (turned, b, d, mut nodes) = turn(g, quat, &ang);
                    // exp6's translation V v = v + B (ω × v) + D (ω × (ω × v)), moved by R(q).
                    let wv = sp::cross(g, &ang, &lin);
                    let wwv = sp::cross(g, &ang, &wv);
                    let shift: V3 = std::array::from_fn(|i| {
                        let x = g.mul(b, wv[i]);
                        let y = g.mul(d, wwv[i]);
                        let s = g.add(x, y);
                        g.add(lin[i], s)
                    });
                    nodes.shift = Some((lin, shift));
                    exps.push(nodes);
                    let r = sp::quaternion_rotation(g, quat);
                    let moved = sp::mat_vec(g, &r, &shift);
                    for i in 0..3 {
                        out[i] = g.add(out[i], moved[i]);
                    }
                    out[3..7].copy_from_slice(&turned);
                }
                LieBlock::Spherical { v, q } => {
                    let quat = [out[q], out[q + 1], out[q + 2], out[q + 3]];
                    let (turned, _, _, nodes) = turn(g, quat, &[w[v], w[v + 1], w[v + 2]]);
                    exps.push(nodes);
                    out[q..q + 4].copy_from_slice(&turned);
                }
            }
        }
        (out, exps)
    }

    /// `(∂(q ⊕ w)/∂q, ∂(q ⊕ w)/∂w)` in the tangent space (Pinocchio's `dIntegrate`):
    /// block-diagonal, 1 on scalar coordinates. A rotation block (ω) is `R(ω)ᵀ` and
    /// `Jr(ω)` ([`ExpNodes::rotation_and_jacobian`]); a free-flyer's (`[v; ω]`, its
    /// translation `p = V(ω) v`) is `[[Rᵀ, −Rᵀ [p]×], [0, Rᵀ]]` (Pinocchio's
    /// `exp6(v).toDualActionMatrix()ᵀ`) and `[[Jr, Rᵀ ∂p/∂ω], [0, Jr]]` (`Jexp6`, whose
    /// coupling block is taken here by forward mode: `Rᵀ` moves `∂p/∂ω` from q⁺'s parent
    /// into q⁺'s frame). `p`'s coefficients depend on ω only through θ², so their
    /// derivatives along θ² are taken once and each column chains them (`dθ² = 2 ω_i`).
    pub(super) fn d_integrate(&mut self, exps: &[ExpNodes]) -> (Mat, Mat) {
        let nv = self.model.nv();
        let (zero, one) = (self.g.constant(0.0), self.g.constant(1.0));
        let (mut jq, mut jv) = (vec![vec![zero; nv]; nv], vec![vec![zero; nv]; nv]);
        let mut exps = exps.iter();
        for block in self.model.lie_blocks() {
            let (v, dims) = match block {
                LieBlock::Scalar { v, .. } => {
                    jq[v][v] = one;
                    jv[v][v] = one;
                    continue;
                }
                LieBlock::FreeFlyer => (0, 6),
                LieBlock::Spherical { v, .. } => (v, 3),
            };
            let exp = *exps.next().expect("one exponential per rotation block");
            let g = &mut self.g;
            let (rt, jr) = exp.rotation_and_jacobian(g);
            let at = v + dims - 3;
            for r in 0..3 {
                for c in 0..3 {
                    jq[at + r][at + c] = rt[r][c];
                    jv[at + r][at + c] = jr[r][c];
                }
            }
            let Some((lin, p)) = exp.shift else { continue };
            for r in 0..3 {
                for c in 0..3 {
                    jq[v + r][v + c] = rt[r][c];
                    jv[v + r][v + c] = jr[r][c];
                }
            }
            let d_coefs = g.tangent_at(&exp.coefs, &[], &[(exp.theta2, one)]);
            let two = k(g, 2.0);
            for c in 0..3 {
                // −Rᵀ [p]× e_c = Rᵀ (e_c × p).
                let mut ep = [zero; 3];
                let (a, b) = ((c + 1) % 3, (c + 2) % 3);
                ep[a] = g.neg(p[b]);
                ep[b] = p[a];
                let col = sp::mat_vec(g, &rt, &ep);
                // ∂p/∂ω_c with v held: ω's seed and the coefficients' chained tangents.
                let mut seeded: Vec<(Id, Id)> = (0..3)
                    .map(|i| (exp.omega[i], if i == c { one } else { zero }))
                    .chain(lin.map(|x| (x, zero)))
                    .collect();
                let d_theta2 = g.mul(two, exp.omega[c]);
                for (&x, &dx) in exp.coefs.iter().zip(&d_coefs) {
                    seeded.push((x, g.mul(dx, d_theta2)));
                }
                let dp: V3 = g.tangent_at(&p, &[], &seeded).try_into().expect("three entries");
                let coupling = sp::mat_vec(g, &rt, &dp);
                for r in 0..3 {
                    jq[v + r][at + c] = col[r];
                    jv[v + r][at + c] = coupling[r];
                }
            }
        }
        (jq, jv)
    }

    /// Runs `f` with the joint transforms at the configuration `q` (nodes) instead of the
    /// kernel's input: the dynamics at an RK4 stage's state. The forces are reloaded there
    /// too (a contact's geometry moves with q; fext, in the bodies' frames, does not).
    fn at_config<R>(&mut self, q: &[Id], f: impl FnOnce(&mut Self) -> R) -> R {
        let x = (0..self.model.njoints())
            .map(|i| {
                self.g.at(Some(i), Stage::Transform, self.model.joints[i].level);
                joint_xform_at(&mut self.g, self.model, i, Some(q))
            })
            .collect();
        let saved = std::mem::replace(&mut self.x, x);
        let config = self.config.replace(q.to_vec());
        let forces = self.forces.clone();
        self.load_forces(LambdaSource::Unknown);
        let out = f(self);
        self.x = saved;
        self.config = config;
        self.forces = forces;
        out
    }

    /// The q̈ a step integrates: forward dynamics under the loaded fext, with the model's
    /// contacts held rigid when it declares any (`contact_fd`, as Crocoddyl's contact
    /// dynamics inside its integrated action models); and then the contacts' forces λ.
    fn step_acceleration(&mut self, qd: &[Id], tau: &[Id]) -> (Vec<Id>, Option<Vec<Id>>) {
        if self.called && self.declares_contacts() {
            let (qdd, lambda) = (
                self.called_inputs(Some(Input::Called(0))),
                self.called_inputs(Some(Input::Called(1))),
            );
            return (qdd, Some(lambda));
        }
        if self.declares_contacts() {
            let c = self.contact_fd(qd, tau);
            return (c.qdd, Some(c.lambda));
        }
        (self.fd(qd, tau), None)
    }

    /// [`Self::step_acceleration`] and `s (∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ)`, τ's columns the
    /// coordinates `tau_cols`: `contact_fd_grad`'s with contacts, `fd_grad`'s without; with
    /// contacts, λ and its derivatives too (unscaled).
    fn step_acceleration_grad(
        &mut self,
        qd: &[Id],
        tau: &[Id],
        tau_cols: &[usize],
        s: Scalar,
    ) -> (Vec<Id>, Mat, Mat, Mat, Option<StepLambda>) {
        if self.called && self.declares_contacts() {
            // contact_fd_grad's outputs, as its kernel lays them out: τ's columns are all
            // of them, of which the step reads the actuated.
            let nv = self.model.nv();
            let (qdd, lambda) = (
                self.called_inputs(Some(Input::Called(0))),
                self.called_inputs(Some(Input::Called(1))),
            );
            let mut by = |k: u8, cols: Option<&[usize]>| -> Mat {
                let flat = self.called_inputs(Some(Input::Called(k)));
                flat.chunks(nv.max(1))
                    .map(|row| match cols {
                        Some(cols) => cols.iter().map(|&c| row[c]).collect(),
                        None => row.to_vec(),
                    })
                    .collect()
            };
            let (dq, dqd, dtau) = (by(2, None), by(3, None), by(4, Some(tau_cols)));
            let lam =
                StepLambda { lambda, dq: by(5, None), dqd: by(6, None), du: by(7, Some(tau_cols)) };
            // The composition runs over the columns as the whole kernel's does
            // ([`step_program`]), from the callee's ∂q̈/∂u as they come: a combination of
            // no steps. λ's derivatives are the callee's, copied, so they have no rows here.
            let blocks = [&dq, &dqd, &dtau]
                .iter()
                .enumerate()
                .map(|(which, m)| {
                    let cols = m.first().map_or(0, Vec::len);
                    let init =
                        m.iter().map(|row| row.iter().map(|&id| Operand::Node(id)).collect());
                    // step_program reads which of u the block is from its first store.
                    let store = ColumnStore {
                        row: 0,
                        output: super::contact::DQDD_BY[which],
                        flat: (0..cols).collect(),
                        negate: false,
                    };
                    ColumnBlock { init: init.collect(), steps: Vec::new(), stores: vec![store] }
                })
                .collect();
            self.program = Some(ColumnProgram { rows: nv, blocks, replaces: None });
            let (dq, dqd, dtau) =
                (self.scaled(&dq, s), self.scaled(&dqd, s), self.scaled(&dtau, s));
            return (qdd, dq, dqd, dtau, Some(lam));
        }
        if self.declares_contacts() {
            // contact_fd_grad's program (its combination over the columns) is left in
            // `self.program` for the Euler steps to extend ([`step_program`]).
            let mut out = self.contact_fd_grad(qd, tau, tau_cols).into_iter();
            let mut next = || out.next().unwrap_or_default();
            let qdd = next().into_iter().next().unwrap_or_default();
            let lambda = next().into_iter().next().unwrap_or_default();
            let (dq, dqd, dtau) = (next(), next(), next());
            let lam = StepLambda { lambda, dq: next(), dqd: next(), du: next() };
            let (dq, dqd, dtau) =
                (self.scaled(&dq, s), self.scaled(&dqd, s), self.scaled(&dtau, s));
            return (qdd, dq, dqd, dtau, Some(lam));
        }
        let (qdd, dq, dqd, minv, _) = self.fd_grad_scaled(qd, tau, tau_cols, &[], s);
        (qdd, dq, dqd, minv, None)
    }

    /// `q ⊕ w` for the kernel's q and a state's `x ⊕ dx` (Crocoddyl's `StateMultibody`).
    /// With each exponential's [`ExpNodes`].
    fn state_integrate(&mut self, qd: &[Id], dx: &[Id]) -> (Vec<Id>, Vec<Id>, Vec<ExpNodes>) {
        let nv = self.model.nv();
        let (q, exps) = self.integrate_recorded(&dx[..nv]);
        let v = (0..nv).map(|k| self.g.add(qd[k], dx[nv + k])).collect();
        (q, v, exps)
    }

    /// RK4's stages as Crocoddyl's `IntegratedActionModelRK4`: `k_i = (v_i, q̈_i)` at
    /// `y_i = x ⊕ c_i dt k_(i−1)`, `dx = dt (k_1 + 2 k_2 + 2 k_3 + k_4) / 6`. With `grad`,
    /// each stage's `fd_grad` and the chain rule give `(A, B)` too.
    fn rk4(&mut self, qd: &[Id], tau: &[Id], dt: Scalar, grad: bool) -> StepGradNodes {
        let nv = self.model.nv();
        let nx = 2 * nv;
        let actuated = self.model.actuated();
        let nu = actuated.len();
        let (zero, one) = (self.g.constant(0.0), self.g.constant(1.0));
        let identity = |n: usize| -> Mat {
            (0..n).map(|i| (0..n).map(|j| if i == j { one } else { zero }).collect()).collect()
        };
        let mut dx = vec![zero; nx];
        let (mut dx_dx, mut dx_du) = (vec![vec![zero; nx]; nx], vec![vec![zero; nu]; nx]);
        let (mut k_prev, mut dk_dx, mut dk_du): (Vec<Id>, Mat, Mat) =
            (Vec::new(), Vec::new(), Vec::new());
        // λ is the first stage's: the forces at the knot's own state.
        let mut lambda = None;
        for (i, (c, weight)) in
            [(0.0, 1.0), (0.5, 2.0), (0.5, 2.0), (1.0, 1.0)].into_iter().enumerate()
        {
            if self.exhausted() {
                break;
            }
            let (y_q, y_v, dy_dx, dy_du) = if i == 0 {
                let q: Vec<Id> = (0..self.model.nq()).map(|j| self.g.input(Input::Q, j)).collect();
                (q, qd.to_vec(), identity(nx), vec![vec![zero; nu]; nx])
            } else {
                let h = dt.times(c).id(&mut self.g);
                let d: Vec<Id> = k_prev.iter().map(|&x| self.g.mul(h, x)).collect();
                let (y_q, y_v, exps) = self.state_integrate(qd, &d);
                if grad {
                    let (jq, jv) = self.d_integrate(&exps);
                    let (jx, jdx) = (state_block(&jq, one, zero), state_block(&jv, one, zero));
                    let t = self.scaled_product(&jdx, &dk_dx, dt.times(c));
                    let dy_dx = self.add_mat(&jx, &t);
                    let dy_du = self.scaled_product(&jdx, &dk_du, dt.times(c));
                    (y_q, y_v, dy_dx, dy_du)
                } else {
                    (y_q, y_v, Vec::new(), Vec::new())
                }
            };
            let qdd;
            if grad {
                let (a, da_dq, da_dv, minv_s, lam) = self.at_config(&y_q, |d| {
                    d.step_acceleration_grad(&y_v, tau, &actuated, Scalar::ONE)
                });
                if i == 0 {
                    lambda = lam;
                }
                // ∂k/∂y = [[0, I], [∂q̈/∂q, ∂q̈/∂q̇]].
                let df: Mat = (0..nx)
                    .map(|r| {
                        (0..nx)
                            .map(|c| {
                                if r < nv {
                                    if c == r + nv {
                                        one
                                    } else {
                                        zero
                                    }
                                } else if c < nv {
                                    da_dq[r - nv][c]
                                } else {
                                    da_dv[r - nv][c - nv]
                                }
                            })
                            .collect()
                    })
                    .collect();
                dk_dx = self.scaled_product(&df, &dy_dx, Scalar::ONE);
                dk_du = self.scaled_product(&df, &dy_du, Scalar::ONE);
                for r in 0..nv {
                    for c in 0..nu {
                        dk_du[nv + r][c] = self.g.add(dk_du[nv + r][c], minv_s[r][c]);
                    }
                }
                let w = dt.times(weight).over(6.0);
                let t = self.scaled(&dk_dx, w);
                dx_dx = self.add_mat(&dx_dx, &t);
                let t = self.scaled(&dk_du, w);
                dx_du = self.add_mat(&dx_du, &t);
                qdd = a;
            } else {
                let (a, lam) = self.at_config(&y_q, |d| d.step_acceleration(&y_v, tau));
                if i == 0 {
                    lambda = lam.map(|lambda| StepLambda {
                        lambda,
                        dq: Vec::new(),
                        dqd: Vec::new(),
                        du: Vec::new(),
                    });
                }
                qdd = a;
            }
            k_prev = y_v.iter().chain(&qdd).copied().collect();
            let w = dt.times(weight).over(6.0).id(&mut self.g);
            for (d, &kk) in dx.iter_mut().zip(&k_prev) {
                let t = self.g.mul(w, kk);
                *d = self.g.add(*d, t);
            }
        }
        self.product = None;
        self.program = None;
        let (q_next, qd_next, exps) = self.state_integrate(qd, &dx);
        if !grad {
            return (q_next, qd_next, Vec::new(), Vec::new(), lambda);
        }
        let (jq, jv) = self.d_integrate(&exps);
        let (jx, jdx) = (state_block(&jq, one, zero), state_block(&jv, one, zero));
        let t = self.scaled_product(&jdx, &dx_dx, Scalar::ONE);
        let a = self.add_mat(&jx, &t);
        let b = self.scaled_product(&jdx, &dx_du, Scalar::ONE);
        let (a, b) = (a.into_iter().flatten().collect(), b.into_iter().flatten().collect());
        (q_next, qd_next, a, b, lambda)
    }

    /// `s · x y` (zeros fold away).
    fn scaled_product(&mut self, x: &Mat, y: &Mat, s: Scalar) -> Mat {
        let cols = y.first().map_or(0, Vec::len);
        let h = s.id(&mut self.g);
        (0..x.len())
            .map(|i| {
                (0..cols)
                    .map(|c| {
                        let col: Vec<Id> = (0..y.len()).map(|r| y[r][c]).collect();
                        let d = self.g.dot(&x[i], &col);
                        self.g.mul(h, d)
                    })
                    .collect()
            })
            .collect()
    }

    fn scaled(&mut self, x: &Mat, s: Scalar) -> Mat {
        let h = s.id(&mut self.g);
        x.iter().map(|row| row.iter().map(|&v| self.g.mul(h, v)).collect()).collect()
    }

    fn add_mat(&mut self, x: &Mat, y: &Mat) -> Mat {
        x.iter()
            .zip(y)
            .map(|(a, b)| a.iter().zip(b).map(|(&p, &q)| self.g.add(p, q)).collect())
            .collect()
    }

    /// `x⁺ = (q⁺, q̇⁺)` for one step of `scheme` under the actuated forces `tau`, and with
    /// contacts their forces λ at `(q, q̇)` ([`StepLambda`]).
    pub fn step(
        &mut self,
        qd: &[Id],
        tau: &[Id],
        scheme: Scheme,
        dt: Scalar,
    ) -> (Vec<Id>, Vec<Id>, Option<Vec<Id>>) {
        let tau = self.actuate(tau);
        if scheme == Scheme::Rk4 {
            let (q, v, _, _, lam) = self.rk4(qd, &tau, dt, false);
            return (q, v, lam.map(|l| l.lambda));
        }
        let (qdd, lambda) = self.step_acceleration(qd, &tau);
        self.g.at(None, Stage::Combine, 0);
        let (qd_next, w) = self.euler(qd, &qdd, scheme, dt);
        (self.integrate(&w), qd_next, lambda)
    }

    /// `q̇⁺ = q̇ + dt q̈` and the tangent that moves q: `dt q̇⁺` (semi-implicit) or `dt q̇`.
    fn euler(&mut self, qd: &[Id], qdd: &[Id], scheme: Scheme, dt: Scalar) -> (Vec<Id>, Vec<Id>) {
        let g = &mut self.g;
        let h = dt.id(g);
        let qd_next: Vec<Id> = qd
            .iter()
            .zip(qdd)
            .map(|(&v, &a)| {
                let t = g.mul(h, a);
                g.add(v, t)
            })
            .collect();
        let moved = if scheme == Scheme::SemiImplicitEuler { &qd_next } else { qd };
        let w = moved.iter().map(|&v| g.mul(h, v)).collect();
        (qd_next, w)
    }

    /// [`Self::step`] and `(A, B)`, flat and row-major: A is 2nv × 2nv, B 2nv × nu, rows
    /// and columns `[δq; δq̇]`. With `a_v = dt ∂q̈/∂x`, `b_v = dt M⁻¹ S`:
    /// semi-implicit `A = [[Jq + dt Jv a_vq, dt Jv (I + a_vv)], [a_vq, I + a_vv]]`,
    /// `B = [dt Jv b_v; b_v]`; explicit `A = [[Jq, dt Jv], [a_vq, I + a_vv]]`, `B = [0; b_v]`.
    /// With contacts, their forces and derivatives too ([`StepLambda`]).
    pub fn step_grad(
        &mut self,
        qd: &[Id],
        tau: &[Id],
        scheme: Scheme,
        dt: Scalar,
    ) -> StepGradNodes {
        let nv = self.model.nv();
        let actuated = self.model.actuated();
        let nu = actuated.len();
        let tau = self.actuate(tau);
        if scheme == Scheme::Rk4 {
            return self.rk4(qd, &tau, dt, true);
        }
        // a_v = dt ∂q̈/∂x and b_v = dt M⁻¹ S as they come out of the solves.
        let (qdd, avq, mut avv, bv, lambda) = self.step_acceleration_grad(qd, &tau, &actuated, dt);
        // The step's products are its own: no backend may rerun fd_grad's as a loop; the
        // contacts' combination goes on into the step's own program (below).
        let combination = if self.declares_contacts() { self.program.take() } else { None };
        self.product = None;
        self.program = None;
        self.g.at(None, Stage::Combine, 0);
        let (qd_next, w) = self.euler(qd, &qdd, scheme, dt);
        let (q_next, exps) = self.integrate_recorded(&w);
        let (jq, jv) = self.d_integrate(&exps);
        let (zero, one) = (self.g.constant(0.0), self.g.constant(1.0));
        for (i, row) in avv.iter_mut().enumerate() {
            row[i] = self.g.add(one, row[i]);
        }
        // dt Jv X, with Jv block-diagonal (its zeros fold away) and dt on Jv's entries
        // (on a scalar coordinate's row that is one multiplication per entry, as after).
        let jv_h = self.scaled(&jv, dt);
        let g = &mut self.g;
        let jv_times = |g: &mut Graph, x: &Mat| -> Mat {
            let cols = x.first().map_or(0, Vec::len);
            (0..nv)
                .map(|i| {
                    (0..cols)
                        .map(|c| {
                            let col: Vec<Id> = (0..nv).map(|r| x[r][c]).collect();
                            g.dot(&jv_h[i], &col)
                        })
                        .collect()
                })
                .collect()
        };
        let (aqq, aqv, bq) = if scheme == Scheme::SemiImplicitEuler {
            let t = jv_times(g, &avq);
            let aqq = jq
                .iter()
                .zip(&t)
                .map(|(a, b)| a.iter().zip(b).map(|(&x, &y)| g.add(x, y)).collect())
                .collect();
            (aqq, jv_times(g, &avv), jv_times(g, &bv))
        } else {
            (jq.clone(), jv_h.clone(), vec![vec![zero; nu]; nv])
        };
        let mut a = Vec::with_capacity(4 * nv * nv);
        for (left, right) in aqq.iter().zip(&aqv).chain(avq.iter().zip(&avv)) {
            a.extend(left);
            a.extend(right);
        }
        let b = bq.iter().chain(&bv).flatten().copied().collect();
        if let Some(p) = combination {
            let h = Operand::Node(dt.id(&mut self.g));
            let semi = (scheme == Scheme::SemiImplicitEuler).then_some((&jq, &jv_h));
            self.program = Some(step_program(p, (nv, nu), h, semi, zero));
        }
        (q_next, qd_next, a, b, lambda)
    }
}

/// `step_grad`'s program under contacts: `contact_fd_grad`'s combination per column of u =
/// q, q̇, τ (its three blocks, rows `[∂q̈/∂u e_c (nv); −∂λ/∂u e_c (nλ)]`), then the Euler
/// step's composition with the columns still innermost, so that no (column, coordinate)
/// pair of `[A | B]` is straight-line code: `x ← dt x` (the rows become `a_v e_c`), on
/// q̇'s columns `x ← x + e_c` (from identity rows, `I + a_vv`), and with the semi-implicit
/// scheme `z = Jq e_c + dt Jv x` (`z` starts at q's column of Jq, zero for q̇ and τ). Stored
/// as A's and B's rows `[z; x]` (`[0 from the graph; x]` for the explicit scheme, whose
/// `[Jq, dt Jv]` does not depend on q̈) and ∂λ/∂x, ∂λ/∂u. Rows: `x` 0..nv, the combination's
/// nλ, `z` nv, identity nv.
fn step_program(
    combination: ColumnProgram,
    (nv, nu): (usize, usize),
    dt: Operand,
    semi: Option<(&Mat, &Mat)>,
    zero: Id,
) -> ColumnProgram {
    let nl = combination.rows - nv;
    let (z0, e0) = (nv + nl, 2 * nv + nl);
    let rows = e0 + nv;
    let nx = 2 * nv;
    let blocks = combination
        .blocks
        .into_iter()
        .map(|b| {
            // Which of u = q, q̇, τ the block is, and its columns of u: where the
            // combination stores its row 0 (output `DQDD_BY[which]`, entry c).
            let which = super::contact::DQDD_BY.iter().position(|&o| o == b.stores[0].output);
            let which = which.expect("a contact combination stores q̈'s derivatives first");
            let cols = b.stores[0].flat.clone();
            let columns = cols.len();
            let mut init = b.init;
            let constant = |x: f64| vec![Operand::Const(x); columns];
            // z: q's columns of Jq (semi-implicit), else zero.
            for i in 0..nv {
                init.push(match (which, semi) {
                    (0, Some((jq, _))) => cols.iter().map(|&c| Operand::Node(jq[i][c])).collect(),
                    _ => constant(0.0),
                });
            }
            // Identity rows, read only on q̇'s columns.
            for i in 0..nv {
                init.push(match which {
                    1 => {
                        cols.iter().map(|&c| Operand::Const(f64::from(u8::from(c == i)))).collect()
                    }
                    _ => constant(0.0),
                });
            }
            let mut steps = b.steps;
            steps.extend((0..nv).map(|i| ColumnStep::Mul { dst: i, coef: dt }));
            if which == 1 {
                steps.extend((0..nv).map(|i| ColumnStep::Sub {
                    dst: i,
                    coef: Operand::Const(-1.0),
                    src: e0 + i,
                }));
            }
            if let Some((_, jv_h)) = semi {
                for i in 0..nv {
                    for (r, &j) in jv_h[i].iter().enumerate() {
                        if j != zero {
                            steps.push(ColumnStep::Sub {
                                dst: z0 + i,
                                coef: Operand::Neg(j),
                                src: r,
                            });
                        }
                    }
                }
            }
            // A (2nv x 2nv) and dλ/dx (nλ x 2nv) take q's columns then q̇'s; B (2nv x nu)
            // and dλ/du (nλ x nu) τ's.
            let (width, at, out_x, out_l) = match which {
                0 => (nx, 0, "a", "dlambda_dx"),
                1 => (nx, nv, "a", "dlambda_dx"),
                _ => (nu, 0, "b", "dlambda_du"),
            };
            let store =
                |row: usize, out_row: usize, output: &'static str, negate: bool| ColumnStore {
                    row,
                    output,
                    flat: cols.iter().map(|&c| out_row * width + at + c).collect(),
                    negate,
                };
            let mut stores: Vec<ColumnStore> =
                (0..nv).map(|i| store(i, nv + i, out_x, false)).collect();
            if semi.is_some() {
                stores.extend((0..nv).map(|i| store(z0 + i, i, out_x, false)));
            }
            stores.extend((0..nl).map(|r| store(nv + r, r, out_l, true)));
            ColumnBlock { init, steps, stores }
        })
        .collect();
    ColumnProgram { rows, blocks, replaces: None }
}

/// The state's block-diagonal Jacobian `[[J, 0], [0, I]]` (q's block `j`, q̇'s identity).
fn state_block(j: &Mat, one: Id, zero: Id) -> Mat {
    let nv = j.len();
    (0..2 * nv)
        .map(|r| {
            (0..2 * nv)
                .map(|c| {
                    if r < nv && c < nv {
                        j[r][c]
                    } else if r == c {
                        one
                    } else {
                        zero
                    }
                })
                .collect()
        })
        .collect()
}
