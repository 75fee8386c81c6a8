//! Mixed precision: the plan meets its target on states it was not
//! planned at, the interpreter agrees with the pure formats at its two ends, and the
//! emitted mixed Rust, compiled with rustc, computes the interpreter's numbers bit for bit.

use grid_gen::accuracy::{kernel_states, mixed_plan, random_states, MIXED_PLAN_SEED};
use grid_gen::ir::{self, Function, KernelKind, LowerOptions};
use grid_gen::{reference, Model};
use grid_gen_test_support::*;

const G: [f64; 3] = reference::DEFAULT_GRAVITY;
const THROUGH_MINV: [KernelKind; 3] = [KernelKind::Minv, KernelKind::Fd, KernelKind::FdGrad];

/// Each kernel's inputs at `n` random states of seed `seed` (not the planning seed).
fn inputs(model: &Model, f: &Function, n: usize, seed: u64) -> Vec<Vec<Vec<f64>>> {
    assert_ne!(seed, MIXED_PLAN_SEED);
    let states = kernel_states(f, &random_states(model, G, n, seed, None, None));
    assert_eq!(states.len(), n);
    states
}

fn refs(v: &[Vec<f64>]) -> Vec<&[f64]> {
    v.iter().map(|x| x.as_slice()).collect()
}

/// `max |Δ| / max |true|` per output, the worst output.
fn error(got: &[Vec<f64>], truth: &[Vec<f64>]) -> f64 {
    got.iter()
        .zip(truth)
        .map(|(g, t)| {
            let scale = t.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            g.iter().zip(t).fold(0.0f64, |m, (a, b)| m.max((a - b).abs())) / scale
        })
        .fold(0.0, f64::max)
}

#[test]
fn the_plan_meets_its_target_on_other_states() {
    for robot in ["grid_iiwa", "grid_hyq"] {
        let model = load(robot);
        let exact = ir::lower(
            &model,
            G,
            &LowerOptions {
                fold: false,
                kernels: THROUGH_MINV.to_vec(),
                ..LowerOptions::default()
            },
        )
        .unwrap();
        let fast = ir::lower(
            &model,
            G,
            &LowerOptions { kernels: THROUGH_MINV.to_vec(), ..LowerOptions::default() },
        )
        .unwrap();
        for (e, f) in exact.functions.iter().zip(&fast.functions) {
            let states = inputs(&model, f, 40, 7);
            let truth: Vec<Vec<Vec<f64>>> = states
                .iter()
                .map(|s| {
                    e.eval_as::<grid_gen::numerics::Dd>(&refs(s))
                        .into_iter()
                        .map(|o| o.into_iter().map(|x| x.to_f64()).collect())
                        .collect()
                })
                .collect();
            let mut wide_before = usize::MAX;
            for target in [1e-12, 1e-9, 1e-6] {
                let plan = mixed_plan(&model, G, f, target);
                assert!(
                    plan.bound <= target && plan.all_f32_bound > target,
                    "{robot} {}: {plan:?}",
                    f.kind
                );
                let worst = states
                    .iter()
                    .zip(&truth)
                    .map(|(s, t)| error(&f.eval_mixed(&refs(s), &plan.wide), t))
                    .fold(0.0, f64::max);
                // The bound is first order; measured, it holds with one to two orders to spare
                // (iiwa fd_grad at 1e-12: 4.7e-14 over 100 states), so no slack is added.
                assert!(worst <= target, "{robot} {} mixed ≤{target:e}: {worst:.2e}", f.kind);
                let (wide, all) = plan.wide_operations(f);
                assert!(
                    wide < all && wide <= wide_before,
                    "{robot} {}: {wide} of {all} in f64 at {target:e}",
                    f.kind
                );
                wide_before = wide;
            }
        }
    }
}

