//! One discrete dynamics step and its linearisation `[A | B]` in the tangent space, by
//! composing the reference forward dynamics with the configuration space's `integrate`
//! and its derivatives (Pinocchio's `integrate`, `dIntegrate`; Crocoddyl's integrated
//! action models for the schemes). The exponentials and their Jacobians are closed forms
//! (nalgebra's quaternion exponential; SO(3)'s Jacobians; Pinocchio's `Jexp6` formula)
//! with Taylor series where those cancel: a route independent of the kernels' scaling
//! and squaring and their forward-mode derivatives.
//!
//! The dynamics stepped are the model's: its external forces `fext` held constant over
//! the step (in the bodies' frames), and its contacts, when it declares any, rigid
//! (`constraintDynamics`, as Crocoddyl's `DifferentialActionModelContactFwdDynamics`
//! inside an integrated action model), so that a stage's q̈ and its derivatives are
//! [`super::contact_fd_derivatives`]'s.

use nalgebra::{DMatrix, Matrix3, UnitQuaternion, Vector3};

use super::{
    aba_with, contact_fd_derivatives_with, contact_fd_with, forward_dynamics_derivatives_with,
    minv, Baumgarte, External,
};
use crate::model::{LieBlock, Model, Scheme, Step};

/// `[ω]×`.
fn skew(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0)
}

/// `(1 − cos t) / t²` and `(t − sin t) / t³`: their Taylor series below t = 1 (where the
/// closed forms cancel), the closed forms above.
fn bc(t: f64) -> (f64, f64) {
    if t < 1.0 {
        let y = t * t;
        let (mut b, mut c, mut term_b, mut term_c) = (0.0, 0.0, 0.5, 1.0 / 6.0);
        for n in 1..12 {
            b += term_b;
            c += term_c;
            let k = 2.0 * n as f64;
            term_b *= -y / ((k + 1.0) * (k + 2.0));
            term_c *= -y / ((k + 2.0) * (k + 3.0));
        }
        return (b, c);
    }
    let h = (t / 2.0).sin();
    (2.0 * h * h / (t * t), (t - t.sin()) / (t * t * t))
}

/// Pinocchio's `Jexp6` coefficients `β = 1/t² − sin t / (2t (1 − cos t))` and `β' / t`:
/// their series below t = 1 (from `cot x = Σ (−1)^n 2^2n B_2n x^(2n−1) / (2n)!`, x = t/2,
/// since β = 1/t² − cot(t/2) / (2t)), Pinocchio's closed forms above.
pub(super) fn beta(t: f64) -> (f64, f64) {
    if t >= 1.0 {
        let (st, ct) = t.sin_cos();
        let inv = 1.0 / (2.0 * (1.0 - ct));
        let t2 = t * t;
        return (1.0 / t2 - st / t * inv, -2.0 / (t2 * t2) + (1.0 + st / t) / t2 * inv);
    }
    // Bernoulli numbers B_2n, n = 1..8.
    const B: [f64; 8] = [
        1.0 / 6.0,
        -1.0 / 30.0,
        1.0 / 42.0,
        -1.0 / 30.0,
        5.0 / 66.0,
        -691.0 / 2730.0,
        7.0 / 6.0,
        -3617.0 / 510.0,
    ];
    let (mut b, mut db) = (0.0, 0.0);
    let mut factorial = 1.0;
    for (i, bn) in B.iter().enumerate() {
        let n = i as i32 + 1;
        factorial *= (2 * n - 1) as f64 * (2 * n) as f64;
        // cot(t/2)/(2t) has the term (−1)^n 2^2n B_2n (t/2)^(2n−1) / ((2n)! 2t)
        // = (−1)^n B_2n t^(2n−2) / (2n)!.
        let coefficient = -(-1f64).powi(n) * bn / factorial;
        b += coefficient * t.powi(2 * n - 2);
        if n >= 2 {
            db += coefficient * (2 * n - 2) as f64 * t.powi(2 * n - 4);
        }
    }
    (b, db)
}

/// `[ω]×`-polynomials: SO(3)'s left Jacobian `V = I + B K + C K²` (exp6's translation),
/// and its right Jacobian `Jexp3 = I − B K + C K²` (K = [ω]×).
pub(super) fn so3_jacobians(w: &Vector3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let (b, c) = bc(w.norm());
    let k = skew(w);
    let k2 = k * k;
    (Matrix3::identity() + k * b + k2 * c, Matrix3::identity() - k * b + k2 * c)
}

