//! Helpers shared by every test crate of grid-gen: the bundled robots, the fixtures,
//! the error norm and a seeded generator.

use std::path::PathBuf;

use grid_gen::ir::{Input, KernelKind, Shape};
use grid_gen::{reference, Model};
use nalgebra::DMatrix;

/// The repository root (fixtures and robots live there, not in the crate).
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..").canonicalize().expect("repository root")
}

/// Every robot in `robots/`, by file stem.
pub fn robots() -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(repo().join("robots"))
        .expect("robots/ exists")
        .filter_map(|e| {
            let p = e.ok()?.path();
            if p.extension()? != "urdf" {
                return None;
            }
            Some(p.file_stem()?.to_string_lossy().into_owned())
        })
        .collect();
    names.sort();
    names
}

/// The URDF of a serial chain of `n` equal links (1 kg, 0.1 m), axes cycling x, y, z:
/// cond(M) grows quickly with `n`, and so does every graph.
pub fn chain_urdf(n: usize) -> String {
    let mut s = String::from("<robot name=\"chain\"><link name=\"l0\"/>");
    for i in 1..=n {
        let axis = ["1 0 0", "0 1 0", "0 0 1"][i % 3];
        s.push_str(&format!(
            "<link name=\"l{i}\"><inertial><origin xyz=\"0 0 0.05\"/><mass value=\"1\"/><inertia ixx=\"0.01\" ixy=\"0\" ixz=\"0\" iyy=\"0.01\" iyz=\"0\" izz=\"0.01\"/></inertial></link>\
             <joint name=\"j{i}\" type=\"revolute\"><parent link=\"l{}\"/><child link=\"l{i}\"/><origin xyz=\"0 0 0.1\"/><axis xyz=\"{axis}\"/><limit lower=\"-3\" upper=\"3\" effort=\"1\" velocity=\"1\"/></joint>",
            i - 1
        ));
    }
    s.push_str("</robot>");
    s
}

/// A serial chain of `n` links tapering geometrically from the root to the tip: mass from
/// 1 kg down to 1/`mass_ratio`, length from 0.1 m down to 0.1/`length_ratio` (slender
/// rods, centre of mass mid-link, axes cycling x, y, z). cond(M) grows with both ratios:
/// the near-singular M of the extremes suite (`tests/extremes.rs`).
pub fn tapered_chain_urdf(n: usize, mass_ratio: f64, length_ratio: f64) -> String {
    let mut s = String::from("<robot name=\"tapered\"><link name=\"l0\"/>");
    let (mut parent_length, span) = (0.1, (n.max(2) - 1) as f64);
    for i in 1..=n {
        let t = (i - 1) as f64 / span;
        let (m, l) = (mass_ratio.powf(-t), 0.1 * length_ratio.powf(-t));
        let (axial, transverse) = (m * l * l / 1200.0, m * l * l / 12.0);
        let axis = ["1 0 0", "0 1 0", "0 0 1"][i % 3];
        s.push_str(&format!(
            "<link name=\"l{i}\"><inertial><origin xyz=\"0 0 {:e}\"/><mass value=\"{m:e}\"/><inertia ixx=\"{transverse:e}\" ixy=\"0\" ixz=\"0\" iyy=\"{transverse:e}\" iyz=\"0\" izz=\"{axial:e}\"/></inertial></link>\
             <joint name=\"j{i}\" type=\"revolute\"><parent link=\"l{}\"/><child link=\"l{i}\"/><origin xyz=\"0 0 {parent_length:e}\"/><axis xyz=\"{axis}\"/><limit lower=\"-3\" upper=\"3\" effort=\"1\" velocity=\"1\"/></joint>",
            l / 2.0,
            i - 1
        ));
        parent_length = l;
    }
    s.push_str("</robot>");
    s
}

/// A bundled robot in a scene of `examples/scenes/`, with the scene (its source names
/// both files, as `grid-gen --scene` writes it).
pub fn load_in_scene(robot: &str, scene: &str) -> (Model, grid_gen::Scene) {
    let scene_file = format!("{scene}.toml");
    let text = std::fs::read_to_string(repo().join("examples/scenes").join(&scene_file))
        .expect("scene file");
    let parsed = grid_gen::Scene::parse(&scene_file, &text).unwrap_or_else(|e| panic!("{e}"));
    let path = repo().join("robots").join(format!("{robot}.urdf"));
    let urdf = std::fs::read_to_string(&path).expect("robot file");
    let model = Model::from_urdf_str_in_scene(
        &path.display().to_string(),
        &urdf,
        false,
        &parsed,
        &scene_file,
    )
    .map_err(|e| e.render_plain())
    .expect("scene loads")
    .0;
    (model, parsed)
}

