use grid_gen::ir::{self, fixed::*, KernelKind, LowerOptions};
fn main() {
    for robot in ["double_pendulum_continuous", "ur5", "grid_iiwa", "grid_hyq"] {
        let text = std::fs::read_to_string(format!("robots/{robot}.urdf")).unwrap();
        let (model, _) = grid_gen::Model::from_urdf_str(robot, &text, false).unwrap();
        let m =
            ir::lower(&model, [0.0, 0.0, -9.81], &LowerOptions { kernels: vec![KernelKind::RneaGrad, KernelKind::MassMatrix], ..Default::default() }).unwrap();
        let b = Bounds::new(&m.robot, None, None);
        for f in &m.functions {
            let dp = Datapath::new(f, m.robot.nv()).unwrap();
            let a = analyse(&dp, &b, 16, Rounding::Truncate);
            println!(
                "{robot} {} ports {} nodes {} ops {:?} needed {:.3e} err@16 {:.3e}",
                dp.kernel,
                dp.ports.len(),
                dp.nodes.len(),
                dp.op_counts(),
                a.needed,
                a.output_error
            );
            let mut seed = 12345u64;
            let mut rnd = || {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            };
            let mut maxv = 0.0f64;
            for _ in 0..2000 {
                let q: Vec<f64> = (0..m.robot.nv()).map(|_| 3.0 * rnd()).collect();
                let ports: Vec<f64> = dp
                    .ports
                    .iter()
                    .map(|p| match *p {
                        Port::Sin(j) => q[j as usize].sin(),
                        Port::Cos(j) => q[j as usize].cos(),
                        Port::Value(i, j) => {
                            let (lo, hi) = match i {
                                ir::Input::Q => b.q[j as usize],
                                ir::Input::Qd => (-b.qd[j as usize], b.qd[j as usize]),
                                _ => (-b.qdd[j as usize], b.qdd[j as usize]),
                            };
                            let r = rnd().signum();
                            if r > 0.0 {
                                hi
                            } else {
                                lo
                            }
                        }
                    })
                    .collect();
                maxv = dp.values_f64(&ports).iter().fold(maxv, |m, v| m.max(v.abs()));
            }
            println!("   sampled max {maxv:.3e}");
            for w in [16, 24, 32, 48, 64] {
                if let Some((fm, a)) = format_for_width(&dp, &b, Rounding::HalfUp, w) {
                    println!("   w{w} -> {} err {:.3e}", fm.label(), a.output_error);
                }
            }
        }
    }
}
#[allow(dead_code)]
fn unused() {}
