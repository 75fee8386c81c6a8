use grid_gen::ir::{self, KernelKind, LowerOptions};
fn main() {
    for robot in ["grid_iiwa", "grid_hyq", "grid_atlas"] {
        let path = format!("robots/{robot}.urdf");
        let model = grid_gen::Model::from_urdf_str(&path, &std::fs::read_to_string(&path).unwrap(), false).unwrap().0;
        let g = [0.0, 0.0, -9.81];
        let m = ir::lower(&model, g, &LowerOptions { kernels: vec![KernelKind::Minv, KernelKind::Fd, KernelKind::FdGrad], ..Default::default() }).unwrap();
        for f in &m.functions {
            for target in [1e-6, 1e-12] {
                let plan = grid_gen::accuracy::mixed_plan(&model, g, f, target);
                let mut conv = 0;
                for (i, n) in f.nodes.iter().enumerate() {
                    if !f.is_operation(ir::Id(i as u32)) {
                        continue;
                    }
                    for o in n.op.operands() {
                        if f.is_operation(o) && plan.wide[o.0 as usize] != plan.wide[i] {
                            conv += 1;
                        }
                    }
                }
                let (w, a) = plan.wide_operations(f);
                println!("{robot} {} {target:e}: {w}/{a} conversions {conv}", f.kind);
            }
        }
    }
}
