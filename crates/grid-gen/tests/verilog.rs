//! The Verilog backend: netlists simulated under Icarus Verilog must match the bit-exact
//! software model on random and extreme states within the declared bounds; the software
//! model must stay within the analysed error bound of the f64 reference, entry by entry;
//! states outside the bounds must raise `overflow`. Yosys synthesises the iiwa netlists.
//! With `CI` set, a missing simulator or synthesiser fails the test instead of skipping.

use grid_gen::back::verilog::{plan, Arch, FdGradPartition, FormatChoice, Netlist, VerilogOptions};
use grid_gen::datapath::quantize_ports;
use grid_gen::datapath::Rounding;
use grid_gen::ir::{self, KernelKind, LowerOptions, Module};
use grid_gen::tools::icarus as sim;
use grid_gen_test_support::{load, load_floating, load_floating_urdf, reference_outputs, Rng};

const GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];

fn tool_or_skip(name: &str, available: bool) -> bool {
    if available {
        return true;
    }
    if std::env::var_os("CI").is_some() {
        panic!("{name} is required in CI (scripts/test.sh installs it) but was not found");
    }
    eprintln!("skipping: {name} not installed");
    false
}

fn module(robot: &str) -> (grid_gen::Model, Module) {
    lowered(load(robot))
}

fn lowered(model: grid_gen::Model) -> (grid_gen::Model, Module) {
    let kernels = vec![KernelKind::RneaGrad, KernelKind::MassMatrix];
    let m =
        ir::lower(&model, GRAVITY, &LowerOptions { kernels, ..LowerOptions::default() }).unwrap();
    (model, m)
}

/// States within the bounds: random ones, then the corners (every speed and acceleration
/// at plus or minus its bound, angles at ±π and 0). Positions the datapath takes
/// directly (prismatic joints) stay within their declared range.
/// A floating base gets a random pose, upside down at the corners.
fn states(n: &Netlist, model: &grid_gen::Model, count: usize, seed: u64) -> Vec<[Vec<f64>; 3]> {
    let nv = model.nv();
    use grid_gen::datapath::Port;
    use grid_gen::ir::Input;
    let mut rng = Rng(seed);
    let b = &n.bounds;
    let linear: Vec<usize> = n
        .datapath
        .ports
        .iter()
        .filter_map(|p| if let Port::Value(Input::Q, j) = p { Some(*j as usize) } else { None })
        .collect();
    let clamp = |mut q: Vec<f64>| {
        for &j in &linear {
            q[j] = q[j].clamp(b.q[j].0, b.q[j].1);
        }
        q
    };
    let mut out = Vec::new();
    for _ in 0..count {
        let angles = rng.vec(nv, -std::f64::consts::PI, std::f64::consts::PI);
        let base = if model.floating { rng.base_pose() } else { [0.0; 7] };
        let mut q = clamp(model.q_from_joints(&angles, base));
        for &first in &model.spherical {
            let at = model.group_q(first).0;
            q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
        }
        let qd = (0..nv).map(|j| rng.uniform(-b.qd[j], b.qd[j])).collect();
        let qdd = (0..nv).map(|j| rng.uniform(-b.qdd[j], b.qdd[j])).collect();
        out.push([q, qd, qdd]);
    }
    for corner in 0..4 {
        let s = if corner % 2 == 0 { 1.0 } else { -1.0 };
        let q = clamp(model.q_from_joints(
            &vec![if corner < 2 { std::f64::consts::PI } else { 0.0 } * s; nv],
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        ));
        let qd = (0..nv).map(|j| s * b.qd[j]).collect();
        let qdd = (0..nv).map(|j| if j % 2 == 0 { s } else { -s } * b.qdd[j]).collect();
        out.push([q, qd, qdd]);
    }
    out
}

