use grid_gen::back::verilog::*;
use grid_gen::ir::{self, KernelKind, LowerOptions};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let text = std::fs::read_to_string(format!("robots/{}.urdf", args[1])).unwrap();
    let (model, _) = grid_gen::Model::from_urdf_str(&args[1], &text, false).unwrap();
    let m = ir::lower(&model, [0.0, 0.0, -9.81], &LowerOptions { kernels: vec![KernelKind::RneaGrad, KernelKind::MassMatrix], ..Default::default() }).unwrap();
    for arch in [Arch::Pipelined { stage_depth: 4 }, Arch::Shared { multipliers: 8, adders: 8 }] {
        for n in plan(&m, &VerilogOptions { arch, ..Default::default() }).unwrap() {
            let p = format!("{}/{}_{}.v", args[2], n.top, arch.name());
            std::fs::write(&p, n.verilog(&m.robot)).unwrap();
            println!("{p} {:?}", n.stats());
        }
    }
}