/// SE(3)'s right Jacobian (Pinocchio's `Jexp6`, whose formula this follows), rows and
/// columns [linear; angular].
fn jexp6(v: &Vector3<f64>, w: &Vector3<f64>) -> DMatrix<f64> {
    let (_, jr) = so3_jacobians(w);
    let (b, db) = beta(w.norm());
    let t2 = w.norm_squared();
    let p = jr.transpose() * v;
    let wtp = w.dot(&p);
    let j = skew(&p) * 0.5 + w * w.transpose() * (db * wtp)
        - p * w.transpose() * (t2 * db + 2.0 * b)
        + Matrix3::identity() * (wtp * b)
        + w * p.transpose() * b;
    let mut out = DMatrix::zeros(6, 6);
    out.view_mut((0, 0), (3, 3)).copy_from(&jr);
    out.view_mut((3, 3), (3, 3)).copy_from(&jr);
    out.view_mut((0, 3), (3, 3)).copy_from(&(-jr * j));
    out
}

/// The unit quaternion `[x, y, z, w]` at q's entries `at..at + 4`, normalised.
pub(super) fn quaternion(q: &[f64], at: usize) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        q[at + 3],
        q[at],
        q[at + 1],
        q[at + 2],
    ))
}

fn store(out: &mut [f64], at: usize, r: &UnitQuaternion<f64>) {
    let c = r.quaternion().coords;
    out[at..at + 4].copy_from_slice(&[c[0], c[1], c[2], c[3]]);
}

/// `q ⊕ v` (Pinocchio's `integrate`): scalar coordinates add; a free-flyer moves by
/// `exp6(v)` in its own frame, a spherical joint by `exp3(ω)`.
pub fn integrate(model: &Model, q: &[f64], v: &[f64]) -> Vec<f64> {
    let mut out = q.to_vec();
    for block in model.lie_blocks() {
        match block {
            LieBlock::Scalar { v: k, q: i } => out[i] = q[i] + v[k],
            LieBlock::FreeFlyer => {
                let (lin, w) = (Vector3::new(v[0], v[1], v[2]), Vector3::new(v[3], v[4], v[5]));
                let r = quaternion(q, 3);
                let shift = r * (so3_jacobians(&w).0 * lin);
                for a in 0..3 {
                    out[a] = q[a] + shift[a];
                }
                store(&mut out, 3, &(r * UnitQuaternion::from_scaled_axis(w)));
            }
            LieBlock::Spherical { v: k, q: at } => {
                let w = Vector3::new(v[k], v[k + 1], v[k + 2]);
                store(&mut out, at, &(quaternion(q, at) * UnitQuaternion::from_scaled_axis(w)));
            }
        }
    }
    out
}

/// `(∂(q ⊕ v)/∂q, ∂(q ⊕ v)/∂v)` in the tangent space, nv × nv and block-diagonal
/// (Pinocchio's `dIntegrate` with `ARG0` and `ARG1`): for a free-flyer `Ad(exp6(v))⁻¹`
/// and `Jexp6(v)`, for a spherical joint `exp3(ω)ᵀ` and `Jexp3(ω)`, 1 and 1 otherwise.
pub fn d_integrate(model: &Model, v: &[f64]) -> (DMatrix<f64>, DMatrix<f64>) {
    let nv = model.nv();
    let (mut dq, mut dv) = (DMatrix::zeros(nv, nv), DMatrix::zeros(nv, nv));
    for block in model.lie_blocks() {
        match block {
            LieBlock::Scalar { v: k, .. } => {
                dq[(k, k)] = 1.0;
                dv[(k, k)] = 1.0;
            }
            LieBlock::FreeFlyer => {
                let (lin, w) = (Vector3::new(v[0], v[1], v[2]), Vector3::new(v[3], v[4], v[5]));
                let rt =
                    UnitQuaternion::from_scaled_axis(w).to_rotation_matrix().matrix().transpose();
                let p = so3_jacobians(&w).0 * lin;
                dq.view_mut((0, 0), (3, 3)).copy_from(&rt);
                dq.view_mut((0, 3), (3, 3)).copy_from(&(-rt * skew(&p)));
                dq.view_mut((3, 3), (3, 3)).copy_from(&rt);
                dv.view_mut((0, 0), (6, 6)).copy_from(&jexp6(&lin, &w));
            }
            LieBlock::Spherical { v: k, .. } => {
                let w = Vector3::new(v[k], v[k + 1], v[k + 2]);
                let rt =
                    UnitQuaternion::from_scaled_axis(w).to_rotation_matrix().matrix().transpose();
                dq.view_mut((k, k), (3, 3)).copy_from(&rt);
                dv.view_mut((k, k), (3, 3)).copy_from(&so3_jacobians(&w).1);
            }
        }
    }
    (dq, dv)
}