/// Simulates one netlist on `states` and checks: simulator == software model bit for
/// bit, no overflow, and every entry within its analysed bound of the f64 reference.
fn check_netlist(model: &grid_gen::Model, m: &Module, n: &Netlist, states: &[[Vec<f64>; 3]]) {
    let dp = &n.datapath;
    let nv = model.nv();
    // fd_grad's chip partition takes τ = ID(q, q̇, q̈) in place of q̈.
    let chip = n.measured.is_some();
    // A floating base is unactuated: its τ is zero, and q̈ is FD's.
    let tau = |q: &[f64], qd: &[f64], qdd: &[f64]| {
        let mut t = grid_gen::reference::rnea(model, q, qd, qdd, GRAVITY);
        if model.floating {
            t[..6].fill(0.0);
        }
        t
    };
    // fd_grad's host partition takes the host's M⁻¹ (row-major) after q̈.
    let host = |q: &[f64], qd: &[f64], qdd: &[f64]| -> Vec<f64> {
        if n.reads_minv() {
            grid_gen::reference::minv(model, q).transpose().iter().copied().collect()
        } else if chip {
            tau(q, qd, qdd)
        } else {
            Vec::new()
        }
    };
    let ports: Vec<Vec<i128>> = states
        .iter()
        .map(|[q, qd, qdd]| {
            let qdd_port: &[f64] = if chip { &[] } else { qdd };
            let (p, overflow) = quantize_ports(dp, &n.format, q, qd, qdd_port, &host(q, qd, qdd));
            assert!(
                !overflow,
                "{}: an input within the bounds does not fit {}",
                n.top,
                n.format.label()
            );
            p
        })
        .collect();
    // The analysed ranges hold: every node's exact value (the datapath in f64) lies within
    // them. The slack is f64's rounding over a few thousand operations against the
    // range's magnitude (about 1e-13 of it), with room to spare. A state whose inputs
    // leave their declared ranges is outside what the ranges promise: the host
    // partition's M⁻¹ bound is sampled within the joint limits, which these states' angles
    // ignore (the host checks M⁻¹ against it at run time).
    let within = |i: usize, x: f64| {
        let (lo, hi) = (n.analysis.lo[i], n.analysis.hi[i]);
        let slack = 1e-10 * lo.abs().max(hi.abs()).max(1.0);
        lo - slack <= x && x <= hi + slack
    };
    let mut checked = 0;
    for (k, [q, qd, qdd]) in states.iter().enumerate() {
        let qdd_port: &[f64] = if chip { &[] } else { qdd };
        let exact =
            dp.values_f64(&grid_gen::datapath::port_values(dp, q, qd, qdd_port, &host(q, qd, qdd)));
        let port = |i: usize| matches!(dp.nodes[i], grid_gen::datapath::HwOp::Port(_));
        if (0..exact.len()).any(|i| port(i) && !within(i, exact[i])) {
            assert!(n.reads_minv(), "{} state {k}: an input outside its bound", n.top);
            continue;
        }
        checked += 1;
        for (i, x) in exact.iter().enumerate() {
            assert!(
                within(i, *x),
                "{} state {k}: node {i} = {x:e} outside its analysed range [{:e}, {:e}]",
                n.top,
                n.analysis.lo[i],
                n.analysis.hi[i]
            );
        }
    }
    assert!(checked * 2 >= states.len(), "{}: only {checked} states within the bounds", n.top);
    let simulated = sim::simulate(n, &m.robot, &ports).unwrap_or_else(|e| panic!("{}: {e}", n.top));
    let nonzero = dp.nonzero_outputs();
    assert_eq!(
        n.names.outputs.iter().map(|(_, id)| *id).collect::<Vec<_>>(),
        nonzero.iter().map(|&(_, _, id)| id).collect::<Vec<_>>()
    );
    let mut worst = 0.0f64;
    // Per output: the largest |error| and the largest |exact| over every state.
    let mut relative = vec![(0.0f64, 0.0f64); dp.outputs.len()];
    for (k, ([q, qd, qdd], hw)) in states.iter().zip(&simulated).enumerate() {
        let run = dp.run(&n.format, &ports[k]);
        // The netlist's output ports are the non-zero entries, in this order.
        let model_nonzero: Vec<i128> = nonzero.iter().map(|&(o, e, _)| run.outputs[o][e]).collect();
        assert_eq!(
            hw.outputs, model_nonzero,
            "{} state {k}: simulator and software model differ",
            n.top
        );
        assert!(
            !hw.overflow && !run.overflow,
            "{} state {k}: overflow inside the analysed bounds",
            n.top
        );
        let reference = if n.reads_minv() {
            // The host partition's q̈ is FD(q, q̇, τ) for τ = ID(q, q̇, q̈): its derivatives
            // are fd_grad's, after q̈ itself.
            let tau = grid_gen::reference::rnea(model, q, qd, qdd, GRAVITY);
            reference_outputs(KernelKind::FdGrad, model, q, qd, &tau, GRAVITY).split_off(1)
        } else if chip {
            reference_outputs(KernelKind::FdGrad, model, q, qd, &tau(q, qd, qdd), GRAVITY)
        } else {
            reference_outputs(n.kind, model, q, qd, qdd, GRAVITY)
        };
        for (o, out) in dp.outputs.iter().enumerate() {
            for (e, id) in out.ids.iter().enumerate() {
                // Matrices come back nv × nv; vectors and frame outputs as one column.
                let exact = if reference[o].ncols() == 1 {
                    reference[o][(e, 0)]
                } else {
                    reference[o][(e / nv, e % nv)]
                };
                let got = n.format.to_f64(run.outputs[o][e]);
                // The chip partition's error is measured, not bounded: its format leaves
                // MEASURED_MARGIN between the sample's largest error and --max-error, which
                // these other states must meet.
                let bound = match &n.measured {
                    Some(_) => grid_gen::back::verilog::DEFAULT_MAX_ERROR,
                    None => n.analysis.err[id.0 as usize],
                };
                // The reference itself is f64: allow its rounding on top of the bound.
                let slack = 1e-12 * exact.abs().max(1.0);
                assert!(
                    (got - exact).abs() <= bound + slack,
                    "{} state {k} {}[{e}]: {got} vs {exact}, bound {bound:e}",
                    n.top,
                    out.name
                );
                // The chip partition's backward error analysis bounds it too, however
                // loosely at the measured format.
                let proven = n.analysis.err[id.0 as usize];
                assert!(
                    (got - exact).abs() <= proven + slack,
                    "{} state {k} {}[{e}]: {got} vs {exact}, analysed bound {proven:e}",
                    n.top,
                    out.name
                );
                worst = worst.max((got - exact).abs());
                relative[o].0 = relative[o].0.max((got - exact).abs());
                relative[o].1 = relative[o].1.max(exact.abs());
            }
        }
    }
    // Issue 58's check of the whole gradient in the normal regime: within 1e-2 of each
    // output's largest entry. (The other kernels' formats meet an absolute --max-error, which
    // is coarse against a tiny robot's entries: the double pendulum's M is about 1e-2.)
    if n.kind == KernelKind::FdGrad {
        for (out, (err, size)) in dp.outputs.iter().zip(&relative) {
            assert!(
                *err <= 1e-2 * size,
                "{} {}: error {err:e} against entries up to {size:e}",
                n.top,
                out.name
            );
        }
    }
    eprintln!(
        "{} {} {}: worst error {worst:.3e}, analysed bound {:.3e}, measured {:?}",
        n.top,
        n.arch().name(),
        n.format.label(),
        n.analysis.output_error,
        n.measured.as_ref().map(|m| m.error)
    );
}

/// `fd_grad`'s chip partition (q̈, M's factorisation and the solves on chip) of `model` in
/// `archs`: bit-exact in simulation, q̈, ∂q̈/∂q and ∂q̈/∂q̇ within twice the measured error
/// of the reference (at τ = ID(q, q̇, q̈) for q̈ within its bound) and within 1e-2 of each
/// output's largest entry. Where the backward error analysis proves a format within
/// `--max-error`, that format's netlist too, within its analysed bound; returns how many
/// such netlists it checked.
fn run_chip(model: grid_gen::Model, archs: &[Arch], count: usize) -> usize {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return 0;
    }
    let mut proven = 0;
    let kernels = vec![KernelKind::RneaGrad, KernelKind::MassMatrix, KernelKind::Rnea];
    let m =
        ir::lower(&model, GRAVITY, &LowerOptions { kernels, ..LowerOptions::default() }).unwrap();
    for &arch in archs {
        let options = VerilogOptions {
            arch,
            kernels: vec![],
            fd_grad: Some(FdGradPartition::Chip),
            ..VerilogOptions::default()
        };
        let netlists = plan(&m, &options).unwrap();
        assert_eq!(netlists.len(), 1);
        let n = &netlists[0];
        assert!(n.top.ends_with("_fd_grad_chip") && n.measured.is_some() && !n.reads_minv());
        assert!(n.datapath.reciprocals() > 0, "{}: no pivot is divided on chip", n.top);
        // The ranges are proven for |τ| within its bound: states whose τ = ID(q, q̇, q̈)
        // leaves it (a floating base's wrench at the corners) are outside the contract.
        let all = states(n, &model, count, 11);
        let within: Vec<_> = all
            .iter()
            .filter(|[q, qd, qdd]| {
                let tau = grid_gen::reference::rnea(&model, q, qd, qdd, GRAVITY);
                tau.iter().zip(&n.bounds.tau).all(|(t, b)| t.abs() <= *b || *b == 0.0)
            })
            .cloned()
            .collect();
        assert!(within.len() * 2 >= all.len(), "{}: most states leave the τ bound", n.top);
        check_netlist(&model, &m, n, &within);
        if let Some((f, bound)) = n.proven {
            let fixed = FormatChoice::Fixed { width: f.width, frac: f.frac };
            let p = plan(&m, &VerilogOptions { format: fixed, ..options }).unwrap();
            assert_eq!(p[0].format, f);
            assert_eq!(p[0].analysis.output_error, bound);
            assert!(bound <= grid_gen::back::verilog::DEFAULT_MAX_ERROR, "{}: {bound:e}", n.top);
            check_netlist(&model, &m, &p[0], &within);
            proven += 1;
        }
    }
    proven
}

#[test]
fn fd_grad_chip_double_pendulum_both_architectures() {
    let proven = run_chip(
        load("double_pendulum_continuous"),
        &[Arch::Pipelined { stage_depth: 2 }, Arch::Shared { multipliers: 2, adders: 2 }],
        24,
    );
    assert_eq!(proven, 2 * usize::from(sim::available()), "a proven format in both architectures");
}

#[test]
fn fd_grad_chip_iiwa() {
    let proven = run_chip(load("grid_iiwa"), &[Arch::Pipelined { stage_depth: 4 }], 12);
    assert_eq!(
        proven,
        usize::from(sim::available()),
        "the iiwa's chip partition has a proven format"
    );
}

