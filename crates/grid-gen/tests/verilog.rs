//! The Verilog backend: netlists simulated under Icarus Verilog must match the bit-exact
//! software model on random and extreme states within the declared bounds; the software
//! model must stay within the analysed error bound of the f64 reference, entry by entry;
//! states outside the bounds must raise `overflow`. Yosys synthesises the iiwa netlists.
//! With `CI` set, a missing simulator or synthesiser fails the test instead of skipping.

use grid_gen::back::verilog::{plan, sim, Arch, FormatChoice, Netlist, VerilogOptions};
use grid_gen::ir::fixed::quantize_ports;
use grid_gen::ir::fixed::Rounding;
use grid_gen::ir::{self, KernelKind, LowerOptions, Module};
use grid_gen_test_support::{load, reference_outputs, Rng};

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
    let model = load(robot);
    let kernels = vec![KernelKind::RneaGrad, KernelKind::MassMatrix];
    let m = ir::lower(&model, GRAVITY, &LowerOptions { kernels, ..LowerOptions::default() }).unwrap();
    (model, m)
}

/// States within the bounds: random ones, then the corners (every speed and acceleration
/// at plus or minus its bound, positions at ±π and 0).
fn states(n: &Netlist, nv: usize, count: usize, seed: u64) -> Vec<[Vec<f64>; 3]> {
    let mut rng = Rng(seed);
    let b = &n.bounds;
    let mut out = Vec::new();
    for _ in 0..count {
        let q = rng.vec(nv, -std::f64::consts::PI, std::f64::consts::PI);
        let qd = (0..nv).map(|j| rng.uniform(-b.qd[j], b.qd[j])).collect();
        let qdd = (0..nv).map(|j| rng.uniform(-b.qdd[j], b.qdd[j])).collect();
        out.push([q, qd, qdd]);
    }
    for corner in 0..4 {
        let s = if corner % 2 == 0 { 1.0 } else { -1.0 };
        let q = vec![if corner < 2 { std::f64::consts::PI } else { 0.0 } * s; nv];
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
    let ports: Vec<Vec<i64>> = states
        .iter()
        .map(|[q, qd, qdd]| {
            let (p, overflow) = quantize_ports(dp, &n.format, q, qd, qdd, &[]);
            assert!(!overflow, "{}: an input within the bounds does not fit {}", n.top, n.format.label());
            p
        })
        .collect();
    let simulated = sim::simulate(n, &m.robot, &ports).unwrap_or_else(|e| panic!("{}: {e}", n.top));
    let mut worst = 0.0f64;
    for (k, ([q, qd, qdd], hw)) in states.iter().zip(&simulated).enumerate() {
        let run = dp.run(&n.format, &ports[k]);
        let model_nonzero: Vec<i64> = n
            .names
            .outputs
            .iter()
            .map(|(_, id)| {
                let (o, e, _) = dp.nonzero_outputs().into_iter().find(|(_, _, x)| x == id).unwrap();
                run.outputs[o][e]
            })
            .collect();
        assert_eq!(hw.outputs, model_nonzero, "{} state {k}: simulator and software model differ", n.top);
        assert!(!hw.overflow && !run.overflow, "{} state {k}: overflow inside the analysed bounds", n.top);
        let reference = reference_outputs(n.kind, model, q, qd, qdd, GRAVITY);
        for (o, out) in dp.outputs.iter().enumerate() {
            for (e, id) in out.ids.iter().enumerate() {
                let exact = reference[o][(e / nv, e % nv)];
                let got = n.format.to_f64(run.outputs[o][e]);
                let bound = n.analysis.err[id.0 as usize];
                // The reference itself is f64: allow its rounding on top of the bound.
                let slack = 1e-12 * exact.abs().max(1.0);
                assert!((got - exact).abs() <= bound + slack, "{} state {k} {}[{e}]: {got} vs {exact}, bound {bound:e}", n.top, out.name);
                worst = worst.max((got - exact).abs());
            }
        }
    }
    eprintln!("{} {} {}: worst error {worst:.3e}, analysed bound {:.3e}", n.top, n.arch.name(), n.format.label(), n.analysis.output_error);
}

fn run_robot(robot: &str, archs: &[Arch], count: usize) {
    if !tool_or_skip("Icarus Verilog (iverilog)", sim::available()) {
        return;
    }
    let (model, m) = module(robot);
    for &arch in archs {
        let netlists = plan(&m, &VerilogOptions { arch, ..VerilogOptions::default() }).unwrap();
        for n in &netlists {
            let states = states(n, model.nv(), count, 7);
            check_netlist(&model, &m, n, &states);
        }
    }
}

const BOTH: [Arch; 2] = [Arch::Pipelined { stage_depth: 4 }, Arch::Shared { multipliers: 8, adders: 8 }];

#[test]
fn double_pendulum_bit_exact_and_within_bound() {
    run_robot("double_pendulum_continuous", &BOTH, 40);
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
        let netlists = plan(&m, &VerilogOptions { arch, kernels: vec![KernelKind::RneaGrad], ..VerilogOptions::default() }).unwrap();
        let n = &netlists[0];
        let nv = m.robot.nv();
        // The speed that makes qd² alone exceed the format's range, yet fits as an input.
        let fast = (n.format.max_value() / 2.0).sqrt().min(n.format.max_value() / 2.0);
        let q = vec![0.3; nv];
        let qd = vec![fast; nv];
        let qdd = vec![0.0; nv];
        let (ports, input_overflow) = quantize_ports(&n.datapath, &n.format, &q, &qd, &qdd, &[]);
        assert!(!input_overflow);
        let hw = sim::simulate(n, &m.robot, &[ports.clone()]).unwrap();
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
    let build =
        |rounding| plan(&m, &VerilogOptions { format: fixed, rounding, kernels: vec![KernelKind::RneaGrad], ..VerilogOptions::default() }).unwrap().remove(0);
    let (t, h) = (build(Rounding::Truncate), build(Rounding::HalfUp));
    let st = states(&t, model.nv(), 10, 3);
    let ports: Vec<Vec<i64>> = st.iter().map(|[q, qd, qdd]| quantize_ports(&t.datapath, &t.format, q, qd, qdd, &[]).0).collect();
    let (a, b) = (sim::simulate(&t, &m.robot, &ports).unwrap(), sim::simulate(&h, &m.robot, &ports).unwrap());
    assert_ne!(a, b);
}