/// The next state and `A = ∂x⁺/∂x` (2nv × 2nv), `B = ∂x⁺/∂τ_actuated` (2nv × nu), rows
/// and columns `[δq; δq̇]` in the tangent space.
#[derive(Clone, Debug)]
pub struct StepDerivatives {
    pub q_next: Vec<f64>,
    pub qd_next: Vec<f64>,
    pub a: DMatrix<f64>,
    pub b: DMatrix<f64>,
}

/// The state integration `x ⊕ dx` of Crocoddyl's `StateMultibody`: q by `integrate`, q̇
/// by addition.
fn state_integrate(model: &Model, q: &[f64], qd: &[f64], dx: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let nv = model.nv();
    (integrate(model, q, &dx[..nv]), (0..nv).map(|k| qd[k] + dx[nv + k]).collect())
}

/// q̈ at one state: forward dynamics under `fext`, with the model's contacts held rigid
/// when it declares any. `None` when the contacts' KKT system is singular there.
fn acceleration(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    fext: &[f64],
    corr: Baumgarte,
) -> Option<Vec<f64>> {
    if model.specialisation.contacts.is_empty() {
        return Some(aba_with(model, q, qd, tau, gravity, External { fext, lambda: &[] }));
    }
    contact_fd_with(model, q, qd, tau, gravity, fext, corr).map(|c| c.qdd)
}

/// q̈ and `(∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ)`.
type AccelerationDerivatives = (Vec<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>);

/// [`acceleration`] and `(∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ)`, τ's columns all nv coordinates.
fn acceleration_derivatives(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    fext: &[f64],
    corr: Baumgarte,
) -> Option<AccelerationDerivatives> {
    if model.specialisation.contacts.is_empty() {
        let (qdd, dq, dqd) = forward_dynamics_derivatives_with(
            model,
            q,
            qd,
            tau,
            gravity,
            External { fext, lambda: &[] },
        );
        return Some((qdd, dq, dqd, minv(model, q)));
    }
    let (sol, d) = contact_fd_derivatives_with(model, q, qd, tau, gravity, fext, corr)?;
    Some((sol.qdd, d.dqdd_dq, d.dqdd_dqd, d.dqdd_dtau))
}

/// One step from `(q, q̇)` under joint forces `tau` (nv entries) with gravity `gravity` and
/// the model's external forces `fext` (as [`External::fext`]; empty for none) held over the
/// step. `None` when the model's contacts are singular at a state the step visits.
pub fn step(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    step: Step,
    fext: &[f64],
) -> Option<(Vec<f64>, Vec<f64>)> {
    step_with(model, q, qd, tau, gravity, step, fext, Baumgarte::NONE)
}

/// [`step`] with the contacts stabilised by `corr`.
#[allow(clippy::too_many_arguments)]
pub fn step_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    step: Step,
    fext: &[f64],
    corr: Baumgarte,
) -> Option<(Vec<f64>, Vec<f64>)> {
    let nv = model.nv();
    let dt = step.dt;
    Some(match step.scheme {
        Scheme::SemiImplicitEuler | Scheme::ExplicitEuler => {
            let qdd = acceleration(model, q, qd, tau, gravity, fext, corr)?;
            let qd_next: Vec<f64> = (0..nv).map(|k| qd[k] + dt * qdd[k]).collect();
            let moved = if step.scheme == Scheme::SemiImplicitEuler { &qd_next } else { qd };
            let dq: Vec<f64> = moved.iter().map(|x| dt * x).collect();
            (integrate(model, q, &dq), qd_next)
        }
        Scheme::Rk4 => {
            let mut dx = vec![0.0; 2 * nv];
            let mut k_prev: Vec<f64> = Vec::new();
            for (i, (c, weight)) in
                [(0.0, 1.0), (0.5, 2.0), (0.5, 2.0), (1.0, 1.0)].into_iter().enumerate()
            {
                let (y_q, y_v) = if i == 0 {
                    (q.to_vec(), qd.to_vec())
                } else {
                    let d: Vec<f64> = k_prev.iter().map(|x| c * dt * x).collect();
                    state_integrate(model, q, qd, &d)
                };
                let qdd = acceleration(model, &y_q, &y_v, tau, gravity, fext, corr)?;
                k_prev = y_v.iter().chain(&qdd).copied().collect();
                for (d, k) in dx.iter_mut().zip(&k_prev) {
                    *d += weight * dt / 6.0 * k;
                }
            }
            state_integrate(model, q, qd, &dx)
        }
    })
}