/// A bundled robot in a scene given as TOML text (named `s.toml` in messages): the model,
/// or the rendered error.
pub fn load_scene_text(robot: &str, scene: &str) -> Result<Model, String> {
    let urdf = repo().join("robots").join(format!("{robot}.urdf"));
    let text = std::fs::read_to_string(&urdf).expect("robot file");
    let scene = grid_gen::Scene::parse("s.toml", scene).expect("the scene parses");
    Model::from_urdf_str_in_scene(
        &urdf.display().to_string(),
        &text,
        scene.floating_base,
        &scene,
        "s.toml",
    )
    .map(|l| l.0)
    .map_err(|e| e.render_plain())
}

pub fn load(robot: &str) -> Model {
    let path = repo().join("robots").join(format!("{robot}.urdf"));
    let text = std::fs::read_to_string(&path).expect("robot file");
    Model::from_urdf_str(&path.display().to_string(), &text, false)
        .map_err(|e| e.render_plain())
        .expect("bundled robots load")
        .0
}

/// A bundled robot on a floating base (`--floating-base`).
pub fn load_floating(robot: &str) -> Model {
    load_floating_urdf(&repo().join("robots").join(format!("{robot}.urdf")))
}

/// The robot of a URDF file on a floating base (`--floating-base`).
pub fn load_floating_urdf(path: &std::path::Path) -> Model {
    let text = std::fs::read_to_string(path).expect("robot file");
    let scene = grid_gen::Scene { floating_base: true, ..grid_gen::Scene::default() };
    Model::from_urdf_str_in_scene(&path.display().to_string(), &text, false, &scene, "")
        .map_err(|e| e.render_plain())
        .expect("the robot loads")
        .0
}

/// The robot of a URDF file, on a fixed base or a floating one.
pub fn load_urdf(path: &std::path::Path, floating_base: bool) -> Model {
    let text = std::fs::read_to_string(path).expect("robot file");
    let scene = grid_gen::Scene { floating_base, ..grid_gen::Scene::default() };
    Model::from_urdf_str_in_scene(&path.display().to_string(), &text, false, &scene, "")
        .map_err(|e| e.render_plain())
        .expect("the robot loads")
        .0
}

/// A URDF with its mimic joints coupled (`--mimic coupled`).
pub fn load_coupled_urdf(path: &std::path::Path) -> Model {
    let text = std::fs::read_to_string(path).expect("robot file");
    let scene =
        grid_gen::Scene { mimic: grid_gen::MimicMode::Coupled, ..grid_gen::Scene::default() };
    Model::from_urdf_str_in_scene(&path.display().to_string(), &text, false, &scene, "")
        .map_err(|e| e.render_plain())
        .expect("the robot loads")
        .0
}

pub fn fixture(name: &str) -> serde_json::Value {
    let path = repo().join("tests/fixtures").join(name);
    serde_json::from_str(
        &std::fs::read_to_string(&path)
            .unwrap_or_else(|e| panic!("{}: {e} (run scripts/make_fixtures.py)", path.display())),
    )
    .expect("fixture JSON")
}

/// `perm[k]`: the model's coordinate index of the k-th coordinate a fixture lists in
/// `joint_names` (fixtures keep their tool's joint order, matched here by name).
pub fn fixture_perm(model: &Model, fx: &serde_json::Value, label: &str) -> Vec<usize> {
    let coordinates: Vec<&str> =
        model.coordinate_joints().into_iter().map(|i| model.joint(i).name.as_str()).collect();
    fx["joint_names"]
        .as_array()
        .expect("joint_names")
        .iter()
        .map(|n| n.as_str().expect("a name"))
        .map(|n| {
            coordinates
                .iter()
                .position(|c| *c == n)
                .unwrap_or_else(|| panic!("{label}: no coordinate {n}"))
        })
        .collect()
}

