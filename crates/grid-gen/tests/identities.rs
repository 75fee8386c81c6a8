//! The reference dynamics against themselves: analytical gradients against central finite
//! differences, and the identities ∂c/∂q̈ = M, M M⁻¹ = I and FD(q, q̇, RNEA(q, q̇, q̈)) = q̈,
//! on random states of every bundled robot and with a non-default gravity.

use grid_gen::reference;
use grid_gen_test_support::*;
use nalgebra::DMatrix;

const GRAVITIES: [[f64; 3]; 2] = [reference::DEFAULT_GRAVITY, [1.5, -2.0, -9.0]];

/// Central differences with step h have truncation error h²/6 |f'''| ~ 1e-12 and round-off
/// eps |f| / h ~ 1e-10 relative for h = 1e-6; 1e-7 relative leaves a margin for the
/// O(10-100) growth of third derivatives at unit speeds, and nothing more (measured
/// worst: 1.5e-8).
const FD_TOL: f64 = 1e-7;
const H: f64 = 1e-6;

fn central<F: Fn(&[f64]) -> Vec<f64>>(f: F, x: &[f64]) -> DMatrix<f64> {
    let n = x.len();
    let mut out = DMatrix::zeros(f(x).len(), n);
    for j in 0..n {
        let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
        xp[j] += H;
        xm[j] -= H;
        let (fp, fm) = (f(&xp), f(&xm));
        for i in 0..fp.len() {
            out[(i, j)] = (fp[i] - fm[i]) / (2.0 * H);
        }
    }
    out
}

fn states(n: usize, rng: &mut Rng) -> Vec<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    (0..4).map(|_| (rng.vec(n, -3.0, 3.0), rng.vec(n, -2.0, 2.0), rng.vec(n, -2.0, 2.0))).collect()
}

#[test]
fn rnea_gradient_matches_finite_differences() {
    let mut rng = Rng(1);
    let mut worst = 0.0f64;
    for robot in robots() {
        let model = load(&robot);
        for g in GRAVITIES {
            for (q, qd, qdd) in states(model.nv(), &mut rng) {
                let (dq, dqd) = reference::rnea_derivatives(&model, &q, &qd, &qdd, g);
                let fq = central(|x| reference::rnea(&model, x, &qd, &qdd, g), &q);
                let fqd = central(|x| reference::rnea(&model, &q, x, &qdd, g), &qd);
                assert!(
                    rel_err(&dq, &fq) < FD_TOL,
                    "{robot}: dc/dq off by {:.2e}",
                    rel_err(&dq, &fq)
                );
                assert!(
                    rel_err(&dqd, &fqd) < FD_TOL,
                    "{robot}: dc/dqd off by {:.2e}",
                    rel_err(&dqd, &fqd)
                );
                worst = worst.max(rel_err(&dq, &fq)).max(rel_err(&dqd, &fqd));
            }
        }
    }
    eprintln!("rnea_derivatives: worst relative difference from central differences: {worst:.2e}");
}

#[test]
fn fd_gradient_matches_finite_differences() {
    let mut rng = Rng(2);
    let mut worst = 0.0f64;
    for robot in robots() {
        let model = load(&robot);
        for g in GRAVITIES {
            for (q, qd, tau) in states(model.nv(), &mut rng) {
                let (_, dq, dqd) =
                    reference::forward_dynamics_derivatives(&model, &q, &qd, &tau, g);
                let fq = central(|x| reference::forward_dynamics(&model, x, &qd, &tau, g), &q);
                let fqd = central(|x| reference::forward_dynamics(&model, &q, x, &tau, g), &qd);
                // Through M⁻¹ the round-off term grows with cond(M) (1e2 to 1e4 here): a 10x wider
                // bound (measured worst: 6.2e-8).
                assert!(
                    rel_err(&dq, &fq) < 10.0 * FD_TOL,
                    "{robot}: dqdd/dq off by {:.2e}",
                    rel_err(&dq, &fq)
                );
                assert!(
                    rel_err(&dqd, &fqd) < 10.0 * FD_TOL,
                    "{robot}: dqdd/dqd off by {:.2e}",
                    rel_err(&dqd, &fqd)
                );
                worst = worst.max(rel_err(&dq, &fq)).max(rel_err(&dqd, &fqd));
            }
        }
    }
    eprintln!("forward_dynamics_derivatives: worst relative difference from central differences: {worst:.2e}");
}

#[test]
fn rnea_is_affine_in_qdd_with_slope_m() {
    let mut rng = Rng(3);
    for robot in robots() {
        let model = load(&robot);
        let n = model.nv();
        for (q, qd, _) in states(n, &mut rng) {
            let m = reference::crba(&model, &q);
            let base = reference::rnea(&model, &q, &qd, &vec![0.0; n], reference::DEFAULT_GRAVITY);
            let mut slope = DMatrix::zeros(n, n);
            for j in 0..n {
                let mut e = vec![0.0; n];
                e[j] = 1.0;
                let c = reference::rnea(&model, &q, &qd, &e, reference::DEFAULT_GRAVITY);
                for i in 0..n {
                    slope[(i, j)] = c[i] - base[i];
                }
            }
            // Exact up to the cancellation in c(e_j) - c(0): eps times |c| / |M| ≲ 1e2.
            assert!(
                rel_err(&slope, &m) < 1e-12,
                "{robot}: dc/dqdd vs M {:.2e}",
                rel_err(&slope, &m)
            );
            assert!((&m - m.transpose()).amax() <= 1e-15 * m.amax(), "{robot}: M symmetric");
        }
    }
}

#[test]
fn minv_inverts_m_and_fd_inverts_rnea() {
    let mut rng = Rng(4);
    for robot in robots() {
        let model = load(&robot);
        let n = model.nv();
        for (q, qd, qdd) in states(n, &mut rng) {
            let m = reference::crba(&model, &q);
            let mi = reference::minv(&model, &q);
            let cond = m.norm() * mi.norm();
            let err = (&m * &mi - DMatrix::identity(n, n)).amax();
            // Backward-stable recursions: error ≲ n eps cond(M).
            assert!(
                err < 10.0 * n as f64 * f64::EPSILON * cond,
                "{robot}: |M Minv - I| = {err:.2e}, cond {cond:.2e}"
            );
            let tau = reference::rnea(&model, &q, &qd, &qdd, reference::DEFAULT_GRAVITY);
            let back =
                reference::forward_dynamics(&model, &q, &qd, &tau, reference::DEFAULT_GRAVITY);
            let e = rel_err(&col(&back), &col(&qdd));
            // q̈ is fixed by τ − c(q, q̇, 0): rounding c (eps ‖c‖) moves q̈ by M⁻¹ eps ‖c‖,
            // which exceeds eps cond(M) ‖q̈‖ when ‖τ‖ + ‖c‖ ≫ ‖M‖ ‖q̈‖ (gravity-dominated states).
            let bias = reference::rnea(&model, &q, &qd, &vec![0.0; n], reference::DEFAULT_GRAVITY);
            let amp =
                ((col(&tau).norm() + col(&bias).norm()) / (m.norm() * col(&qdd).norm())).max(1.0);
            assert!(
                e < 10.0 * n as f64 * f64::EPSILON * cond * amp,
                "{robot}: FD(RNEA(qdd)) vs qdd {e:.2e}, cond {cond:.2e}, amplification {amp:.1}"
            );
        }
    }
}