/// HyQ pipelined, the floating quadruped shared. The floating HyQ's pipelined netlist
/// (110,000 registers, 10.8 MB of Verilog) took Icarus four minutes to compile per format,
/// most of the Verilog tests' time; its shared one compiles in a second. The pipelined
/// architecture keeps a floating base through the floating double pendulum.
#[test]
fn fd_grad_chip_hyq_and_a_floating_one() {
    let proven = run_chip(load("grid_hyq"), &[Arch::Pipelined { stage_depth: 4 }], 8);
    assert_eq!(proven, usize::from(sim::available()), "HyQ's chip partition has a proven format");
    let proven =
        run_chip(load_floating("grid_hyq"), &[Arch::Shared { multipliers: 8, adders: 8 }], 8);
    assert_eq!(proven, usize::from(sim::available()), "floating HyQ's has one too");
    // Its light links leave the base's pivots near zero: no format within 1e-3 is proven
    // (bound 7e8 at 106.48), so the default format is checked bit for bit and within 1e-2.
    run_chip(
        load_floating("double_pendulum_continuous"),
        &[Arch::Pipelined { stage_depth: 2 }],
        16,
    );
}

/// `fd_grad`'s host partition (robomorphic computing's: q̈ and M⁻¹ from the host, −M⁻¹ ∂c/∂u
/// on chip) of `model` in `archs`: bit-exact in simulation, within its analysed bound of
/// the reference's ∂q̈/∂q and ∂q̈/∂q̇, and within 1e-2 of each output's largest entry.
fn run_host(model: grid_gen::Model, archs: &[Arch], count: usize) {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let kernels = vec![KernelKind::RneaGrad, KernelKind::Minv];
    let m =
        ir::lower(&model, GRAVITY, &LowerOptions { kernels, ..LowerOptions::default() }).unwrap();
    for &arch in archs {
        let options = VerilogOptions {
            arch,
            kernels: vec![],
            fd_grad: Some(FdGradPartition::Host),
            ..VerilogOptions::default()
        };
        let netlists = plan(&m, &options).unwrap();
        assert_eq!(netlists.len(), 1);
        let n = &netlists[0];
        assert!(n.top.ends_with("_fd_grad_host") && n.reads_minv());
        check_netlist(&model, &m, n, &states(n, &model, count, 7));
    }
}

#[test]
fn fd_grad_host_double_pendulum_and_a_floating_one() {
    run_host(load("double_pendulum_continuous"), &BOTH, 20);
    run_host(load_floating("double_pendulum_continuous"), &BOTH, 20);
}

/// The iiwa needs 74 bits: its wrist's M⁻¹ diagonal (up to about 5e3) multiplies ∂c/∂u,
/// whose analysed range is already 2.6e6.
#[test]
fn fd_grad_host_iiwa() {
    run_host(load("grid_iiwa"), &[Arch::Pipelined { stage_depth: 4 }], 12);
}

#[test]
fn fd_grad_host_hyq() {
    run_host(load("grid_hyq"), &[Arch::Shared { multipliers: 8, adders: 8 }], 12);
}

/// A floating quadruped (Unitree Go2, a robot no other Verilog test builds): 67 bits.
#[test]
fn fd_grad_host_floating_go2() {
    let go2 =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/go2.urdf");
    run_host(load_floating_urdf(&go2), &[Arch::Pipelined { stage_depth: 4 }], 8);
}

fn run_robot(robot: &str, archs: &[Arch], count: usize) {
    run_model(load(robot), archs, count)
}

fn run_model(model: grid_gen::Model, archs: &[Arch], count: usize) {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let (model, m) = lowered(model);
    for &arch in archs {
        let netlists = plan(&m, &VerilogOptions { arch, ..VerilogOptions::default() }).unwrap();
        for n in &netlists {
            let states = states(n, &model, count, 7);
            check_netlist(&model, &m, n, &states);
        }
    }
}

const BOTH: [Arch; 2] =
    [Arch::Pipelined { stage_depth: 4 }, Arch::Shared { multipliers: 8, adders: 8 }];

#[test]
fn double_pendulum_bit_exact_and_within_bound() {
    run_robot("double_pendulum_continuous", &BOTH, 40);
}

/// A floating base: the quaternion enters as four `q` ports and the host's
/// `quat_scale` = 2/|q|² (the datapath has no divider, as it has no sine); random base
/// poses and an upside-down one, both architectures.
#[test]
fn floating_double_pendulum_bit_exact_and_within_bound() {
    let model = load_floating("double_pendulum_continuous");
    assert!(model.floating);
    run_model(model, &BOTH, 40);
}

/// A spherical joint: its quaternion enters as four `q` ports with its own
/// `quat_scale_<k>_<name>`; random rotations and unrotated ones at the corners, both
/// architectures. One spherical joint at the leaf of a pendulum: the interval analysis
/// bounds a rotation built from a quaternion loosely (entries in [-3, 1] and ±4 where
/// they lie in [-1, 1]), so nesting several widens the formats until none fits.
#[test]
fn spherical_pendulum_bit_exact_and_within_bound() {
    let urdf = r#"<robot name="ball_pendulum">
  <link name="base"/>
  <joint name="hip" type="continuous"><parent link="base"/><child link="upper"/><axis xyz="0 1 0"/><limit effort="1" velocity="3"/></joint>
  <link name="upper"><inertial><origin xyz="0 0 -0.25"/><mass value="1"/><inertia ixx="0.02" iyy="0.02" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="ball" type="spherical"><parent link="upper"/><child link="lower"/><origin xyz="0 0 -0.5" rpy="0.1 0 0.2"/></joint>
  <link name="lower"><inertial><origin xyz="0.01 0 -0.2"/><mass value="0.5"/><inertia ixx="0.01" iyy="0.012" izz="0.002" ixy="0.001" ixz="0" iyz="0"/></inertial></link>
</robot>"#;
    let model = grid_gen::Model::from_urdf_str("ball_pendulum.urdf", urdf, false)
        .map_err(|e| e.render_plain())
        .unwrap()
        .0;
    assert_eq!((model.spherical.len(), model.nq()), (1, 5));
    run_model(model, &BOTH, 40);
}

/// The frame Jacobian (LOCAL_WORLD_ALIGNED, the default) of iiwa's flange, UR5's tool0
/// (a link merged by fixed joints) and a floating double pendulum's tip (the base pose
/// enters as q ports, random poses): a short datapath fed sin q and cos q, bit-exact in
/// simulation and within its analysed bound of the reference, both architectures.
#[test]
fn frame_jacobians_bit_exact_and_within_bound() {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    use grid_gen::model::ReferenceFrame;
    let cases = [
        (load("grid_iiwa"), "iiwa_link_7"),
        (load("ur5"), "tool0"),
        (load_floating("double_pendulum_continuous"), "link2"),
    ];
    for (robot, frame) in cases {
        let model =
            grid_gen_test_support::with_frames(&robot, &[frame], ReferenceFrame::LocalWorldAligned);
        let m = ir::lower(
            &model,
            GRAVITY,
            &LowerOptions { kernels: vec![KernelKind::FrameJacobian], ..LowerOptions::default() },
        )
        .unwrap();
        for arch in BOTH {
            let netlists = plan(
                &m,
                &VerilogOptions {
                    arch,
                    kernels: vec![KernelKind::FrameJacobian],
                    ..VerilogOptions::default()
                },
            )
            .unwrap();
            let n = &netlists[0];
            check_netlist(&model, &m, n, &states(n, &model, 20, 11));
        }
    }
}

#[test]
fn ur5_bit_exact_and_within_bound() {
    run_robot("ur5", &BOTH, 20);
}