/// Compiles `main_rs` (which includes `robot.rs`, written from `robot_rs`) with rustc as the
/// tests do (`-C opt-level=1`, warnings denied), runs it, and returns what it printed; a
/// failed build or run fails the test with rustc's or the program's message.
pub fn compile_and_run(label: &str, robot_rs: &str, main_rs: &str) -> String {
    let dir = std::env::temp_dir().join(format!("grid-gen-{label}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("robot.rs"), robot_rs).unwrap();
    std::fs::write(dir.join("main.rs"), main_rs).unwrap();
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let exe = dir.join(format!("{label}_check"));
    let out = std::process::Command::new(rustc)
        .args([
            "--edition",
            "2021",
            "-C",
            "opt-level=1",
            "-C",
            "debuginfo=0",
            "-D",
            "warnings",
            "-o",
        ])
        .arg(&exe)
        .arg(dir.join("main.rs"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let run = std::process::Command::new(&exe).output().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    String::from_utf8_lossy(&run.stdout).into_owned()
}

/// A state entry in [-1.5, 1.5) for state `k`, entry `i` and input `salt`: the same numbers
/// the compiled test programs draw with [`SEEDED_STATE_RS`], so a test can rebuild the
/// states a program ran on.
pub fn seeded_state(k: usize, i: usize, salt: usize) -> f64 {
    (((k * 7919 + i * 104_729 + salt * 15_485_863) % 2001) as f64 / 1000.0) * 3.0 - 1.5
}

/// [`seeded_state`] as `fn state` in a compiled test program's source.
pub const SEEDED_STATE_RS: &str = "fn state(k: usize, i: usize, salt: usize) -> f64 { (((k * 7919 + i * 104_729 + salt * 15_485_863) % 2001) as f64 / 1000.0) * 3.0 - 1.5 }\n";

/// A compiled program's output, one line of space-separated numbers per state, against
/// `want(k)` (state k's expected values, after the first `skip` printed ones): the worst
/// relative error, each state's held below `bound`, with `lines` states printed.
pub fn worst_line_error(
    said: &str,
    lines: usize,
    skip: usize,
    bound: f64,
    mut want: impl FnMut(usize, &[f64]) -> Vec<f64>,
) -> f64 {
    let mut worst: f64 = 0.0;
    for (k, line) in said.lines().enumerate() {
        let got: Vec<f64> = line.split(' ').map(|x| x.parse().unwrap()).collect();
        let expected = want(k, &got[..skip]);
        assert_eq!(got.len() - skip, expected.len(), "state {k}: values printed");
        let e = rel_err(&col(&got[skip..]), &col(&expected));
        worst = worst.max(e);
        assert!(e < bound, "state {k}: {e:.2e}");
    }
    assert_eq!(said.lines().count(), lines, "states printed");
    worst
}

pub fn vec_of(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().expect("array").iter().map(|x| x.as_f64().expect("number")).collect()
}

pub fn mat_of(v: &serde_json::Value) -> DMatrix<f64> {
    let rows: Vec<Vec<f64>> = v.as_array().expect("array").iter().map(vec_of).collect();
    let n = rows.len();
    let m = rows.first().map_or(0, |r| r.len());
    DMatrix::from_fn(n, m, |i, j| rows[i][j])
}

/// ‖a − b‖_max / ‖b‖_max: the relative error in the max-abs norm used by every test.
pub fn rel_err(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    assert_eq!(a.shape(), b.shape());
    let scale = b.amax();
    let diff = (a - b).amax();
    if scale == 0.0 {
        diff
    } else {
        diff / scale
    }
}

pub fn col(v: &[f64]) -> DMatrix<f64> {
    DMatrix::from_column_slice(v.len(), 1, v)
}

/// The library's seeded generator, so tests and `accuracy --random` draw alike.
pub use grid_gen::accuracy::Rng;

/// The reference's values of kernel `kind`, in the kernel's output order; `u` is q̈ for
/// the RNEA kernels, τ for the forward-dynamics ones, the actuated joints' τ (nu
/// entries) for the step kernels and `difference`'s q1 (nq entries); `integrate`'s v is
/// `qd`.
pub fn reference_outputs(
    kind: KernelKind,
    model: &Model,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
    g: [f64; 3],
) -> Vec<DMatrix<f64>> {
    match kind {
        KernelKind::Rnea => vec![col(&reference::rnea(model, q, qd, u, g))],
        KernelKind::RneaGrad => {
            let (a, b) = reference::rnea_derivatives(model, q, qd, u, g);
            vec![a, b]
        }
        KernelKind::MassMatrix => vec![reference::crba(model, q)],
        KernelKind::Minv => vec![reference::minv(model, q)],
        KernelKind::Fd => vec![col(&reference::forward_dynamics(model, q, qd, u, g))],
        KernelKind::FdGrad => {
            let (a, b, c) = reference::forward_dynamics_derivatives(model, q, qd, u, g);
            vec![col(&a), b, c]
        }
        KernelKind::Step
        | KernelKind::StepGrad
        | KernelKind::ContactFd
        | KernelKind::ContactFdGrad => {
            reference_outputs_with(kind, model, q, qd, u, g, reference::External::NONE)
        }
        KernelKind::Integrate => vec![col(&reference::integrate(model, q, qd))],
        KernelKind::DIntegrate => {
            let (a, b) = reference::d_integrate(model, qd);
            vec![a, b]
        }
        KernelKind::Difference => vec![col(&reference::difference(model, q, u))],
        KernelKind::DDifference => {
            let (a, b) = reference::d_difference(model, q, u);
            vec![a, b]
        }
        _ => reference_frames(kind, model, q, qd, u).iter().map(|v| col(v)).collect(),
    }
}

/// The reference's values of a dynamics kernel under forces, in its output order (the
/// force derivatives after the usual outputs, when the model declares the forces).
pub fn reference_outputs_with(
    kind: KernelKind,
    m: &Model,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
    g: [f64; 3],
    ext: reference::External,
) -> Vec<DMatrix<f64>> {
    if kind.is_step() {
        let dt = m.specialisation.step.and_then(|s| s.dt);
        let dt = dt.expect("a folded dt (reference_step_outputs takes a run-time one)");
        return reference_step_outputs(kind, m, q, qd, u, g, ext.fext, dt);
    }
    let d = reference::force_derivatives(m, q);
    let mut out = match kind {
        KernelKind::Rnea => vec![col(&reference::rnea_with(m, q, qd, u, g, ext))],
        KernelKind::RneaGrad => {
            let (a, b) = reference::rnea_derivatives_with(m, q, qd, u, g, ext);
            vec![a, b]
        }
        KernelKind::Fd => vec![col(&reference::aba_with(m, q, qd, u, g, ext))],
        KernelKind::FdGrad => {
            let (a, b, c) = reference::forward_dynamics_derivatives_with(m, q, qd, u, g, ext);
            vec![col(&a), b, c]
        }
        KernelKind::ContactFd | KernelKind::ContactFdGrad => {
            let (s, d) = reference::contact_fd_derivatives(m, q, qd, u, g, ext.fext)
                .expect("independent contacts");
            let mut out = vec![col(&s.qdd), col(&s.lambda)];
            if kind == KernelKind::ContactFdGrad {
                out.extend([
                    d.dqdd_dq,
                    d.dqdd_dqd,
                    d.dqdd_dtau,
                    d.dlambda_dq,
                    d.dlambda_dqd,
                    d.dlambda_dtau,
                ]);
            }
            return out;
        }
        _ => unreachable!(),
    };
    let (by_fext, by_lambda) = match kind {
        KernelKind::RneaGrad => (d.dc_dfext, d.dc_dlambda),
        KernelKind::FdGrad => (d.dqdd_dfext, d.dqdd_dlambda),
        _ => return out,
    };
    if m.nfext() > 0 {
        out.push(by_fext);
    }
    if m.nlambda() > 0 {
        out.push(by_lambda);
    }
    out
}

/// The reference's values of a step kernel, in its output order, over a step of `dt`
/// seconds (a folded step's own dt, or a run-time one): the step solves its contacts'
/// forces and holds `fext`.
#[allow(clippy::too_many_arguments)]
pub fn reference_step_outputs(
    kind: KernelKind,
    m: &Model,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
    g: [f64; 3],
    fext: &[f64],
    dt: f64,
) -> Vec<DMatrix<f64>> {
    let step = m.specialisation.step.expect("a model with a step").at(dt);
    let tau = actuated_tau(m, u);
    // With contacts, the forces at (q, q̇) follow the state (and the linearisation).
    let lambda = (!m.specialisation.contacts.is_empty()).then(|| {
        reference::step_lambda(m, q, qd, &tau, g, &m.actuated(), fext)
            .expect("independent contacts")
    });
    if kind == KernelKind::Step {
        let (q1, v1) =
            reference::step(m, q, qd, &tau, g, step, fext).expect("independent contacts");
        return [col(&q1), col(&v1)].into_iter().chain(lambda.map(|l| col(&l.0))).collect();
    }
    let d = reference::step_derivatives(m, q, qd, &tau, g, step, &m.actuated(), fext)
        .expect("independent contacts");
    // ∂λ/∂u as output_matrix shapes it: a column, row-major.
    let lambda =
        lambda.into_iter().flat_map(|(l, dx, du)| [col(&l), dx, col(du.transpose().as_slice())]);
    [col(&d.q_next), col(&d.qd_next), d.a, d.b].into_iter().chain(lambda).collect()
}

/// τ per coordinate from the actuated joints' forces (0 on the others).
pub fn actuated_tau(model: &Model, u: &[f64]) -> Vec<f64> {
    let mut tau = vec![0.0; model.nv()];
    for (&c, &t) in model.actuated().iter().zip(u) {
        tau[c] = t;
    }
    tau
}

/// A model that takes a step of `dt` seconds, folded into the kernels.
pub fn with_step(model: &Model, scheme: grid_gen::model::Scheme, dt: f64) -> Model {
    let mut m = model.clone();
    m.specialisation.step = Some(grid_gen::model::StepSpec::folded(scheme, dt));
    m
}

/// Floating HyQ standing on its four lower legs as point contacts, with the semi-implicit
/// step over 10 ms folded in: the contact step the tests lower, count and run on wgpu.
pub fn hyq_standing_step() -> Model {
    use grid_gen::model::{ContactKind, Scheme};
    let feet = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .map(|l| (l, ContactKind::Point));
    with_step(&with_forces(&load_floating("grid_hyq"), &[], &feet), Scheme::SemiImplicitEuler, 0.01)
}

/// A model whose step kernels take their time step at run time.
pub fn with_runtime_step(model: &Model, scheme: grid_gen::model::Scheme) -> Model {
    let mut m = model.clone();
    m.specialisation.step = Some(grid_gen::model::StepSpec::at_run_time(scheme));
    m
}

/// The reference's values of a frame kernel's outputs, flat in the kernel's layout (per
/// frame: translation and row-major rotation; the row-major 6 × nv Jacobian; the velocity;
/// the classical acceleration), for the model's selected frames and reference frame.
pub fn reference_frames(
    kind: KernelKind,
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
) -> Vec<Vec<f64>> {
    let rf = model.specialisation.reference;
    let frames: Vec<_> = model.selected_frames().collect();
    match kind {
        KernelKind::FramePlacement => {
            let (mut t, mut r) = (Vec::new(), Vec::new());
            for f in &frames {
                let (rot, p) = reference::frame_placement(model, q, f);
                t.extend(p.iter());
                r.extend((0..9).map(|k| rot[(k / 3, k % 3)]));
            }
            vec![t, r]
        }
        KernelKind::FrameJacobian => {
            let nv = model.nv();
            let j = frames
                .iter()
                .flat_map(|f| {
                    let j = reference::frame_jacobian(model, q, f, rf);
                    (0..6 * nv).map(move |k| j[(k / nv, k % nv)])
                })
                .collect();
            vec![j]
        }
        KernelKind::FrameVelocity => vec![frames.iter().flat_map(|f| reference::frame_velocity(model, q, qd, f, rf)).collect()],
        KernelKind::FrameAcceleration => vec![frames.iter().flat_map(|f| reference::frame_classical_acceleration(model, q, qd, qdd, f, rf)).collect()],
        _ => panic!("{kind} has no reference (frame_acceleration_grad is checked against central differences in tests/frames.rs)"),
    }
}

/// A model with frames selected (by link name), in one reference frame.
pub fn with_frames(model: &Model, names: &[&str], rf: grid_gen::model::ReferenceFrame) -> Model {
    let mut m = model.clone();
    m.specialisation.frames =
        names.iter().map(|n| m.frame(n).unwrap_or_else(|| panic!("no frame {n}"))).collect();
    m.specialisation.reference = rf;
    m
}

/// A kernel's arguments in its order, from q, q̇ and u (q̈ or τ, whichever it takes).
pub fn kernel_args<'a>(
    inputs: &[Input],
    q: &'a [f64],
    qd: &'a [f64],
    u: &'a [f64],
) -> Vec<&'a [f64]> {
    kernel_args_with(inputs, q, qd, u, reference::External::NONE)
}

/// [`kernel_args`] for a kernel that may also take external forces and contact forces.
pub fn kernel_args_with<'a>(
    inputs: &[Input],
    q: &'a [f64],
    qd: &'a [f64],
    u: &'a [f64],
    ext: reference::External<'a>,
) -> Vec<&'a [f64]> {
    assert!(!inputs.contains(&Input::Dt), "a run-time step's kernel: use kernel_args_dt");
    kernel_args_dt(inputs, q, qd, u, ext, &[])
}

