//! Operation counts of the two RNEA-gradient formulations for each bundled robot (the
//! figures of the README's gradient table): `cargo run --release -p grid-gen --example gradient_ops`.

use grid_gen::ir::{self, Gradient, KernelKind, LowerOptions};

fn main() {
    let robots = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../robots");
    let mut names: Vec<_> =
        std::fs::read_dir(&robots).expect("robots/").filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "urdf")).collect();
    names.sort();
    println!("| robot | kernel | columns | idsva | auto picks |");
    println!("|---|---|---:|---:|---|");
    for path in names {
        let text = std::fs::read_to_string(&path).expect("bundled robot reads");
        let (model, _) = grid_gen::Model::from_urdf_str(&path.to_string_lossy(), &text, false).expect("bundled robot loads");
        for kind in [KernelKind::RneaGrad, KernelKind::FdGrad] {
            let ops = |gradient| {
                let options = LowerOptions { kernels: vec![kind], gradient, ..LowerOptions::default() };
                let f = ir::lower_function(&model, [0.0, 0.0, -9.81], kind, &options).expect("lowers");
                (f.nodes.iter().filter(|n| !matches!(n.op, ir::Op::Const(_) | ir::Op::Input(..))).count(), f.gradient)
            };
            let (c, _) = ops(Gradient::Columns);
            let (i, _) = ops(Gradient::Idsva);
            let (_, pick) = ops(Gradient::Auto);
            println!("| {} | {} | {c} | {i} | {} |", model.name, kind, pick.map_or("-", |g| g.name()));
        }
    }
}