/// [`step`] and its linearisation; B's columns are the coordinates `actuated`.
#[allow(clippy::too_many_arguments)]
pub fn step_derivatives(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    step: Step,
    actuated: &[usize],
    fext: &[f64],
) -> Option<StepDerivatives> {
    step_derivatives_with(model, q, qd, tau, gravity, step, actuated, fext, Baumgarte::NONE)
}

/// [`step_derivatives`] with the contacts stabilised by `corr` (references held fixed).
#[allow(clippy::too_many_arguments)]
pub fn step_derivatives_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    step: Step,
    actuated: &[usize],
    fext: &[f64],
    corr: Baumgarte,
) -> Option<StepDerivatives> {
    let nv = model.nv();
    let dt = step.dt;
    let identity = DMatrix::<f64>::identity(nv, nv);
    // ∂q̈/∂τ_actuated = M⁻¹ S.
    let select =
        |m: &DMatrix<f64>| DMatrix::from_fn(nv, actuated.len(), |r, c| m[(r, actuated[c])]);
    let assemble = |aqq: DMatrix<f64>,
                    aqv: DMatrix<f64>,
                    avq: DMatrix<f64>,
                    avv: DMatrix<f64>,
                    bq: DMatrix<f64>,
                    bv: DMatrix<f64>| {
        let mut a = DMatrix::zeros(2 * nv, 2 * nv);
        a.view_mut((0, 0), (nv, nv)).copy_from(&aqq);
        a.view_mut((0, nv), (nv, nv)).copy_from(&aqv);
        a.view_mut((nv, 0), (nv, nv)).copy_from(&avq);
        a.view_mut((nv, nv), (nv, nv)).copy_from(&avv);
        let mut b = DMatrix::zeros(2 * nv, actuated.len());
        b.view_mut((0, 0), (nv, actuated.len())).copy_from(&bq);
        b.view_mut((nv, 0), (nv, actuated.len())).copy_from(&bv);
        (a, b)
    };
    match step.scheme {
        Scheme::SemiImplicitEuler | Scheme::ExplicitEuler => {
            let (qdd, da_dq, da_dv, da_dtau) =
                acceleration_derivatives(model, q, qd, tau, gravity, fext, corr)?;
            let da_du = select(&da_dtau);
            let qd_next: Vec<f64> = (0..nv).map(|k| qd[k] + dt * qdd[k]).collect();
            let (avq, avv, bv) = (&da_dq * dt, &identity + &da_dv * dt, &da_du * dt);
            let semi = step.scheme == Scheme::SemiImplicitEuler;
            let moved = if semi { &qd_next } else { qd };
            let dq: Vec<f64> = moved.iter().map(|x| dt * x).collect();
            let (jq, jv) = d_integrate(model, &dq);
            let (aqq, aqv, bq) = if semi {
                (&jq + &jv * &avq * dt, &jv * &avv * dt, &jv * &bv * dt)
            } else {
                (jq, &jv * dt, DMatrix::zeros(nv, actuated.len()))
            };
            let (a, b) = assemble(aqq, aqv, avq, avv, bq, bv);
            Some(StepDerivatives { q_next: integrate(model, q, &dq), qd_next, a, b })
        }
        Scheme::Rk4 => {
            rk4_derivatives(model, q, qd, tau, gravity, fext, dt, actuated.len(), &select, corr)
        }
    }
}

/// The contact forces a step returns with a model that declares contacts: λ at the knot's
/// state `(q, q̇)` under `tau` (for RK4, its first stage), `∂λ/∂x` (nλ × 2nv, columns
/// `[δq; δq̇]`, q in the tangent space) and `∂λ/∂u` (nλ × nu, the coordinates
/// `actuated`). `None` when the contacts are singular there.
pub fn step_lambda(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    actuated: &[usize],
    fext: &[f64],
) -> Option<(Vec<f64>, DMatrix<f64>, DMatrix<f64>)> {
    step_lambda_with(model, q, qd, tau, gravity, actuated, fext, Baumgarte::NONE)
}