/// [`kernel_args_with`] for a step kernel that may also take its time step (`dt`, one
/// value).
pub fn kernel_args_dt<'a>(
    inputs: &[Input],
    q: &'a [f64],
    qd: &'a [f64],
    u: &'a [f64],
    ext: reference::External<'a>,
    dt: &'a [f64],
) -> Vec<&'a [f64]> {
    assert!(!inputs.contains(&Input::Active), "a masked kernel: use kernel_args_masked");
    kernel_args_masked(inputs, q, qd, u, ext, dt, &[])
}

/// [`kernel_args_dt`] for a kernel that may also take a contact mask (`active`, one 0 or
/// 1 per contact).
pub fn kernel_args_masked<'a>(
    inputs: &[Input],
    q: &'a [f64],
    qd: &'a [f64],
    u: &'a [f64],
    ext: reference::External<'a>,
    dt: &'a [f64],
    active: &'a [f64],
) -> Vec<&'a [f64]> {
    assert!(!inputs.contains(&Input::Gains), "a stabilised kernel: use kernel_args_corrected");
    kernel_args_corrected(inputs, q, qd, u, ext, dt, active, reference::Baumgarte::NONE)
}

/// [`kernel_args_masked`] for a kernel that may also take Baumgarte gains and references.
#[allow(clippy::too_many_arguments)]
pub fn kernel_args_corrected<'a>(
    inputs: &[Input],
    q: &'a [f64],
    qd: &'a [f64],
    u: &'a [f64],
    ext: reference::External<'a>,
    dt: &'a [f64],
    active: &'a [f64],
    corr: reference::Baumgarte<'a>,
) -> Vec<&'a [f64]> {
    inputs
        .iter()
        .map(|i| match i {
            Input::Q => q,
            Input::Qd | Input::V => qd,
            Input::Qdd | Input::Tau | Input::TauActuated | Input::Q1 => u,
            Input::Fext => ext.fext,
            Input::Lambda => ext.lambda,
            Input::Dt => dt,
            Input::Active => active,
            Input::Gains => corr.gains,
            Input::ContactRef => corr.refs,
            // Only a step kernel's rest takes the callee's outputs; no kernel's arguments do.
            Input::Called(_) => &[],
        })
        .collect()
}

