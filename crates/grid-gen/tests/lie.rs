//! The Lie-group kernels (`integrate`, `dintegrate`, `difference`, `ddifference`): their IR
//! against the reference on fixed, floating, spherical and coupled robots, at the angles
//! where the logarithm is delicate (zero, tiny, near a half turn, a quaternion of the other
//! sign), `difference` undoing `integrate`, and the generated Rust compiled and run. The
//! reference is held to Pinocchio 4.1 in `python/tests` (`test_lie_group_kernels_*`).

use grid_gen::ir::{self, KernelKind, LowerOptions};
use grid_gen::{reference, Model};
use grid_gen_test_support::*;

/// The kernels and the reference compute the same f64 quantities by other routes (halving
/// the angle and forward mode against `atan2`, an LU solve and a matrix inverse): each
/// step is exact to rounding, so they agree to a few hundred ulps of the largest entry.
const TOL: f64 = 1e-12;

const LIE: [KernelKind; 4] = [
    KernelKind::Integrate,
    KernelKind::DIntegrate,
    KernelKind::Difference,
    KernelKind::DDifference,
];

fn cases() -> Vec<(&'static str, Model)> {
    let fixtures = repo().join("tests/fixtures");
    vec![
        ("iiwa", load("grid_iiwa")),
        ("hyq floating", load_floating("grid_hyq")),
        ("ball_arm floating", load_urdf(&fixtures.join("ball_arm.urdf"), true)),
        ("mimic_arm coupled", load_coupled_urdf(&fixtures.join("mimic_arm.urdf"))),
    ]
}

/// A random configuration: joint angles in [-3, 3], a random base pose and unit
/// quaternions on the spherical joints.
fn random_q(m: &Model, rng: &mut Rng) -> Vec<f64> {
    let mut q = m.q_from_joints(&rng.vec(m.nv(), -3.0, 3.0), rng.base_pose());
    for &s in &m.spherical {
        let at = m.group_q(s).0;
        q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
    }
    q
}

/// Each rotation block's tangent scaled to the angle `theta` (the scalar coordinates and
/// the base's translation keep `v`'s entries).
fn with_angle(m: &Model, v: &[f64], theta: f64) -> Vec<f64> {
    let mut v = v.to_vec();
    for block in m.lie_blocks() {
        let at = match block {
            grid_gen::model::LieBlock::FreeFlyer => 3,
            grid_gen::model::LieBlock::Spherical { v, .. } => v,
            grid_gen::model::LieBlock::Scalar { .. } => continue,
        };
        let n = v[at..at + 3].iter().map(|x| x * x).sum::<f64>().sqrt();
        v[at..at + 3].iter_mut().for_each(|x| *x *= theta / n);
    }
    v
}

/// Every quaternion of `q` negated: the same rotations.
fn flipped(m: &Model, q: &[f64]) -> Vec<f64> {
    let mut q = q.to_vec();
    for block in m.lie_blocks() {
        let at = match block {
            grid_gen::model::LieBlock::FreeFlyer => 3,
            grid_gen::model::LieBlock::Spherical { q, .. } => q,
            grid_gen::model::LieBlock::Scalar { .. } => continue,
        };
        q[at..at + 4].iter_mut().for_each(|x| *x = -*x);
    }
    q
}

