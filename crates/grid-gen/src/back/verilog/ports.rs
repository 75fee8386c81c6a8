//! Port names of a netlist: inputs `<sin_q|cos_q|q|qd|qdd>_<joint index>_<joint name>`,
//! outputs `<output>_<row>_<column>` for the non-zero entries only. Joint names go through
//! the shared namer (`[a-z0-9_]`, never a reserved word); the joint index keeps them
//! unique whatever the names are.

use crate::back::names::{comment_text, identifier};
use crate::ir::fixed::{Datapath, HwId};
use crate::ir::{Robot, Shape};

/// The names of a datapath's ports, in port order (inputs) and output order.
#[derive(Clone, Debug, PartialEq)]
pub struct PortNames {
    pub inputs: Vec<String>,
    /// (name, node) of every non-zero output entry: outputs in kernel order, matrices
    /// row-major.
    pub outputs: Vec<(String, HwId)>,
}

impl PortNames {
    pub fn new(robot: &Robot, dp: &Datapath) -> PortNames {
        let inputs = dp.ports.iter().map(|p| format!("{}_{}_{}", p.prefix(), p.joint(), identifier(&robot.joint_names[p.joint()]))).collect();
        let outputs = dp
            .nonzero_outputs()
            .into_iter()
            .map(|(k, e, id)| {
                let o = &dp.outputs[k];
                let name = match o.shape {
                    Shape::Vector => format!("{}_{e}", o.name),
                    Shape::Matrix => format!("{}_{}_{}", o.name, e / dp.nv, e % dp.nv),
                };
                (name, id)
            })
            .collect();
        PortNames { inputs, outputs }
    }

    /// The port table for the file header.
    pub fn doc(&self, robot: &Robot) -> String {
        let mut s = String::from("//   joints: ");
        let joints: Vec<String> = robot.joint_names.iter().enumerate().map(|(i, n)| format!("{i} \"{}\"", comment_text(n))).collect();
        s.push_str(&joints.join(", "));
        s.push_str("\n//   inputs, in this order: ");
        s.push_str(&self.inputs.join(", "));
        s.push_str("\n//   outputs `<name>_<i>_<j>` = d out_i / d in_j (matrices) or `<name>_<i>`, structural zeros omitted, in this order:\n//     ");
        let names: Vec<&str> = self.outputs.iter().map(|(n, _)| n.as_str()).collect();
        for (i, chunk) in names.chunks(12).enumerate() {
            if i > 0 {
                s.push_str("\n//     ");
            }
            s.push_str(&chunk.join(", "));
        }
        s.push('\n');
        s
    }
}