/// The reference's values of a contact or step kernel of a masked model `m` at the mask
/// `active`: those of the model holding just the active contacts, with λ's rows of the
/// inactive ones 0 (in the kernel's output order and λ's full layout).
#[allow(clippy::too_many_arguments)]
pub fn reference_masked_outputs(
    kind: KernelKind,
    m: &Model,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
    g: [f64; 3],
    fext: &[f64],
    dt: f64,
    active: &[bool],
) -> Vec<DMatrix<f64>> {
    let held = m.holding_contacts(active);
    let mut got = if kind.is_step() {
        reference_step_outputs(kind, &held, q, qd, u, g, fext, dt)
    } else {
        let ext = reference::External { fext, lambda: &[] };
        reference_outputs_with(kind, &held, q, qd, u, g, ext)
    };
    // With no contact held, the step has no λ outputs: each is 0 rows of its columns.
    let nv = m.nv();
    for o in &kind.outputs_for(&m.specialisation)[got.len()..] {
        let cols = if o.shape == Shape::LambdaByState { 2 * nv } else { 1 };
        got.push(DMatrix::zeros(0, cols));
    }
    // λ's rows: the active contacts' in order, zeros for the others.
    let rows: Vec<Option<usize>> = {
        let mut at = 0;
        m.specialisation
            .contacts
            .iter()
            .zip(active)
            .flat_map(|(c, &a)| {
                let start = at;
                if a {
                    at += c.kind.dim();
                }
                (0..c.kind.dim()).map(move |k| a.then_some(start + k))
            })
            .collect()
    };
    let outputs = kind.outputs_for(&m.specialisation);
    got.into_iter()
        .zip(&outputs)
        .map(|(x, o)| match o.shape {
            Shape::Lambda | Shape::LambdaBy | Shape::LambdaByState => {
                DMatrix::from_fn(rows.len(), x.ncols(), |r, c| rows[r].map_or(0.0, |r| x[(r, c)]))
            }
            Shape::LambdaByInput => {
                let nu = m.actuated().len();
                DMatrix::from_fn(rows.len() * nu, 1, |i, _| {
                    rows[i / nu.max(1)].map_or(0.0, |r| x[(r * nu + i % nu.max(1), 0)])
                })
            }
            _ => x,
        })
        .collect()
}