#[test]
fn lie_group_kernels_match_the_reference() {
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(2026);
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for (name, model) in cases() {
        let options = LowerOptions { kernels: LIE.to_vec(), ..LowerOptions::default() };
        let module = ir::lower(&model, g, &options).unwrap();
        assert_eq!(module.functions.len(), 4, "{name}: every robot has the four kernels");
        let nv = model.nv();
        // Rotation angles of the tangent between q and q1: none, tiny, ordinary, near a
        // half turn (the logarithm's far end), and a random draw with q1's quaternions of
        // the other sign.
        for (case, theta) in
            [(0, 0.0), (1, 1e-9), (2, 0.7), (3, 3.1), (4, std::f64::consts::PI - 1e-6), (5, 2.0)]
        {
            let q = random_q(&model, &mut rng);
            let v = with_angle(&model, &rng.vec(nv, -2.0, 2.0), theta);
            let v = if case == 0 { vec![0.0; nv] } else { v };
            let q1 = reference::integrate(&model, &q, &v);
            let q1 = if case == 5 { flipped(&model, &q1) } else { q1 };
            for f in &module.functions {
                let got = f.eval(&kernel_args(f.inputs(), &q, &v, &q1));
                let want = reference_outputs(f.kind, &model, &q, &v, &q1, g);
                for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                    let got = output_matrix(o.shape, nv, got);
                    // At v = 0 the differences are zeros, to be met to rounding absolutely.
                    let e = if case == 0 { (&got - want).amax() } else { rel_err(&got, want) };
                    worst = worst.max(e);
                    checked += 1;
                    assert!(
                        e < TOL,
                        "{name} θ = {theta} {}.{}: {e:.2e}\n{got:?}\n{want}",
                        f.kind,
                        o.name
                    );
                }
            }
            // difference undoes integrate (angles below π).
            let back = reference::difference(&model, &q, &q1);
            let e = if case == 0 { col(&back).amax() } else { rel_err(&col(&back), &col(&v)) };
            assert!(e < TOL, "{name} θ = {theta}: difference(q, q ⊕ v) is {e:.2e} from v");
        }
    }
    println!("{checked} Lie-group outputs, worst {worst:.2e} from the reference (bound {TOL:e})");
}

/// The generated Rust of a floating robot with a spherical joint, compiled with rustc and
/// run (both copies): the four kernels on four states against the reference.
#[test]
fn lie_group_kernels_compile_and_match_the_reference() {
    use grid_gen::generate::{generate, Options, Target};
    let model = load_urdf(&repo().join("tests/fixtures/ball_arm.urdf"), true);
    let lower = LowerOptions { kernels: LIE.to_vec(), ..LowerOptions::default() };
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    let (nq, nv) = (model.nq(), model.nv());
    // Each state: q and q1 from the seeded joints, unit quaternions made by normalising
    // their entries, and the tangent v.
    let state = |k: usize, salt: usize| -> Vec<f64> {
        let mut q: Vec<f64> = (0..nq).map(|i| seeded_state(k, i, salt)).collect();
        for at in quaternion_starts(&model) {
            let n = q[at..at + 4].iter().map(|x| x * x).sum::<f64>().sqrt();
            q[at..at + 4].iter_mut().for_each(|x| *x /= n);
        }
        q
    };
    let starts = format!("{:?}", quaternion_starts(&model));
    let said = compile_and_run(
        "lie",
        &file.contents,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            &format!(
                r#"fn config(k: usize, salt: usize) -> [f64; NQ] {{
    let mut q: [f64; NQ] = std::array::from_fn(|i| state(k, i, salt));
    for at in {starts} {{
        let n = q[at..at + 4].iter().map(|x| x * x).sum::<f64>().sqrt();
        q[at..at + 4].iter_mut().for_each(|x| *x /= n);
    }}
    q
}}
fn main() {{
    for k in 0..4 {{
        let (q, q1) = (config(k, 0), config(k, 1));
        let v: [f64; NV] = std::array::from_fn(|i| state(k, i, 2));
        for fma in [false, true] {{
            if fma && !has_fma() {{ continue; }}
            let (a, (b, c), d, (e, f)) = if fma {{
                unsafe {{ (fma::integrate(&q, &v), fma::dintegrate(&q, &v), fma::difference(&q, &q1), fma::ddifference(&q, &q1)) }}
            }} else {{
                (portable::integrate(&q, &v), portable::dintegrate(&q, &v), portable::difference(&q, &q1), portable::ddifference(&q, &q1))
            }};
            let all: Vec<String> = a.iter().chain(b.as_flattened()).chain(c.as_flattened()).chain(&d).chain(e.as_flattened()).chain(f.as_flattened()).map(|x| format!("{{x:?}}")).collect();
            println!("{{}}", all.join(" "));
        }}
    }}
}}
"#
            ),
        ]
        .concat(),
    );
    let lines = said.lines().count();
    assert!(lines >= 4, "one line per state and copy:\n{said}");
    let worst = worst_line_error(&said, lines, 0, TOL, |line, _| {
        let k = if lines == 8 { line / 2 } else { line };
        let (q, q1) = (state(k, 0), state(k, 1));
        let v: Vec<f64> = (0..nv).map(|i| seeded_state(k, i, 2)).collect();
        let g = reference::DEFAULT_GRAVITY;
        LIE.iter()
            .flat_map(|&kind| {
                reference_outputs(kind, &model, &q, &v, &q1, g)
                    .into_iter()
                    .flat_map(|m| m.transpose().as_slice().to_vec())
            })
            .collect()
    });
    println!("ball_arm floating Lie-group kernels, compiled: worst {worst:.2e} (bound {TOL:e})");
}

