//! Which stages of `minv`, `fd` and `fd_grad` the mixed-precision plans keep in f64, per
//! bundled robot and target, and how many operands cross between f32 and f64 (each a
//! conversion) (the book's mixed-precision section quotes it):
//! `cargo run --release -p grid-gen --example mixed_stages`.

use grid_gen::ir::{self, KernelKind, LowerOptions};
fn main() {
    for robot in ["grid_iiwa", "grid_hyq", "grid_atlas"] {
        let path = format!("robots/{robot}.urdf");
        let model =
            grid_gen::Model::from_urdf_str(&path, &std::fs::read_to_string(&path).unwrap(), false)
                .unwrap()
                .0;
        let g = [0.0, 0.0, -9.81];
        let m = ir::lower(
            &model,
            g,
            &LowerOptions {
                kernels: vec![KernelKind::Minv, KernelKind::Fd, KernelKind::FdGrad],
                ..Default::default()
            },
        )
        .unwrap();
        for f in &m.functions {
            for target in [1e-6, 1e-9, 1e-12] {
                // Operations per stage: (in f64, all).
                let plan = grid_gen::accuracy::mixed_plan(&model, g, f, target);
                let mut by: std::collections::BTreeMap<String, (usize, usize)> = Default::default();
                let mut conversions = 0;
                for (i, n) in f.nodes.iter().enumerate() {
                    if !f.is_operation(ir::Id(i as u32)) {
                        continue;
                    }
                    conversions += n
                        .op
                        .operands()
                        .filter(|&o| f.is_operation(o) && plan.wide[o.0 as usize] != plan.wide[i])
                        .count();
                    let e = by.entry(format!("{:?}", n.stage)).or_default();
                    e.1 += 1;
                    if plan.wide[i] {
                        e.0 += 1;
                    }
                }
                let (w, a) = plan.wide_operations(f);
                println!("{robot} {} {target:e}: {w}/{a} in f64, {conversions} conversions, by stage {:?}", f.kind, by);
            }
        }
    }
}