#[test]
fn iiwa_bit_exact_and_within_bound() {
    run_robot("grid_iiwa", &BOTH, 20);
}

#[test]
fn hyq_bit_exact_and_within_bound() {
    run_robot("grid_hyq", &BOTH, 20);
}

/// Far outside the declared speeds, the datapath saturates: the simulator and the model
/// both raise `overflow` (and agree bit for bit on the saturated values).
#[test]
fn states_outside_the_bounds_raise_overflow() {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let (_, m) = module("grid_iiwa");
    for arch in BOTH {
        let netlists = plan(
            &m,
            &VerilogOptions {
                arch,
                kernels: vec![KernelKind::RneaGrad],
                ..VerilogOptions::default()
            },
        )
        .unwrap();
        let n = &netlists[0];
        let nv = m.robot.nv();
        // The speed that makes qd² alone exceed the format's range, yet fits as an input.
        let fast = (n.format.max_value() / 2.0).sqrt().min(n.format.max_value() / 2.0);
        let q = vec![0.3; nv];
        let qd = vec![fast; nv];
        let qdd = vec![0.0; nv];
        let (ports, input_overflow) = quantize_ports(&n.datapath, &n.format, &q, &qd, &qdd, &[]);
        assert!(!input_overflow);
        let hw = sim::simulate(n, &m.robot, std::slice::from_ref(&ports)).unwrap();
        let run = n.datapath.run(&n.format, &ports);
        assert!(run.overflow, "{}: the model did not saturate at qd = {fast}", n.top);
        assert!(hw[0].overflow, "{}: the netlist did not raise overflow at qd = {fast}", n.top);
    }
}

/// The bit-exactness check can fail: the same ports through a netlist built with the
/// other rounding give different bits.
#[test]
fn rounding_modes_differ_in_the_bits() {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let (model, m) = module("double_pendulum_continuous");
    let fixed = FormatChoice::Fixed { width: 24, frac: 12 };
    let build = |rounding| {
        plan(
            &m,
            &VerilogOptions {
                format: fixed,
                rounding,
                kernels: vec![KernelKind::RneaGrad],
                ..VerilogOptions::default()
            },
        )
        .unwrap()
        .remove(0)
    };
    let (t, h) = (build(Rounding::Truncate), build(Rounding::HalfUp));
    let st = states(&t, &model, 10, 3);
    let ports: Vec<Vec<i128>> = st
        .iter()
        .map(|[q, qd, qdd]| quantize_ports(&t.datapath, &t.format, q, qd, qdd, &[]).0)
        .collect();
    let (a, b) = (
        sim::simulate(&t, &m.robot, &ports).unwrap(),
        sim::simulate(&h, &m.robot, &ports).unwrap(),
    );
    assert_ne!(a, b);
}