/// [`step_lambda`] with the contacts stabilised by `corr`.
#[allow(clippy::too_many_arguments)]
pub fn step_lambda_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    actuated: &[usize],
    fext: &[f64],
    corr: Baumgarte,
) -> Option<(Vec<f64>, DMatrix<f64>, DMatrix<f64>)> {
    let nv = model.nv();
    let (sol, d) = contact_fd_derivatives_with(model, q, qd, tau, gravity, fext, corr)?;
    let nl = sol.lambda.len();
    let mut dx = DMatrix::zeros(nl, 2 * nv);
    dx.view_mut((0, 0), (nl, nv)).copy_from(&d.dlambda_dq);
    dx.view_mut((0, nv), (nl, nv)).copy_from(&d.dlambda_dqd);
    let du = DMatrix::from_fn(nl, actuated.len(), |r, c| d.dlambda_dtau[(r, actuated[c])]);
    Some((sol.lambda, dx, du))
}

/// RK4's chain rule, stage by stage, as Crocoddyl's `IntegratedActionModelRK4::calcDiff`:
/// `∂y_i/∂x = J_x(x, dx_i) + J_dx(x, dx_i) c_i dt ∂k_(i−1)/∂x`, `∂k_i/∂x = ∂f/∂y_i ∂y_i/∂x`,
/// with `J_x`, `J_dx` the state's `Jintegrate` (q's `dIntegrate`, identity for q̇).
#[allow(clippy::too_many_arguments)]
fn rk4_derivatives(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    fext: &[f64],
    dt: f64,
    nu: usize,
    select: &dyn Fn(&DMatrix<f64>) -> DMatrix<f64>,
    corr: Baumgarte,
) -> Option<StepDerivatives> {
    let nv = model.nv();
    let state_jacobians = |dx: &[f64]| {
        let (jq, jv) = d_integrate(model, &dx[..nv]);
        let (mut jx, mut jdx) =
            (DMatrix::identity(2 * nv, 2 * nv), DMatrix::identity(2 * nv, 2 * nv));
        jx.view_mut((0, 0), (nv, nv)).copy_from(&jq);
        jdx.view_mut((0, 0), (nv, nv)).copy_from(&jv);
        (jx, jdx)
    };
    let mut dx = vec![0.0; 2 * nv];
    let (mut dx_dx, mut dx_du) =
        (DMatrix::<f64>::zeros(2 * nv, 2 * nv), DMatrix::<f64>::zeros(2 * nv, nu));
    let (mut k_prev, mut dk_dx_prev, mut dk_du_prev) =
        (Vec::new(), DMatrix::zeros(2 * nv, 2 * nv), DMatrix::zeros(2 * nv, nu));
    for (i, (c, weight)) in [(0.0, 1.0), (0.5, 2.0), (0.5, 2.0), (1.0, 1.0)].into_iter().enumerate()
    {
        let (y_q, y_v, dy_dx, dy_du) = if i == 0 {
            (q.to_vec(), qd.to_vec(), DMatrix::identity(2 * nv, 2 * nv), DMatrix::zeros(2 * nv, nu))
        } else {
            let d: Vec<f64> = k_prev.iter().map(|x: &f64| c * dt * x).collect();
            let (y_q, y_v) = state_integrate(model, q, qd, &d);
            let (jx, jdx) = state_jacobians(&d);
            (y_q, y_v, jx + &jdx * &dk_dx_prev * (c * dt), &jdx * &dk_du_prev * (c * dt))
        };
        let (qdd, da_dq, da_dv, da_dtau) =
            acceleration_derivatives(model, &y_q, &y_v, tau, gravity, fext, corr)?;
        let da_du = select(&da_dtau);
        // ∂f/∂y = [[0, I], [∂q̈/∂q, ∂q̈/∂q̇]].
        let mut df = DMatrix::zeros(2 * nv, 2 * nv);
        df.view_mut((0, nv), (nv, nv)).fill_with_identity();
        df.view_mut((nv, 0), (nv, nv)).copy_from(&da_dq);
        df.view_mut((nv, nv), (nv, nv)).copy_from(&da_dv);
        let dk_dx = &df * &dy_dx;
        let mut dk_du = &df * &dy_du;
        let mut lower = dk_du.view_mut((nv, 0), (nv, nu));
        lower += &da_du;
        k_prev = y_v.iter().chain(&qdd).copied().collect();
        for (d, k) in dx.iter_mut().zip(&k_prev) {
            *d += weight * dt / 6.0 * k;
        }
        dx_dx += &dk_dx * (weight * dt / 6.0);
        dx_du += &dk_du * (weight * dt / 6.0);
        (dk_dx_prev, dk_du_prev) = (dk_dx, dk_du);
    }
    let (jx, jdx) = state_jacobians(&dx);
    let (q_next, qd_next) = state_integrate(model, q, qd, &dx);
    Some(StepDerivatives { q_next, qd_next, a: jx + &jdx * dx_dx, b: &jdx * dx_du })
}