#[test]
fn all_f32_and_all_f64_are_the_pure_formats_to_the_bit() {
    let model = load("grid_iiwa");
    let m = ir::lower(
        &model,
        G,
        &LowerOptions { kernels: THROUGH_MINV.to_vec(), ..LowerOptions::default() },
    )
    .unwrap();
    for f in &m.functions {
        for s in inputs(&model, f, 3, 11) {
            let narrow: Vec<Vec<f64>> = f
                .eval_f32(&refs(&s))
                .into_iter()
                .map(|o| o.into_iter().map(f64::from).collect())
                .collect();
            assert_eq!(f.eval_mixed(&refs(&s), &vec![false; f.nodes.len()]), narrow, "{}", f.kind);
            assert_eq!(
                f.eval_mixed(&refs(&s), &vec![true; f.nodes.len()]),
                f.eval(&refs(&s)),
                "{}",
                f.kind
            );
        }
    }
}

/// The emitted mixed Rust, compiled with rustc -O, against `eval_mixed`, every output bit:
/// iiwa's fd_grad (3 chunks) and HyQ's minv at 1e-9, where both precisions and every
/// conversion occur.
#[test]
fn emitted_mixed_rust_computes_the_interpreters_numbers() {
    let work = std::env::temp_dir().join(format!("grid-gen-mixed-test-{}", std::process::id()));
    std::fs::create_dir_all(&work).unwrap();
    let mut program = String::from("#![allow(dead_code, clippy::all)]\nfn bits(v: &[f64]) { for x in v { print!(\"{:016x} \", x.to_bits()); } println!(); }\n");
    let mut main = String::from("fn main() {\n");
    let mut expected = String::new();
    for (i, (robot, kind)) in
        [("grid_iiwa", KernelKind::FdGrad), ("grid_hyq", KernelKind::Minv)].into_iter().enumerate()
    {
        let model = load(robot);
        let m =
            ir::lower(&model, G, &LowerOptions { kernels: vec![kind], ..LowerOptions::default() })
                .unwrap();
        let f = &m.functions[0];
        let plan = mixed_plan(&model, G, f, 1e-9);
        let (wide, all) = plan.wide_operations(f);
        assert!(wide > 0 && wide < all);
        program += &format!("mod k{i} {{\nconst NV: usize = {};\n", model.nv());
        grid_gen::back::rust::emit_mixed_kernel(
            &mut program,
            f,
            "NV",
            &grid_gen::back::rust::RustOptions { chunk: 2500, ..Default::default() },
            &plan.wide,
        );
        program += "}\n";
        for s in inputs(&model, f, 3, 13) {
            let args: Vec<String> = s.iter().map(|v| format!("&{:?}", v)).collect();
            let outs: Vec<String> = (0..f.outputs.len()).map(|o| format!("o{o}")).collect();
            let pattern =
                if outs.len() == 1 { outs[0].clone() } else { format!("({})", outs.join(", ")) };
            main += &format!("{{ let {pattern} = k{i}::{}({});\n", f.kind.name(), args.join(", "));
            for (o, out) in f.outputs.iter().enumerate() {
                let flat = if out.shape == ir::Shape::Matrix {
                    format!("o{o}.concat()")
                } else {
                    format!("o{o}.to_vec()")
                };
                main += &format!("bits(&{flat});\n");
            }
            main += "}\n";
            for out in f.eval_mixed(&refs(&s), &plan.wide) {
                expected +=
                    &out.iter().map(|x| format!("{:016x} ", x.to_bits())).collect::<String>();
                expected += "\n";
            }
        }
    }
    program += &main;
    program += "}\n";
    std::fs::write(work.join("main.rs"), &program).unwrap();
    let exe = work.join("mixed");
    let rustc = grid_gen::tools::rustc::rustc();
    let out = std::process::Command::new(&rustc)
        .args(["--edition", "2021", "-C", "opt-level=3", "-o"])
        .arg(&exe)
        .arg(work.join("main.rs"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let run = std::process::Command::new(&exe).output().unwrap();
    assert!(run.status.success());
    assert_eq!(String::from_utf8_lossy(&run.stdout), expected);
    std::fs::remove_dir_all(&work).unwrap();
}
