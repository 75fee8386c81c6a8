//! Operation counts of the three RNEA-gradient formulations for each bundled robot, and of
//! `fd_grad`'s two M⁻¹ routes (the figures of the book's gradient tables):
//! `cargo run --release -p grid-gen --example gradient_ops`.

use grid_gen::ir::{self, Gradient, KernelKind, LowerOptions, Solve};

fn main() {
    let robots = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../robots");
    let mut names: Vec<_> = std::fs::read_dir(&robots)
        .expect("robots/")
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "urdf"))
        .collect();
    names.sort();
    let mut routes = String::from("\n| robot | `fd_grad`, minv | `fd_grad`, ltdl | `fd_grad`, crba | auto picks |\n|---|---:|---:|---:|---|\n");
    println!("| robot | kernel | columns | idsva | world | auto picks |");
    println!("|---|---|---:|---:|---:|---|");
    for path in names {
        let text = std::fs::read_to_string(&path).expect("bundled robot reads");
        let (model, _) = grid_gen::Model::from_urdf_str(&path.to_string_lossy(), &text, false)
            .expect("bundled robot loads");
        for kind in [KernelKind::RneaGrad, KernelKind::FdGrad] {
            let ops = |gradient, solve| {
                let options = LowerOptions {
                    kernels: vec![kind],
                    gradient,
                    solve,
                    ..LowerOptions::default()
                };
                let f =
                    ir::lower_function(&model, [0.0, 0.0, -9.81], kind, &options).expect("lowers");
                (
                    f.nodes
                        .iter()
                        .filter(|n| !matches!(n.op, ir::Op::Const(_) | ir::Op::Input(..)))
                        .count(),
                    f.gradient,
                    f.solve,
                )
            };
            let (c, _, _) = ops(Gradient::Columns, Solve::Auto);
            let (i, _, _) = ops(Gradient::Idsva, Solve::Auto);
            let (w, _, _) = ops(Gradient::World, Solve::Auto);
            let (_, pick, _) = ops(Gradient::Auto, Solve::Auto);
            println!(
                "| {} | {} | {c} | {i} | {w} | {} |",
                model.name,
                kind,
                pick.map_or("-", |g| g.name())
            );
            if kind == KernelKind::FdGrad {
                let (m, _, _) = ops(Gradient::Auto, Solve::Minv);
                let (l, _, _) = ops(Gradient::Auto, Solve::Ltdl);
                let (c, _, _) = ops(Gradient::Auto, Solve::Crba);
                let (_, _, route) = ops(Gradient::Auto, Solve::Auto);
                routes += &format!(
                    "| {} | {m} | {l} | {c} | {} |\n",
                    model.name,
                    route.map_or("-", |s| s.name())
                );
            }
        }
    }
    print!("{routes}");
}
