//! The extremes suite: f64 forward dynamics and its gradient against the
//! double-double value where the numbers are hardest: near-singular M (chains whose mass
//! and length taper by up to 1e6 from root to tip), speeds from 1e-8 to 1e4, angles up to
//! ±1e3 rad, joint limits. Each case prints cond(M), the measured error, and the bound a
//! backward-stable recursion guarantees, C · n · ε · cond(M) with C = 10 (the constant of
//! `identities.rs`) times the cancellation factor of τ − c. Asserted: the project's f64
//! tolerance, 1e-12 relative, on every case (ABA measures ≤ 1e-13 up to cond(M) = 2e10,
//! where the former q̈ = M⁻¹(τ − c) route lost 1e-9 at cond(M) = 1e5), and the bound.
//! Past cond(M) ~ 1/(n·ε) the model flags M as singular (next test); `grid-gen accuracy`
//! prints cond(M) for any states.

use grid_gen::ir::{self, KernelKind, LowerOptions};
use grid_gen::{reference, Model};
use grid_gen_test_support::*;

/// The f64 tolerance of every other test of the IR and the generated code.
const TOL: f64 = 1e-12;

struct Case {
    name: String,
    model: Model,
    q: Vec<f64>,
    qd: Vec<f64>,
    tau: Vec<f64>,
}

fn cases() -> Vec<Case> {
    let mut rng = Rng(41);
    let mut out = Vec::new();
    let tapered = [(1.0, 1.0), (1e3, 1.0), (1e6, 1.0), (1.0, 1e3), (1e3, 1e3)];
    for (mass, length) in tapered {
        let urdf = tapered_chain_urdf(12, mass, length);
        let model = Model::from_urdf_str("tapered.urdf", &urdf, false)
            .map_err(|e| e.render_plain())
            .unwrap()
            .0;
        let n = model.nv();
        out.push(Case {
            name: format!("12 links, mass ratio {mass:e}, length ratio {length:e}"),
            q: rng.vec(n, -3.0, 3.0),
            qd: rng.vec(n, -1.0, 1.0),
            tau: rng.vec(n, -1e-3, 1e-3),
            model,
        });
    }
    for robot in ["grid_iiwa", "grid_hyq", "ur5"] {
        let model = load(robot);
        let n = model.nv();
        let limits: Vec<(f64, f64)> =
            model.joints.iter().map(|j| j.limit.unwrap_or((-3.1, 3.1))).collect();
        let mut add = |what: &str, q: Vec<f64>, qd: Vec<f64>, tau: Vec<f64>| {
            out.push(Case { name: format!("{robot}, {what}"), model: model.clone(), q, qd, tau })
        };
        add(
            "lower limits",
            limits.iter().map(|l| l.0).collect(),
            rng.vec(n, -1.0, 1.0),
            rng.vec(n, -10.0, 10.0),
        );
        add(
            "upper limits",
            limits.iter().map(|l| l.1).collect(),
            rng.vec(n, -1.0, 1.0),
            rng.vec(n, -10.0, 10.0),
        );
        add(
            "angles up to ±1e3 rad",
            rng.vec(n, -1e3, 1e3),
            rng.vec(n, -1.0, 1.0),
            rng.vec(n, -10.0, 10.0),
        );
        for speed in [1e-8, 1e4] {
            add(
                &format!("speeds {speed:e}"),
                rng.vec(n, -3.0, 3.0),
                rng.vec(n, -speed, speed),
                rng.vec(n, -10.0, 10.0),
            );
        }
    }
    out
}

#[test]
fn forward_dynamics_within_the_conditioning_bound_at_the_extremes() {
    let g = reference::DEFAULT_GRAVITY;
    let kernels = vec![KernelKind::FdGrad];
    eprintln!("| case | cond(M) | τ − c cancellation | q̈ | ∂q̈/∂q | ∂q̈/∂q̇ | bound |");
    for c in cases() {
        let n = c.model.nv();
        let exact = ir::lower(
            &c.model,
            g,
            &LowerOptions { fold: false, kernels: kernels.clone(), ..LowerOptions::default() },
        )
        .unwrap();
        let fast = ir::lower(
            &c.model,
            g,
            &LowerOptions { kernels: kernels.clone(), ..LowerOptions::default() },
        )
        .unwrap();
        let (exact, fast) = (
            exact.function(KernelKind::FdGrad).unwrap(),
            fast.function(KernelKind::FdGrad).unwrap(),
        );
        let args = kernel_args(exact.inputs(), &c.q, &c.qd, &c.tau);
        let truth: Vec<Vec<f64>> = exact
            .eval_as::<grid_gen::numerics::Dd>(&args)
            .into_iter()
            .map(|o| o.into_iter().map(|x| x.to_f64()).collect())
            .collect();
        let got = fast.eval(&args);
        let m = reference::crba(&c.model, &c.q);
        let eig = m.clone().symmetric_eigenvalues();
        let cond = eig.max() / eig.min();
        let qdd = output_matrix(exact.outputs[0].shape, n, &truth[0]);
        let bias = reference::rnea(&c.model, &c.q, &c.qd, &vec![0.0; n], g);
        let amp = ((col(&c.tau).norm() + col(&bias).norm()) / (m.norm() * qdd.norm())).max(1.0);
        let bound = 10.0 * n as f64 * f64::EPSILON * cond * amp;
        let errors: Vec<f64> = exact
            .outputs
            .iter()
            .enumerate()
            .map(|(k, o)| {
                rel_err(&output_matrix(o.shape, n, &got[k]), &output_matrix(o.shape, n, &truth[k]))
            })
            .collect();
        eprintln!(
            "| {} | {cond:.1e} | {amp:.1e} | {:.1e} | {:.1e} | {:.1e} | {bound:.1e} |",
            c.name, errors[0], errors[1], errors[2]
        );
        for (o, e) in exact.outputs.iter().zip(&errors) {
            assert!(
                *e <= TOL.min(bound),
                "{}: {} error {e:.1e} above {:.1e} (cond(M) {cond:.1e})",
                c.name,
                o.name,
                TOL.min(bound)
            );
        }
    }
}

/// Past f64's precision the model says so instead of returning garbage: a chain tapering
/// by 1e6 in mass and length has a tip whose M_ii is 1e-20 of M's largest diagonal entry
/// (cond(M) > 1/ε): a warning located at the joint, and the kernels that need M⁻¹ are
/// not generated.
#[test]
fn a_numerically_singular_mass_matrix_is_named_not_computed() {
    let urdf = tapered_chain_urdf(12, 1e6, 1e6);
    let (model, warnings) =
        Model::from_urdf_str("tapered.urdf", &urdf, false).map_err(|e| e.render_plain()).unwrap();
    assert!(model.singular.is_some());
    assert!(
        warnings.iter().any(|w| w.message.contains("`j12` moves no inertia about its axis")),
        "{warnings:?}"
    );
    let module = ir::lower(&model, reference::DEFAULT_GRAVITY, &LowerOptions::default()).unwrap();
    let kinds: Vec<KernelKind> = module.functions.iter().map(|f| f.kind).collect();
    let lie = [
        KernelKind::Integrate,
        KernelKind::DIntegrate,
        KernelKind::Difference,
        KernelKind::DDifference,
    ];
    assert_eq!(
        kinds,
        [&[KernelKind::Rnea, KernelKind::RneaGrad, KernelKind::MassMatrix][..], &lie].concat()
    );
}