/// Where each unit quaternion of q starts: the base's, then the spherical joints'.
fn quaternion_starts(m: &Model) -> Vec<usize> {
    m.lie_blocks()
        .into_iter()
        .filter_map(|b| match b {
            grid_gen::model::LieBlock::FreeFlyer => Some(3),
            grid_gen::model::LieBlock::Spherical { q, .. } => Some(q),
            grid_gen::model::LieBlock::Scalar { .. } => None,
        })
        .collect()
}

/// `eval` gives `integrate` and `difference` where a state has `v` and `q1`, and names
/// `q1` in its errors as it names `q`.
#[test]
fn eval_gives_the_lie_group_operations_and_checks_q1() {
    use grid_gen::eval::{evaluate, parse_states, EvalError};
    let model = load_urdf(&repo().join("tests/fixtures/ball_arm.urdf"), true);
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(58);
    let (q, q1) = (random_q(&model, &mut rng), random_q(&model, &mut rng));
    let v = rng.vec(model.nv(), -1.0, 1.0);
    let json = |q1: &[f64]| {
        format!(
            r#"{{"states": [{{"q": {q:?}, "qd": {qd:?}, "v": {v:?}, "q1": {q1:?}}}, {{"q": {q:?}, "qd": {qd:?}}}]}}"#,
            qd = vec![0.0; model.nv()]
        )
    };
    let out = evaluate(&model, &parse_states(&json(&q1)).unwrap(), g).unwrap();
    let (i, d) =
        (out.states[0].integrate.as_ref().unwrap(), out.states[0].difference.as_ref().unwrap());
    // eval reads q's quaternions normalised (see tests/floating.rs): equal to rounding.
    let close = |a: &[f64], b: &[f64]| rel_err(&col(a), &col(b)) < 1e-14;
    assert!(close(&i.q_next, &reference::integrate(&model, &q, &v)));
    assert!(close(&d.v, &reference::difference(&model, &q, &q1)));
    let (dq, dq1) = reference::d_difference(&model, &q, &q1);
    assert!(
        (d.dq[1][2] - dq[(1, 2)]).abs() < 1e-14 && (d.dq1[4][3] - dq1[(4, 3)]).abs() < 1e-14,
        "row-major"
    );
    assert!(out.states[1].integrate.is_none() && out.states[1].difference.is_none());
    let mut bad = q1.clone();
    bad[3..7].copy_from_slice(&[0.0; 4]);
    let e = evaluate(&model, &parse_states(&json(&bad)).unwrap(), g).unwrap_err();
    assert!(matches!(e, EvalError::Quaternion { index: 0, field: "q1", .. }), "{e}");
    assert!(e.to_string().contains("`q1[3..7]`"), "{e}");
    let e = evaluate(&model, &parse_states(&json(&q1[..q1.len() - 1])).unwrap(), g).unwrap_err();
    assert!(e.to_string().contains("`q1` has"), "{e}");
}