/// A model whose bodies moved by `fext` joints (Pinocchio's names) take a force, with
/// contacts at frames.
pub fn with_forces(
    model: &Model,
    fext: &[&str],
    contacts: &[(&str, grid_gen::model::ContactKind)],
) -> Model {
    let mut m = model.clone();
    m.specialisation.fext =
        fext.iter().map(|n| m.body_of_joint(n).unwrap_or_else(|| panic!("no joint {n}"))).collect();
    m.specialisation.contacts = contacts
        .iter()
        .map(|&(f, kind)| grid_gen::model::Contact {
            frame: m.frame(f).unwrap_or_else(|| panic!("no frame {f}")),
            kind,
        })
        .collect();
    m
}

/// One output's values as the reference shapes it: an nv × nv matrix (from row-major
/// values) or a column.
pub fn output_matrix(shape: Shape, nv: usize, values: &[f64]) -> DMatrix<f64> {
    match shape {
        Shape::Matrix => DMatrix::from_row_slice(nv, nv, values),
        Shape::StateMatrix => DMatrix::from_row_slice(2 * nv, 2 * nv, values),
        Shape::StateInput => {
            DMatrix::from_row_slice(2 * nv, values.len() / (2 * nv).max(1), values)
        }
        Shape::ByFext | Shape::ByLambda => {
            DMatrix::from_row_slice(nv, values.len() / nv.max(1), values)
        }
        Shape::LambdaBy => DMatrix::from_row_slice(values.len() / nv.max(1), nv, values),
        Shape::LambdaByState => {
            DMatrix::from_row_slice(values.len() / (2 * nv).max(1), 2 * nv, values)
        }

        Shape::Vector
        | Shape::PerFrame(_)
        | Shape::FrameMatrix(_)
        | Shape::Config
        | Shape::Lambda
        // nλ × nu, neither known from nv: compared as a column, row-major.
        | Shape::LambdaByInput => col(values),
    }
}

/// A generated Rust module's column program for `kernel` runs as loops in both copies, the
/// portable one and the `fma` one: each calls each of its `blocks` block functions once,
/// whose tables the copy's runner runs, the portable copy's with a multiplication and a
/// subtraction per term, the `fma` copy's with one `mul_add`.
pub fn assert_program_looped(text: &str, kernel: &str, blocks: usize) {
    let (portable, fma) = text.split_at(text.find("pub mod fma").expect("an fma copy"));
    for (copy, text, term) in [
        ("portable", portable, "a[c] = a[c] - k * s[c]"),
        ("fma", fma, "a[c] = T::mul_add(k, s[c], a[c])"),
    ] {
        for b in 0..blocks {
            let call = format!("{kernel}_cols{b}(&rows, &pc);");
            assert_eq!(text.matches(&call).count(), 1, "the {copy} copy calls {call}");
        }
        assert!(text.contains(term), "the {copy} copy's loops: `{term}`");
    }
}
