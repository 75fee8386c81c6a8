//! One copy of the kernels instead of the dispatched pair (`--copies`, `Builder::copies`,
//! what `grid_gen.load` builds): a module with only `fma` or only `portable` gives the
//! dispatched module's values for that copy bit for bit, and holds nothing else.

use grid_gen::back::rust::Copies;
use grid_gen::generate::{generate, Options, Target};
use grid_gen::ir::{KernelKind, LowerOptions};
use grid_gen_test_support::*;

#[test]
fn one_copy_gives_the_dispatched_copys_values_bit_for_bit() {
    let model = load("grid_iiwa");
    let lower = LowerOptions {
        kernels: vec![KernelKind::Rnea, KernelKind::RneaGrad, KernelKind::Fd],
        ..LowerOptions::default()
    };
    let module = |copies: Copies| -> String {
        let mut options =
            Options { targets: vec![Target::Rust], lower: lower.clone(), ..Options::default() };
        options.rust.copies = copies;
        generate(&model, &options).unwrap().remove(0).contents
    };
    let (dispatch, fma, portable) =
        (module(Copies::Dispatch), module(Copies::Fma), module(Copies::Portable));
    assert!(dispatch.contains("pub mod portable") && dispatch.contains("pub mod fma"));
    assert!(!fma.contains("pub mod portable") && fma.contains("pub mod fma"));
    assert!(portable.contains("pub mod portable") && !portable.contains("pub mod fma"));
    assert!(fma.len() < dispatch.len() * 2 / 3 && portable.len() < dispatch.len() * 2 / 3);
    let robot_rs = format!(
        "pub mod dispatch {{\n{dispatch}\n}}\npub mod fma_only {{\n{fma}\n}}\npub mod portable_only {{\n{portable}\n}}\n"
    );
    let said = compile_and_run(
        "copies",
        &robot_rs,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            r#"const NV: usize = dispatch::NV;
fn bits(rnea: [f64; NV], grad: ([[f64; NV]; NV], [[f64; NV]; NV]), fd: [f64; NV]) -> Vec<u64> {
    rnea.iter().chain(grad.0.as_flattened()).chain(grad.1.as_flattened()).chain(&fd).map(|x| x.to_bits()).collect()
}
fn main() {
    for k in 0..4 {
        let [q, qd, u]: [[f64; NV]; 3] = std::array::from_fn(|salt| std::array::from_fn(|i| state(k, i, salt)));
        let both = bits(dispatch::rnea(&q, &qd, &u), dispatch::rnea_grad(&q, &qd, &u), dispatch::fd(&q, &qd, &u));
        let portable = bits(dispatch::portable::rnea(&q, &qd, &u), dispatch::portable::rnea_grad(&q, &qd, &u), dispatch::portable::fd(&q, &qd, &u));
        let only = bits(portable_only::rnea(&q, &qd, &u), portable_only::rnea_grad(&q, &qd, &u), portable_only::fd(&q, &qd, &u));
        println!("portable {}", only == portable);
        if dispatch::has_fma() {
            let fma = bits(fma_only::rnea(&q, &qd, &u), fma_only::rnea_grad(&q, &qd, &u), fma_only::fd(&q, &qd, &u));
            println!("fma {}", fma == both);
        }
    }
}
"#,
        ]
        .concat(),
    );
    assert!(said.lines().count() >= 4, "{said}");
    assert!(said.lines().all(|l| l.ends_with(" true")), "a copy alone differs:\n{said}");
    println!("{said}");
}