fn yosys_available() -> bool {
    std::process::Command::new("yosys")
        .arg("-V")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

/// Runs Yosys's generic `synth` (hierarchical: each cell module is mapped once) on a
/// netlist and returns the `stat -top` report; fails on errors, latches or `check`
/// problems.
fn synthesise(n: &Netlist, robot: &grid_gen::ir::Robot) -> String {
    synthesise_with(n, robot, "synth")
}

/// [`synthesise`] with another synthesis command (`synth -run begin:fine`: Yosys's
/// word-level synthesis, everything before gate mapping).
fn synthesise_with(n: &Netlist, robot: &grid_gen::ir::Robot, synth: &str) -> String {
    let dir = std::env::temp_dir().join(format!(
        "grid-gen-yosys-{}-{}-{}",
        std::process::id(),
        n.top,
        n.arch().name()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let v = dir.join(n.file_names().0);
    std::fs::write(&v, n.verilog(robot)).unwrap();
    let stat = dir.join("stat.txt");
    let script = format!(
        "read_verilog {}; {synth} -top {top}; select -assert-none t:$dlatch t:$_DLATCH_*; tee -q -o {} stat -top {top}; check -assert",
        v.display(),
        stat.display(),
        top = n.top
    );
    let out =
        std::process::Command::new("yosys").arg("-q").arg("-p").arg(&script).output().unwrap();
    assert!(
        out.status.success(),
        "{}: yosys failed:\n{}{}",
        n.top,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let report = std::fs::read_to_string(&stat).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    report
}

/// The number after `name` on the last line of `report` that starts with it.
fn count(report: &str, name: &str) -> usize {
    report
        .lines()
        .rev()
        .find_map(|l| {
            let mut f = l.split_whitespace();
            (f.next() == Some(name)).then(|| f.next().unwrap().parse().unwrap())
        })
        .unwrap_or(0)
}

/// Yosys synthesises the iiwa netlists without latches or errors, with exactly the
/// multiplier and adder instances the generator reports, and the flip-flops of its
/// registers. The shared `rnea_grad` goes through Yosys's word-level synthesis only
/// (`synth -run begin:fine`, about a minute): mapping its operand multiplexers (224
/// cycles into 16 operand ports over 340 registers) to 0.9 million gates takes 8 minutes
/// on the development machine, measured once for the book, too long for every run.
#[test]
fn yosys_synthesises_the_iiwa_netlists() {
    if !tool_or_skip("Yosys", yosys_available()) {
        return;
    }
    let (_, m) = module("grid_iiwa");
    for n in plan(
        &m,
        &VerilogOptions {
            arch: BOTH[1],
            kernels: vec![KernelKind::RneaGrad],
            ..VerilogOptions::default()
        },
    )
    .unwrap()
    {
        let report = synthesise_with(&n, &m.robot, "synth -run begin:fine");
        let s = n.stats();
        assert_eq!(
            count(&report, &format!("{}_mul", n.top)),
            s.multipliers,
            "{}: multiplier instances",
            n.top
        );
        assert_eq!(
            count(&report, &format!("{}_add", n.top)),
            s.adders,
            "{}: adder instances",
            n.top
        );
        // One word-level register with enable per register of the file.
        assert_eq!(count(&report, "$dffe"), s.registers, "{}: registers", n.top);
    }
    // (Full-width formats from `--fixed auto`: 49.31 for rnea_grad, 23.17 for M.)
    let cases = [
        (BOTH[0], vec![KernelKind::RneaGrad, KernelKind::MassMatrix]),
        (BOTH[1], vec![KernelKind::MassMatrix]),
    ];
    for (arch, kernels) in cases {
        for n in plan(&m, &VerilogOptions { arch, kernels, ..VerilogOptions::default() }).unwrap() {
            let report = synthesise(&n, &m.robot);
            let s = n.stats();
            assert_eq!(
                count(&report, &format!("{}_mul", n.top)),
                s.multipliers,
                "{}: multiplier instances",
                n.top
            );
            assert_eq!(
                count(&report, &format!("{}_add", n.top)),
                s.adders,
                "{}: adder instances",
                n.top
            );
            let totals = report
                .split("=== design hierarchy ===")
                .nth(1)
                .expect("stat -top prints the hierarchy");
            let flops: usize = totals
                .lines()
                .filter_map(|l| {
                    let mut f = l.split_whitespace();
                    let name = f.next()?;
                    (name.starts_with("$_DFF") || name.starts_with("$_SDFF"))
                        .then(|| f.next()?.parse::<usize>().ok())
                        .flatten()
                })
                .sum();
            let data = s.registers * n.format.width as usize;
            // Control: the pipelined valid and overflow bits, or the shared busy/done/
            // overflow bits and the cycle counter.
            assert!(
                flops >= data && flops <= data + 2 * s.latency_cycles + 16,
                "{}: {flops} flip-flops for {data} data bits",
                n.top
            );
            eprintln!(
                "{} {}: {} cells, {flops} flip-flops, {} multipliers, {} adders",
                n.top,
                n.arch().name(),
                totals
                    .lines()
                    .filter(|l| l.contains("Number of cells:"))
                    .filter_map(|l| l.split_whitespace().last()?.parse::<usize>().ok())
                    .next_back()
                    .unwrap_or(0),
                s.multipliers,
                s.adders
            );
        }
    }
}

/// A robot the project never saw, with joint and robot names that are Verilog keywords,
/// backslashes (Verilog's escaped identifiers), spaces, comment closers and unicode:
/// the netlists compile and simulate, ports are plain identifiers, and
/// `eval --backend verilog` (the library call behind it) returns the software model's
/// numbers, within the analysed bound of the reference.
#[test]
fn hostile_names_and_an_unseen_robot_through_eval() {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let urdf = r#"<robot name="module \evil */ endmodule">
      <link name="base"/>
      <link name="a"><inertial><origin xyz="0.1 0.02 -0.3" rpy="0.3 0.1 0"/><mass value="2.5"/><inertia ixx="0.03" ixy="0.001" ixz="0" iyy="0.02" iyz="0.002" izz="0.01"/></inertial></link>
      <link name="b"><inertial><origin xyz="0 0.2 0"/><mass value="1.2"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.004" iyz="0" izz="0.01"/></inertial></link>
      <link name="c"><inertial><mass value="0.4"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
      <joint name="module" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" velocity="4" effort="1"/></joint>
      <joint name="wire\ x */ endmodule // ü" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 0.4" rpy="0.2 0 0.1"/><axis xyz="0 1 1"/></joint>
      <joint name="output" type="prismatic"><parent link="b"/><child link="c"/><origin xyz="0 0.3 0"/><axis xyz="1 0 0"/><limit lower="-0.5" upper="0.5" velocity="1" effort="1"/></joint>
    </robot>"#;
    let (model, _) = grid_gen::Model::from_urdf_str("hostile.urdf", urdf, false).unwrap();
    let m = ir::lower(
        &model,
        GRAVITY,
        &LowerOptions {
            kernels: vec![KernelKind::RneaGrad, KernelKind::MassMatrix],
            ..LowerOptions::default()
        },
    )
    .unwrap();
    for arch in BOTH {
        for n in plan(&m, &VerilogOptions { arch, ..VerilogOptions::default() }).unwrap() {
            assert_eq!(n.top, format!("module__evil____endmodule_{}", n.datapath.kernel));
            for name in n.names.inputs.iter().chain(n.names.outputs.iter().map(|(s, _)| s)) {
                assert!(
                    name.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_'),
                    "port `{name}`"
                );
            }
            let text = n.verilog(&m.robot);
            // Names reach only line comments (escaped, one line each); code lines never see them.
            let code: Vec<&str> =
                text.lines().filter(|l| !l.trim_start().starts_with("//")).collect();
            assert!(
                code.iter().all(|l| !l.contains('\\') && !l.contains("*/")),
                "a name reached the code"
            );
            let states = states(&n, &model, 15, 11);
            check_netlist(&model, &m, &n, &states);
        }
    }
    // Through the `eval --backend verilog` path: the same bits as the software model.
    let json =
        r#"{"states": [{"q": [0.4, -1.2, 0.3], "qd": [1.5, -2.0, 0.5], "qdd": [3.0, -1.0, 2.0]}]}"#;
    let file = grid_gen::eval::parse_states(json).unwrap();
    let out = grid_gen::eval::evaluate_verilog(&model, &file, GRAVITY, &VerilogOptions::default())
        .unwrap();
    let netlists = plan(&m, &VerilogOptions::default()).unwrap();
    let s = &file.states[0];
    for n in &netlists {
        let (ports, _) =
            quantize_ports(&n.datapath, &n.format, &s.q, &s.qd, s.qdd.as_ref().unwrap(), &[]);
        let run = n.datapath.run(&n.format, &ports);
        let got: Vec<f64> = match n.kind {
            KernelKind::RneaGrad => out.states[0]
                .drnea_dq
                .iter()
                .chain(out.states[0].drnea_dqd.iter())
                .flatten()
                .flatten()
                .copied()
                .collect(),
            _ => out.states[0].m.iter().flatten().copied().collect(),
        };
        let want: Vec<f64> = run.outputs.iter().flatten().map(|&r| n.format.to_f64(r)).collect();
        assert_eq!(got, want, "{}: eval --backend verilog differs from the software model", n.top);
        assert!(!out.states[0].overflow[n.kind.name()]);
    }
}

/// External and contact forces as netlist inputs: UR5's `rnea_grad` with fext on
/// its wrist body and a point contact at tool0 (λ in world axes), both architectures, the
/// forces ports named after their body or frame; random states and forces within the
/// bounds (`--force-max 200`), simulated bit-exact against the software model and within
/// the analysed bound of the reference under the same forces (held to Pinocchio by
/// tests/forces.rs).
#[test]
fn netlists_take_forces_bit_exact_and_within_bound() {
    use grid_gen::model::ContactKind;
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let model = grid_gen_test_support::with_forces(
        &load("ur5"),
        &["wrist_3_joint"],
        &[("tool0", ContactKind::Point)],
    );
    let m = ir::lower(
        &model,
        GRAVITY,
        &LowerOptions { kernels: vec![KernelKind::RneaGrad], ..LowerOptions::default() },
    )
    .unwrap();
    for arch in BOTH {
        let options = VerilogOptions {
            arch,
            force_max: Some(200.0),
            kernels: vec![KernelKind::RneaGrad],
            ..VerilogOptions::default()
        };
        let n = plan(&m, &options).unwrap().remove(0);
        assert!(
            n.names.inputs.iter().any(|p| p == "fext_3_wrist_3_joint_tx"),
            "{:?}",
            n.names.inputs
        );
        assert!(n.names.inputs.iter().any(|p| p == "lambda_2_tool0_fz"), "{:?}", n.names.inputs);
        assert_eq!(n.bounds.force, 200.0);
        let dp = &n.datapath;
        let mut rng = Rng(83);
        let nv = model.nv();
        let cases: Vec<([Vec<f64>; 3], Vec<f64>)> = states(&n, &model, 12, 11)
            .into_iter()
            .enumerate()
            .map(|(k, s)| {
                // The corners push every force entry to its bound too.
                let forces = if k >= 12 {
                    vec![if k % 2 == 0 { 200.0 } else { -200.0 }; 9]
                } else {
                    rng.vec(9, -200.0, 200.0)
                };
                (s, forces)
            })
            .collect();
        let ports: Vec<Vec<i128>> = cases
            .iter()
            .map(|([q, qd, qdd], f)| {
                let (p, overflow) = quantize_ports(dp, &n.format, q, qd, qdd, f);
                assert!(!overflow, "an input within the bounds does not fit {}", n.format.label());
                p
            })
            .collect();
        let simulated =
            sim::simulate(&n, &m.robot, &ports).unwrap_or_else(|e| panic!("{}: {e}", n.top));
        let nonzero = dp.nonzero_outputs();
        let mut worst = 0.0f64;
        for (k, (([q, qd, qdd], f), hw)) in cases.iter().zip(&simulated).enumerate() {
            let run = dp.run(&n.format, &ports[k]);
            let model_nonzero: Vec<i128> =
                nonzero.iter().map(|&(o, e, _)| run.outputs[o][e]).collect();
            assert_eq!(hw.outputs, model_nonzero, "state {k}: simulator and software model differ");
            assert!(
                !hw.overflow && !run.overflow,
                "state {k}: overflow inside the analysed bounds"
            );
            let ext = grid_gen::reference::External { fext: &f[..6], lambda: &f[6..] };
            let reference = grid_gen_test_support::reference_outputs_with(
                KernelKind::RneaGrad,
                &model,
                q,
                qd,
                qdd,
                GRAVITY,
                ext,
            );
            assert_eq!(reference.len(), dp.outputs.len(), "dc_dq, dc_dqd, dc_dfext, dc_dlambda");
            for (o, out) in dp.outputs.iter().enumerate() {
                for (e, id) in out.ids.iter().enumerate() {
                    let cols = reference[o].ncols();
                    let exact = reference[o][(e / cols, e % cols)];
                    let got = n.format.to_f64(run.outputs[o][e]);
                    let bound = n.analysis.err[id.0 as usize];
                    let slack = 1e-12 * exact.abs().max(1.0);
                    assert!(
                        (got - exact).abs() <= bound + slack,
                        "state {k} {}[{e}]: {got} vs {exact}, bound {bound:e}",
                        out.name
                    );
                    worst = worst.max((got - exact).abs());
                }
            }
        }
        assert_eq!(nv, 6);
        eprintln!(
            "ur5 with forces {} {}: worst error {worst:.3e}, analysed bound {:.3e}",
            n.arch().name(),
            n.format.label(),
            n.analysis.output_error
        );
    }
}

/// A seeded random tree of `n` joints (revolute about random axes, one prismatic with
/// limits), random origins and positive-definite inertias: a robot no file holds.
/// A seeded random tree of `n` links with box-like inertias; the last joint prismatic
/// where `prismatic`, the others revolute.
fn random_tree(rng: &mut Rng, n: usize, prismatic: bool) -> String {
    let mut links = String::from(r#"<link name="base"/>"#);
    let mut joints = String::new();
    for j in 0..n {
        let m = rng.uniform(0.3, 3.0);
        // Principal moments that satisfy the triangle inequality: a box's.
        let [a, b, c] = [rng.uniform(0.05, 0.4), rng.uniform(0.05, 0.4), rng.uniform(0.05, 0.4)];
        let (ixx, iyy, izz) =
            (m * (b * b + c * c) / 12.0, m * (a * a + c * c) / 12.0, m * (a * a + b * b) / 12.0);
        let com = rng.vec(3, -0.2, 0.2);
        links.push_str(&format!(
            r#"<link name="l{j}"><inertial><origin xyz="{} {} {}"/><mass value="{m}"/><inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial></link>"#,
            com[0], com[1], com[2]
        ));
        let parent =
            if j == 0 { "base".to_string() } else { format!("l{}", rng.next_u64() as usize % j) };
        let xyz = rng.vec(3, -0.3, 0.3);
        let rpy = rng.vec(3, -1.0, 1.0);
        let axis = rng.vec(3, -1.0, 1.0);
        let (kind, limit) = if j == n - 1 && prismatic {
            ("prismatic", r#"<limit lower="-0.3" upper="0.3" velocity="1" effort="1"/>"#)
        } else {
            ("revolute", r#"<limit lower="-3.1" upper="3.1" velocity="3" effort="1"/>"#)
        };
        joints.push_str(&format!(
            r#"<joint name="j{j}" type="{kind}"><parent link="{parent}"/><child link="l{j}"/><origin xyz="{} {} {}" rpy="{} {} {}"/><axis xyz="{} {} {}"/>{limit}</joint>"#,
            xyz[0], xyz[1], xyz[2], rpy[0], rpy[1], rpy[2], axis[0], axis[1], axis[2]
        ));
    }
    format!(r#"<robot name="random">{links}{joints}</robot>"#)
}

/// `fd_grad`'s host partition on seeded random trees no file holds (issue 58's property
/// test), and through `eval --backend verilog` (the library call behind it): states with
/// τ, q̈ and M⁻¹ from the reference as the host would compute them, the netlist's
/// ∂q̈/∂q and ∂q̈/∂q̇ within the analysed bound of the reference's.
#[test]
fn fd_grad_host_on_random_trees_and_through_eval() {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let mut rng = Rng(58);
    for (k, n) in [3, 4, 5].into_iter().enumerate() {
        let urdf = random_tree(&mut rng, n, true);
        let (model, _) = grid_gen::Model::from_urdf_str("random.urdf", &urdf, false)
            .map_err(|e| e.render_plain())
            .unwrap();
        let arch = if k == 1 { BOTH[1] } else { BOTH[0] };
        run_host(model, &[arch], 10);
    }
    let urdf = random_tree(&mut rng, 3, true);
    let (model, _) = grid_gen::Model::from_urdf_str("random.urdf", &urdf, false).unwrap();
    let json = r#"{"states": [{"q": [0.4, -1.2, 0.1], "qd": [1.5, -2.0, 0.5], "tau": [3.0, -1.0, 2.0]},
                              {"q": [0.4, -1.2, 0.1], "qd": [1.5, -2.0, 0.5], "qdd": [3.0, -1.0, 2.0]}]}"#;
    let file = grid_gen::eval::parse_states(json).unwrap();
    let options =
        VerilogOptions { fd_grad: Some(FdGradPartition::Host), ..VerilogOptions::default() };
    let out = grid_gen::eval::evaluate_verilog(&model, &file, GRAVITY, &options).unwrap();
    let stats = out.netlists.iter().find(|s| s.kernel == KernelKind::FdGrad).unwrap();
    let s = &file.states[0];
    let (_, dq, dqd) = grid_gen::reference::forward_dynamics_derivatives(
        &model,
        &s.q,
        &s.qd,
        s.tau.as_ref().unwrap(),
        GRAVITY,
    );
    let got = &out.states[0];
    for (name, got, exact) in [("dfd_dq", &got.dfd_dq, dq), ("dfd_dqd", &got.dfd_dqd, dqd)] {
        let got = got.as_ref().unwrap_or_else(|| panic!("{name} missing"));
        for i in 0..3 {
            for j in 0..3 {
                let e = (got[i][j] - exact[(i, j)]).abs();
                assert!(
                    e <= stats.error_bound,
                    "{name}[{i}][{j}]: {} vs {}",
                    got[i][j],
                    exact[(i, j)]
                );
            }
        }
    }
    assert_eq!(got.overflow.get("fd_grad"), Some(&false));
    // The state without τ has no host-partition outputs.
    assert!(out.states[1].dfd_dq.is_none() && out.states[1].drnea_dq.is_some());
}

/// The host partition refuses what it cannot build, with the reason: a scene that selects
/// gradient entries (the product reads whole columns), and a robot whose formats outgrow 120
/// bits (floating Atlas's `rnea_grad` gets 99.57 at the default 1e-3, not 1e-12; the
/// refusal names the joint where the widest value is computed).
#[test]
fn fd_grad_host_refusals_say_why() {
    let host = VerilogOptions {
        kernels: vec![],
        fd_grad: Some(FdGradPartition::Host),
        ..VerilogOptions::default()
    };
    let kernels = vec![KernelKind::RneaGrad, KernelKind::Minv];
    let lower = |model: &grid_gen::Model| {
        ir::lower(
            model,
            GRAVITY,
            &LowerOptions { kernels: kernels.clone(), ..LowerOptions::default() },
        )
        .unwrap()
    };
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_lf_columns");
    let e = plan(&lower(&model), &host).unwrap_err().to_string();
    assert!(e.contains("selects gradient entries"), "{e}");
    let strict = VerilogOptions {
        format: FormatChoice::Auto { max_error: 1e-12 },
        ..VerilogOptions::default()
    };
    let e = plan(&lower(&load_floating("grid_atlas")), &strict).unwrap_err().to_string();
    assert!(
        e.contains("no format of at most 120 bits") && e.contains("joints from the root"),
        "{e}"
    );
}

/// `fd_grad`'s chip partition on seeded random trees no file holds (revolute joints: a
/// prismatic joint under a moving body is refused, below) and on a spherical joint.
#[test]
fn fd_grad_chip_on_random_trees_and_a_spherical_joint() {
    let mut rng = Rng(5858);
    for (k, n) in [3, 4, 5].into_iter().enumerate() {
        let urdf = random_tree(&mut rng, n, false);
        let (model, _) = grid_gen::Model::from_urdf_str("random.urdf", &urdf, false)
            .map_err(|e| e.render_plain())
            .unwrap();
        let arch = if k == 1 { BOTH[1] } else { BOTH[0] };
        run_chip(model, &[arch], 10);
    }
    // The spherical-joint arm with its prismatic joint made revolute.
    let ball =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/ball_arm.urdf");
    let urdf = std::fs::read_to_string(ball)
        .unwrap()
        .replace(r#"name="slide" type="prismatic""#, r#"name="slide" type="revolute""#);
    let (model, _) = grid_gen::Model::from_urdf_str("ball_arm.urdf", &urdf, false)
        .map_err(|e| e.render_plain())
        .unwrap();
    assert!(!model.spherical.is_empty());
    run_chip(model, &[BOTH[1]], 8);
}

/// The chip partition refuses what its proofs do not cover, naming the joint: a prismatic
/// joint under a moving body (Panda's fingers), a body without inertia (nothing bounds its
/// pivot), coupled mimic joints (M is a projection); and a given format too narrow for
/// the proven ranges.
#[test]
fn fd_grad_chip_refusals_say_why() {
    let chip = VerilogOptions {
        kernels: vec![],
        fd_grad: Some(FdGradPartition::Chip),
        ..VerilogOptions::default()
    };
    let lower = |model: &grid_gen::Model| {
        let kernels = vec![KernelKind::RneaGrad, KernelKind::MassMatrix, KernelKind::Rnea];
        ir::lower(model, GRAVITY, &LowerOptions { kernels, ..LowerOptions::default() }).unwrap()
    };
    let e = plan(&lower(&load("panda")), &chip).unwrap_err().to_string();
    assert!(e.contains("panda_finger_joint1") && e.contains("prismatic"), "{e}");
    let massless = r#"<robot name="m"><link name="base"/>
        <link name="a"/>
        <link name="b"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
        <joint name="ja" type="continuous"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/></joint>
        <joint name="jb" type="continuous"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0"/><axis xyz="0 1 0"/></joint>
        </robot>"#;
    let (model, _) = grid_gen::Model::from_urdf_str("m.urdf", massless, false).unwrap();
    let e = plan(&lower(&model), &chip).unwrap_err().to_string();
    assert!(e.contains("`ja`") && e.contains("not positive definite"), "{e}");
    let mimic = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures/mimic_arm.urdf");
    let e = plan(&lower(&grid_gen_test_support::load_coupled_urdf(&mimic)), &chip)
        .unwrap_err()
        .to_string();
    assert!(e.contains("coupled mimic"), "{e}");
    let narrow = VerilogOptions { format: FormatChoice::Fixed { width: 32, frac: 16 }, ..chip };
    let e = plan(&lower(&load("grid_iiwa")), &narrow).unwrap_err().to_string();
    assert!(e.contains("cannot hold kernel `fd_grad`"), "{e}");
}

/// Yosys synthesises `fd_grad`'s chip partition, divider included, in both architectures
/// (the double pendulum's: one state-dependent pivot): one cell instance per operation
/// (pipelined, to word-level cells: its 97 gate-level multipliers would take minutes) or
/// per unit (shared, to gates).
#[test]
fn yosys_synthesises_a_chip_netlist() {
    if !tool_or_skip("Yosys", yosys_available()) {
        return;
    }
    let model = load("double_pendulum_continuous");
    let kernels = vec![KernelKind::RneaGrad, KernelKind::MassMatrix, KernelKind::Rnea];
    let m =
        ir::lower(&model, GRAVITY, &LowerOptions { kernels, ..LowerOptions::default() }).unwrap();
    for arch in [BOTH[0], Arch::Shared { multipliers: 2, adders: 2 }] {
        let options = VerilogOptions {
            arch,
            kernels: vec![],
            fd_grad: Some(FdGradPartition::Chip),
            ..VerilogOptions::default()
        };
        let n = plan(&m, &options).unwrap().remove(0);
        let report = match arch {
            Arch::Pipelined { .. } => synthesise_with(&n, &m.robot, "synth -run begin:fine"),
            Arch::Shared { .. } => synthesise(&n, &m.robot),
        };
        let s = n.stats();
        assert!(s.dividers >= 1);
        for (cell, units) in [("mul", s.multipliers), ("add", s.adders), ("recip", s.dividers)] {
            assert_eq!(
                count(&report, &format!("{}_{cell}", n.top)),
                units,
                "{} {}: {cell} instances",
                n.top,
                n.arch().name()
            );
        }
    }
}

/// `eval --backend verilog --fd-grad-netlist chip` (the library call behind it): q̈, ∂q̈/∂q
/// and ∂q̈/∂q̇ from τ, against the reference within `--max-error` (the format leaves
/// `MEASURED_MARGIN` below it on its own states); a floating base's τ must be zero.
#[test]
fn fd_grad_chip_through_eval() {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let mut rng = Rng(5859);
    let urdf = random_tree(&mut rng, 3, false);
    let (model, _) = grid_gen::Model::from_urdf_str("random.urdf", &urdf, false).unwrap();
    let json =
        r#"{"states": [{"q": [0.4, -1.2, 0.1], "qd": [1.5, -2.0, 0.5], "tau": [3.0, -1.0, 2.0]}]}"#;
    let file = grid_gen::eval::parse_states(json).unwrap();
    let options =
        VerilogOptions { fd_grad: Some(FdGradPartition::Chip), ..VerilogOptions::default() };
    let out = grid_gen::eval::evaluate_verilog(&model, &file, GRAVITY, &options).unwrap();
    let stats = out.netlists.iter().find(|s| s.kernel == KernelKind::FdGrad).unwrap();
    assert_eq!(stats.partition, Some(FdGradPartition::Chip));
    let s = &file.states[0];
    let tau = s.tau.as_ref().unwrap();
    let (qdd, dq, dqd) =
        grid_gen::reference::forward_dynamics_derivatives(&model, &s.q, &s.qd, tau, GRAVITY);
    let got = &out.states[0];
    let max_error = grid_gen::back::verilog::DEFAULT_MAX_ERROR;
    let fd = got.fd.as_ref().expect("fd");
    for i in 0..3 {
        assert!((fd[i] - qdd[i]).abs() <= max_error, "fd[{i}]: {} vs {}", fd[i], qdd[i]);
    }
    for (name, got, exact) in [("dfd_dq", &got.dfd_dq, dq), ("dfd_dqd", &got.dfd_dqd, dqd)] {
        let got = got.as_ref().unwrap_or_else(|| panic!("{name} missing"));
        for i in 0..3 {
            for j in 0..3 {
                let e = (got[i][j] - exact[(i, j)]).abs();
                assert!(e <= max_error, "{name}[{i}][{j}]: {} vs {}", got[i][j], exact[(i, j)]);
            }
        }
    }
    assert_eq!(got.overflow.get("fd_grad"), Some(&false));
    // A floating base is unactuated on this netlist: a wrench there is refused.
    let go2 =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/go2.urdf");
    let model = load_floating_urdf(&go2);
    let mut tau = vec![0.0; model.nv()];
    tau[2] = 5.0;
    let q = model.q_from_joints(&vec![0.0; model.nv()], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    let json = serde_json::json!({"states": [{"q": q, "qd": vec![0.0; model.nv()], "tau": tau}]});
    let file = grid_gen::eval::parse_states(&json.to_string()).unwrap();
    let e = grid_gen::eval::evaluate_verilog(&model, &file, GRAVITY, &options).unwrap_err();
    assert!(e.to_string().contains("unactuated base"), "{e}");
}

/// `--fd-grad-netlist auto` (the flag alone): the chip partition where its bounds cover the
/// robot (the double pendulum), else the host's (Panda's prismatic fingers).
#[test]
fn fd_grad_auto_picks_chip_where_it_fits() {
    let auto = VerilogOptions {
        kernels: vec![],
        fd_grad: Some(FdGradPartition::Auto),
        ..VerilogOptions::default()
    };
    let kernels =
        vec![KernelKind::RneaGrad, KernelKind::MassMatrix, KernelKind::Rnea, KernelKind::Minv];
    let lower = |model: &grid_gen::Model| {
        ir::lower(
            model,
            GRAVITY,
            &LowerOptions { kernels: kernels.clone(), ..LowerOptions::default() },
        )
        .unwrap()
    };
    let n = plan(&lower(&load("double_pendulum_continuous")), &auto).unwrap().remove(0);
    assert!(n.top.ends_with("_fd_grad_chip"), "{}", n.top);
    assert_eq!(n.stats().partition, Some(FdGradPartition::Chip));
    let n = plan(&lower(&load("panda")), &auto).unwrap().remove(0);
    assert!(n.top.ends_with("_fd_grad_host"), "{}", n.top);
    assert_eq!(n.stats().partition, Some(FdGradPartition::Host));
}

/// `info`'s stage path (what `scripts/fpga.py` places for a pipelined netlist's clock)
/// names cells the netlist holds, as many as a stage's levels at most; the chip partition's
/// runs through its divider, and a shared netlist has none.
#[test]
fn the_stage_path_names_the_netlists_own_cells() {
    let chip = VerilogOptions {
        kernels: vec![KernelKind::RneaGrad],
        fd_grad: Some(FdGradPartition::Chip),
        ..VerilogOptions::default()
    };
    let kernels =
        vec![KernelKind::RneaGrad, KernelKind::MassMatrix, KernelKind::Rnea, KernelKind::Minv];
    let options = LowerOptions { kernels, ..LowerOptions::default() };
    let m = ir::lower(&load("double_pendulum_continuous"), GRAVITY, &options).unwrap();
    let netlists = plan(&m, &chip).unwrap();
    assert_eq!(netlists.len(), 2, "rnea_grad and fd_grad's chip partition");
    for n in netlists {
        let s = n.stats();
        let path = s.stage_path.clone().expect("a pipelined netlist has a stage path");
        assert!(
            !path.is_empty() && path.len() <= s.stage_depth.unwrap() as usize,
            "{}: {path:?}",
            n.top
        );
        let text = n.verilog(&m.robot);
        for cell in &path {
            assert!(text.contains(&format!("module {}_{cell} (", n.top)), "{}: no {cell}", n.top);
        }
        assert_eq!(
            path.contains(&"recip"),
            n.top.ends_with("_fd_grad_chip"),
            "{}: {path:?}",
            n.top
        );
    }
    let shared = VerilogOptions { arch: BOTH[1], ..chip };
    assert!(plan(&m, &shared).unwrap().iter().all(|n| n.stats().stage_path.is_none()));
}

/// The pipelined divider (`Divider::Pipelined`) gives the combinational one's quotient and
/// flag, delayed by its stages less one, for every input of 12-bit formats whose dividend
/// 2^(2 FRAC) sits below, inside and above the quotient's bits, in one to eleven stages
/// (one restoring step each). The combinational cell is the one the shared netlists
/// simulate bit for bit against the software model.
#[test]
fn the_pipelined_divider_matches_the_combinational_one_on_every_input() {
    use grid_gen::back::verilog::{cell_modules, Divider};
    use grid_gen::datapath::Format;
    if !tool_or_skip("Icarus Verilog", sim::available()) {
        return;
    }
    let w = 12u32;
    let dir = std::env::temp_dir().join(format!("grid-gen-recip-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for frac in [0, 3, 5, 6, 7, 11] {
        let f = Format::new(w, frac, Rounding::Truncate).unwrap();
        for stages in [1u32, 2, 4, 11] {
            let tb = format!(
                "module tb;
    reg clk = 0;
    reg signed [{wm}:0] a;
    reg signed [{wm}:0] hist [0:{sm}];
    wire signed [{wm}:0] yp, yc;
    wire op, oc;
    p_recip up (.clk(clk), .a(a), .y(yp), .ovf(op));
    c_recip uc (.a(hist[{sm}]), .y(yc), .ovf(oc));
    integer i, k, bad;
    initial begin
        bad = 0;
        for (i = 0; i < {n}; i = i + 1) begin
            a = i;
            for (k = {sm}; k > 0; k = k - 1) hist[k] = hist[k - 1];
            hist[0] = a;
            #1;
            if (i >= {sm} && (yp !== yc || op !== oc)) begin
                if (bad == 0) $display(\"first: a=%0d y=%0d/%0d ovf=%0d/%0d\", hist[{sm}], yp, yc, op, oc);
                bad = bad + 1;
            end
            clk = 1; #1; clk = 0;
        end
        $display(\"mismatches %0d\", bad);
        $finish;
    end
endmodule
",
                wm = w - 1,
                sm = stages - 1,
                n = (1u32 << w) + stages,
            );
            let v = dir.join("recip.v");
            std::fs::write(
                &v,
                format!(
                    "{}{}{tb}",
                    cell_modules("p", &f, Divider::Pipelined(stages)),
                    cell_modules("c", &f, Divider::Combinational)
                ),
            )
            .unwrap();
            let image = dir.join("recip.vvp");
            let run = |cmd: &mut std::process::Command| {
                let out = cmd.output().unwrap();
                let text = format!(
                    "{}{}",
                    String::from_utf8_lossy(&out.stdout),
                    String::from_utf8_lossy(&out.stderr)
                );
                assert!(out.status.success(), "{}: {text}", f.label());
                text
            };
            run(std::process::Command::new("iverilog")
                .args(["-g2005", "-o"])
                .arg(&image)
                .args(["-s", "tb"])
                .arg(&v));
            let text = run(std::process::Command::new("vvp").arg("-n").arg(&image));
            assert!(text.contains("mismatches 0"), "{} in {stages} stages: {text}", f.label());
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
