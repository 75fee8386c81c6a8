//! Coupled mimic joints, beyond the Pinocchio comparison in
//! tests/pinocchio.rs: chains of mimics compose, the coupled dynamics are the independent
//! robot's restricted to the mimic-consistent states (checked here without Pinocchio),
//! and what coupling cannot express is a clear error.

use grid_gen::generate::{generate, Options, Target};
use grid_gen::{reference, MimicMode, Model, Scene};
use grid_gen_test_support::*;
use nalgebra::DMatrix;

const INERTIAL: &str = r#"<inertial><origin xyz="0.05 0.02 0.1" rpy="0.1 0.2 0.3"/><mass value="1"/><inertia ixx="0.1" ixy="0.01" ixz="0" iyy="0.2" iyz="0.02" izz="0.15"/></inertial>"#;

/// base → j (revolute z) → m1 (revolute x) → m2 (prismatic y) → w (revolute y), with the
/// two mimics given by `m1` and `m2`'s `<mimic>` attributes.
fn chain(m1: &str, m2: &str) -> String {
    let link = |n: &str| format!(r#"<link name="{n}">{INERTIAL}</link>"#);
    let joint = |n: &str, kind: &str, p: &str, c: &str, axis: &str, mimic: &str| {
        format!(
            r#"<joint name="{n}" type="{kind}"><parent link="{p}"/><child link="{c}"/><origin xyz="0.1 0 0.2" rpy="0 0.3 0"/><axis xyz="{axis}"/><limit lower="-2" upper="2" effort="1" velocity="1"/>{mimic}</joint>"#
        )
    };
    [
        r#"<robot name="chain"><link name="base"/>"#.to_string(),
        link("a"),
        link("b"),
        link("c"),
        link("d"),
        joint("j", "revolute", "base", "a", "0 0 1", ""),
        joint("m1", "revolute", "a", "b", "1 0 0", m1),
        joint("m2", "prismatic", "b", "c", "0 1 0", m2),
        joint("w", "revolute", "c", "d", "0 1 0", ""),
        "</robot>".into(),
    ]
    .concat()
}

fn coupled(text: &str) -> Model {
    let scene = Scene { mimic: MimicMode::Coupled, ..Scene::default() };
    Model::from_urdf_str_in_scene("chain.urdf", text, false, &scene, "")
        .map_err(|e| e.render_plain())
        .unwrap()
        .0
}

fn coupled_errors(text: &str, scene: &Scene) -> String {
    Model::from_urdf_str_in_scene("chain.urdf", text, false, scene, "")
        .map(|_| ())
        .unwrap_err()
        .render_plain()
}

/// m2 mimics m1 mimics j: m2 = 0.5 (3 q_j + 0.2) − 0.1 = 1.5 q_j. The composed chain is the
/// same model, and the same kernels, as one that names j directly.
#[test]
fn chains_of_mimics_compose() {
    let through = coupled(&chain(
        r#"<mimic joint="j" multiplier="3" offset="0.2"/>"#,
        r#"<mimic joint="m1" multiplier="0.5" offset="-0.1"/>"#,
    ));
    let direct = coupled(&chain(
        r#"<mimic joint="j" multiplier="3" offset="0.2"/>"#,
        r#"<mimic joint="j" multiplier="1.5" offset="0"/>"#,
    ));
    assert_eq!((through.nv(), through.njoints()), (2, 4));
    let c = through.coupling(2).unwrap();
    assert_eq!((c.of, c.multiplier), (0, 1.5));
    assert!(c.offset.abs() < 1e-15, "{}", c.offset);
    let mut rng = Rng(3);
    let g = reference::DEFAULT_GRAVITY;
    for _ in 0..5 {
        let (q, qd, qdd) = (rng.vec(2, -2.0, 2.0), rng.vec(2, -1.0, 1.0), rng.vec(2, -1.0, 1.0));
        let (a, b) = (
            reference::rnea_derivatives(&through, &q, &qd, &qdd, g),
            reference::rnea_derivatives(&direct, &q, &qd, &qdd, g),
        );
        assert!(rel_err(&a.0, &b.0) < 1e-14 && rel_err(&a.1, &b.1) < 1e-14);
        let (a, b) = (
            reference::forward_dynamics_derivatives(&through, &q, &qd, &qdd, g),
            reference::forward_dynamics_derivatives(&direct, &q, &qd, &qdd, g),
        );
        assert!(
            rel_err(&col(&a.0), &col(&b.0)) < 1e-13 && rel_err(&a.1, &b.1) < 1e-12,
            "{:?} {:?}",
            a.0,
            b.0
        );
    }
}

/// Without Pinocchio: at a mimic-consistent state (q_m = k q + o, q̇_m = k q̇, q̈_m = k q̈)
/// the coupled robot's forces are Gᵀ times the independent robot's, its M is Gᵀ M G, and
/// its forward dynamics solve `Gᵀ M G q̈ = τ − Gᵀ c(q, G q̇, 0)` (checked by substituting
/// back, relative to τ's scale). G = the coupling map. Tolerances: f64 recursions of a few
/// dozen terms, 1e-12 relative.
#[test]
fn coupled_dynamics_restrict_the_independent_robot() {
    let text = chain(
        r#"<mimic joint="j" multiplier="-0.7" offset="0.3"/>"#,
        r#"<mimic joint="w" multiplier="0.2" offset="0.05"/>"#,
    );
    let model = coupled(&text);
    let (free, _) = Model::from_urdf_str("chain.urdf", &text, false).unwrap();
    assert_eq!((model.nv(), free.nv()), (2, 4));
    // Coordinates j and w; joints j, m1, m2, w.
    let gmap = DMatrix::from_row_slice(4, 2, &[1.0, 0.0, -0.7, 0.0, 0.0, 0.2, 0.0, 1.0]);
    let expand =
        |x: &[f64], off: [f64; 2]| vec![x[0], -0.7 * x[0] + off[0], 0.2 * x[1] + off[1], x[1]];
    let mut rng = Rng(5);
    let g = reference::DEFAULT_GRAVITY;
    for _ in 0..5 {
        let (q, qd, qdd, tau) = (
            rng.vec(2, -2.0, 2.0),
            rng.vec(2, -1.0, 1.0),
            rng.vec(2, -1.0, 1.0),
            rng.vec(2, -1.0, 1.0),
        );
        let (qf, qdf, qddf) =
            (expand(&q, [0.3, 0.05]), expand(&qd, [0.0; 2]), expand(&qdd, [0.0; 2]));
        let c = col(&reference::rnea(&model, &q, &qd, &qdd, g));
        let want = gmap.transpose() * col(&reference::rnea(&free, &qf, &qdf, &qddf, g));
        assert!(rel_err(&c, &want) < 1e-12, "{c} vs {want}");
        let m = gmap.transpose() * reference::crba(&free, &qf) * &gmap;
        assert!(rel_err(&reference::crba(&model, &q), &m) < 1e-12);
        let (dq, _) = reference::rnea_derivatives(&model, &q, &qd, &qdd, g);
        let (dqf, _) = reference::rnea_derivatives(&free, &qf, &qdf, &qddf, g);
        assert!(rel_err(&dq, &(gmap.transpose() * dqf * &gmap)) < 1e-12);
        let a = col(&reference::forward_dynamics(&model, &q, &qd, &tau, g));
        let bias = gmap.transpose() * col(&reference::rnea(&free, &qf, &qdf, &[0.0; 4], g));
        let residual = &m * &a + bias - col(&tau);
        assert!(
            residual.amax() < 1e-12 * (1.0 + tau.iter().fold(0.0f64, |x, t| x.max(t.abs()))),
            "{residual}"
        );
        assert!(rel_err(&reference::minv(&model, &q), &m.clone().try_inverse().unwrap()) < 1e-12);
    }
}

#[test]
fn what_coupling_cannot_express_is_a_clear_error() {
    let scene = Scene { mimic: MimicMode::Coupled, ..Scene::default() };
    // A mimic of a locked joint: the mimicked joint has no coordinate.
    let mut locked = scene.clone();
    locked.lock.insert("j".into(), 0.1);
    let e = coupled_errors(&chain(r#"<mimic joint="j"/>"#, ""), &locked);
    assert!(e.contains("joint `m1` mimics `j`, which is locked or left out by the scene"), "{e}");
    // A scene's [gradient] naming a coupled joint.
    let mut rows = scene.clone();
    rows.gradient.rows = Some(vec!["m1".into()]);
    let e = coupled_errors(&chain(r#"<mimic joint="j"/>"#, ""), &rows);
    assert!(
        e.contains("[gradient] rows names `m1`, a coupled mimic joint")
            && e.contains("name the joint it follows, `j`"),
        "{e}"
    );
    // The fixed-point datapath cannot take sin/cos of `multiplier · q + offset`: Verilog of
    // such a robot is refused, naming the cause; with multiplier 1 and offset 0 it is not.
    let model = coupled(&chain(r#"<mimic joint="j" multiplier="2"/>"#, ""));
    let verilog = Options { targets: vec![Target::Verilog], ..Options::default() };
    let e = generate(&model, &verilog).unwrap_err().to_string();
    assert!(e.contains("coupled mimic joint with a multiplier or offset"), "{e}");
    let plain = coupled(&chain(r#"<mimic joint="j"/>"#, ""));
    assert!(generate(&plain, &verilog).is_ok());
}
