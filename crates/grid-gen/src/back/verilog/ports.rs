//! Port names of a netlist: inputs `<sin_q|cos_q|q|qd|qdd>_<index>_<joint name>` (the
//! index into the input: q's for sin, cos and q), forces `fext_<index>_<joint>_<fx…tz>`
//! and `lambda_<index>_<frame>_<fx…tz>`, each quaternion's `quat_scale…`, M⁻¹'s
//! `minv_<row>_<column>` (the upper triangle),
//! outputs `<output>_<row>_<column>` for the non-zero entries only. Joint names go through
//! the shared namer (`[a-z0-9_]`, never a reserved word); the joint index keeps them
//! unique whatever the names are.

use crate::back::names::{comment_text, identifier};
use crate::datapath::{Datapath, HwId, Port};
use crate::ir::{Input, Robot};

/// The names of a datapath's ports, in port order (inputs) and output order.
#[derive(Clone, Debug, PartialEq)]
pub struct PortNames {
    pub inputs: Vec<String>,
    /// (name, node) of every non-zero output entry: outputs in kernel order, matrices
    /// row-major.
    pub outputs: Vec<(String, HwId)>,
}

/// The components of a force entry, Pinocchio's order.
const FORCE_COMPONENTS: [&str; 6] = ["fx", "fy", "fz", "tx", "ty", "tz"];

/// An input port's name. q-indexed ports (sin, cos, q) name the q entry (`Robot::q_name`:
/// a joint, the floating base's `base_x` … `base_qw`, a spherical joint's `<name>_qx` …);
/// a spherical joint's quaternion scale is `quat_scale_<k>_<name>`, the base's `quat_scale`.
fn input_name(robot: &Robot, p: Port) -> String {
    let q_indexed = matches!(p, Port::Sin(_) | Port::Cos(_) | Port::Value(Input::Q, _));
    let k = p.joint();
    match p {
        Port::QuatScale(3) if robot.floating => "quat_scale".to_string(),
        // M⁻¹'s entries are numbered by coordinate (the row and column of ∂q̈).
        Port::Minv(i, k) => format!("minv_{i}_{k}"),
        Port::QuatScale(_) => format!(
            "quat_scale_{k}_{}",
            identifier(robot.q_name(k).strip_suffix("_qx").unwrap_or_default())
        ),
        _ if q_indexed => format!("{}_{k}_{}", p.prefix(), identifier(&robot.q_name(k))),
        // A force entry: the body's joint or the contact's frame, and the component.
        Port::Value(Input::Fext, _) => {
            format!("fext_{k}_{}_{}", identifier(&robot.fext[k / 6]), FORCE_COMPONENTS[k % 6])
        }
        Port::Value(Input::Lambda, _) => {
            let mut at = 0;
            let contact = robot
                .contacts
                .iter()
                .find(|c| {
                    at += c.kind.dim();
                    k < at
                })
                .expect("a λ port names a declared contact");
            let component = FORCE_COMPONENTS[k + contact.kind.dim() - at];
            format!("lambda_{k}_{}_{component}", identifier(&contact.frame))
        }
        _ => format!("{}_{k}_{}", p.prefix(), identifier(&robot.joint_names[k])),
    }
}

impl PortNames {
    pub fn new(robot: &Robot, dp: &Datapath) -> PortNames {
        let inputs = dp.ports.iter().map(|&p| input_name(robot, p)).collect();
        let outputs = dp
            .nonzero_outputs()
            .into_iter()
            .map(|(k, e, id)| {
                let o = &dp.outputs[k];
                let index: Vec<String> =
                    o.shape.index(e, &dp.dims).iter().map(|i| i.to_string()).collect();
                let name = format!("{}_{}", o.name, index.join("_"));
                (name, id)
            })
            .collect();
        PortNames { inputs, outputs }
    }

    /// The port table for the file header.
    pub fn doc(&self, robot: &Robot) -> String {
        let mut s = String::from("//   joints: ");
        let joints: Vec<String> = robot
            .joint_names
            .iter()
            .enumerate()
            .map(|(i, n)| format!("{i} \"{}\"", comment_text(n)))
            .collect();
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
