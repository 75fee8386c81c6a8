//! The book's fixed-point trade table: for iiwa and HyQ `rnea_grad`, each WIDTH with
//! the most FRAC bits the range analysis allows, the largest error measured by the
//! bit-exact software model over random states within the bounds (against the f64
//! datapath, which equals the reference to 1e-12), the analysed bound, units, and the
//! shared architecture's cycles per state at M = 8, 32, 128, and (with Yosys) the gates
//! of one multiplier and one adder cell after generic `synth`, times the units; then
//! robomorphic's Q16.16 with truncation on the same states. Run: `cargo run --release --example
//! verilog_trade`.

use grid_gen::back::verilog::SharedSchedule;
use grid_gen::datapath::{
    format_for_width, port_values, quantize_ports, Bounds, Datapath, Format, Rounding,
};
use grid_gen::ir::{self, KernelKind, LowerOptions};

/// Gates of the `kind` cell (`mul` or `add`) of format `f` after Yosys's generic `synth`.
fn cell_gates(f: &Format, kind: &str) -> usize {
    let dir = std::env::temp_dir().join(format!("grid-gen-trade-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let v = dir.join("cells.v");
    std::fs::write(
        &v,
        grid_gen::back::verilog::cell_modules("t", f, grid_gen::back::verilog::Divider::None),
    )
    .expect("write");
    let stat = dir.join("stat.txt");
    let script = format!(
        "read_verilog {}; synth -top t_{kind}; tee -q -o {} stat",
        v.display(),
        stat.display()
    );
    let out = std::process::Command::new("yosys")
        .arg("-q")
        .arg("-p")
        .arg(&script)
        .output()
        .expect("yosys runs");
    assert!(out.status.success(), "yosys: {}", String::from_utf8_lossy(&out.stderr));
    let report = std::fs::read_to_string(&stat).expect("stat");
    let _ = std::fs::remove_dir_all(&dir);
    report
        .lines()
        .find_map(|l| {
            l.trim().strip_prefix("Number of cells:").map(|n| n.trim().parse().expect("a count"))
        })
        .expect("stat prints the cells")
}

fn main() {
    let yosys =
        std::process::Command::new("yosys").arg("-V").output().is_ok_and(|o| o.status.success());
    if !yosys {
        eprintln!("yosys is not installed (Debian package `yosys`): the gate counts are left out");
    }
    for robot in ["grid_iiwa", "grid_hyq"] {
        let text = std::fs::read_to_string(format!("robots/{robot}.urdf"))
            .expect("run from the repository root");
        let (model, _) =
            grid_gen::Model::from_urdf_str(robot, &text, false).expect("bundled robot loads");
        let m = ir::lower(
            &model,
            [0.0, 0.0, -9.81],
            &LowerOptions { kernels: vec![KernelKind::RneaGrad], ..LowerOptions::default() },
        )
        .expect("lowers");
        let dp = Datapath::new(&m.functions[0], m.robot.nv()).expect("datapath");
        let bounds = Bounds::new(&m.robot, None, None);
        let nv = m.robot.nv();
        // Deterministic states within the bounds.
        let mut seed = 0x9e3779b97f4a7c15u64;
        let mut uniform = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let states: Vec<[Vec<f64>; 3]> = (0..200)
            .map(|_| {
                let q = (0..nv).map(|_| std::f64::consts::PI * uniform()).collect();
                let qd = (0..nv).map(|j| bounds.qd[j] * uniform()).collect();
                let qdd = (0..nv).map(|j| bounds.qdd[j] * uniform()).collect();
                [q, qd, qdd]
            })
            .collect();
        // The largest |value| of any node over the states, against the analysed range:
        // how pessimistic the range analysis is.
        let mut largest = 0.0f64;
        let exact: Vec<Vec<f64>> = states
            .iter()
            .map(|[q, qd, qdd]| {
                let ports = port_values(&dp, q, qd, qdd, &[]);
                let v = dp.values_f64(&ports);
                largest = v.iter().fold(largest, |m, x| m.max(x.abs()));
                dp.outputs.iter().flat_map(|o| o.ids.iter().map(|id| v[id.0 as usize])).collect()
            })
            .collect();
        let measure = |f: &Format| -> (f64, usize) {
            let mut worst = 0.0f64;
            let mut overflows = 0;
            for ([q, qd, qdd], ex) in states.iter().zip(&exact) {
                let (p, o) = quantize_ports(&dp, f, q, qd, qdd, &[]);
                let run = dp.run(f, &p);
                overflows += usize::from(o || run.overflow);
                for (raw, e) in run.outputs.iter().flatten().zip(ex) {
                    worst = worst.max((f.to_f64(*raw) - e).abs());
                }
            }
            (worst, overflows)
        };
        let (muls, adds) = dp.op_counts();
        println!("{robot} rnea_grad: {muls} multipliers ({} by a constant), {adds} adders pipelined; {} per link", dp.constant_muls(), muls / nv);
        // rnea_grad does not divide, so the width (which sets the divider's stages) is not read.
        let cycles: Vec<String> = [8, 32, 128]
            .iter()
            .map(|&k| format!("M=A={k}: {}", SharedSchedule::new(&dp, k, k, 32).cycles + 1))
            .collect();
        println!("  shared cycles per state: {}", cycles.join(", "));
        println!(
            "  largest |value| over the states {largest:.2e}, analysed range {:.2e}",
            grid_gen::datapath::analyse(&dp, &bounds, 30, Rounding::HalfUp).range()
        );
        println!("  | WIDTH.FRAC | measured max error | analysed bound |");
        for width in [16, 24, 32, 40, 48, 56, 64] {
            for rounding in Rounding::ALL {
                match format_for_width(&dp, &bounds, rounding, width) {
                    Some((f, a)) => {
                        let (worst, over) = measure(&f);
                        // Yosys gates of one multiplier and one adder cell at this format:
                        // what hierarchical synthesis counts per instance.
                        let gates = if rounding == Rounding::HalfUp && yosys {
                            let (m, a) = (cell_gates(&f, "mul"), cell_gates(&f, "add"));
                            format!(
                                " | mul cell {m} gates, add cell {a}; all units {}",
                                m * muls + a * adds
                            )
                        } else {
                            String::new()
                        };
                        println!(
                            "  | {} {} | {worst:.2e} | {:.2e} | overflows {over}/200{gates}",
                            f.label(),
                            rounding.name(),
                            a.output_error
                        );
                    }
                    None => println!(
                        "  | {width}.- {} | the analysed range needs more than {width} bits | |",
                        rounding.name()
                    ),
                }
            }
        }
        let q16 = Format::new(32, 16, Rounding::Truncate).expect("valid");
        let (worst, over) = measure(&q16);
        println!(
            "  robomorphic Q16.16 truncate: measured max error {worst:.2e}, {over}/200 states overflow (analysed range needs {:.2e}, Q16.16 holds {:.2e})",
            grid_gen::datapath::analyse(&dp, &bounds, 16, Rounding::Truncate).needed,
            q16.max_value()
        );
    }
}
