//! IR validation, run on every lowered function: what every backend may rely on. Operands
//! come before their users, constants are finite, inputs are kernel inputs within the
//! robot's joints, outputs have their declared length and point at existing nodes, and a
//! product or program writes only outputs the function has.

use super::graph::{Id, Op};
use super::module::Function;

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ValidationError {
    #[error("node {node} reads node {operand}, which does not come before it")]
    OperandOrder { node: u32, operand: u32 },
    #[error("node {node} is a non-finite constant ({value})")]
    NotFinite { node: u32, value: f64 },
    #[error("node {node} reads input `{input}[{joint}]`, which the kernel does not have")]
    BadInput { node: u32, input: &'static str, joint: u16 },
    #[error("output `{output}` has {got} values, expected {expected}")]
    OutputLength { output: &'static str, got: usize, expected: usize },
    #[error("output `{output}` refers to node {node}, past the last node")]
    OutputRange { output: &'static str, node: u32 },
    #[error("the kernel's {what} writes output `{output}`, which it does not have")]
    UnknownOutput { what: &'static str, output: &'static str },
}

/// Checks `f` for a robot of sizes `dims`.
pub fn validate(f: &Function, dims: &crate::ir::Dims) -> Result<(), ValidationError> {
    for (i, node) in f.nodes.iter().enumerate() {
        let i = i as u32;
        for Id(o) in node.op.operands() {
            if o >= i {
                return Err(ValidationError::OperandOrder { node: i, operand: o });
            }
        }
        match node.op {
            Op::Const(value) if !value.is_finite() => {
                return Err(ValidationError::NotFinite { node: i, value })
            }
            Op::Input(input, joint)
                if !f.inputs().contains(&input) || joint as usize >= input.len(dims) =>
            {
                return Err(ValidationError::BadInput { node: i, input: input.name(), joint })
            }
            _ => {}
        }
    }
    for o in &f.outputs {
        let expected = o.shape.len(dims);
        if o.ids.len() != expected {
            return Err(ValidationError::OutputLength {
                output: o.name,
                got: o.ids.len(),
                expected,
            });
        }
        if let Some(id) = o.ids.iter().find(|id| id.0 as usize >= f.nodes.len()) {
            return Err(ValidationError::OutputRange { output: o.name, node: id.0 });
        }
    }
    let products = f.product.iter().flat_map(|p| p.outputs.iter().map(|&o| ("product", o)));
    let stores = f.program.iter().flat_map(|p| p.blocks.iter()).flat_map(|b| &b.stores);
    for (what, output) in products.chain(stores.map(|st| ("program", st.output))) {
        if f.output_index(output).is_none() {
            return Err(ValidationError::UnknownOutput { what, output });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::{KernelKind, Node, Output, Shape, Stage};

    fn dims(n: usize) -> crate::ir::Dims {
        crate::ir::Dims {
            nq: n,
            nv: n,
            nu: n,
            nframes: 0,
            nfext: 0,
            nlambda: 0,
            ncontacts: 0,
            nbaumgarte: 0,
            ncontact_ref: 0,
        }
    }

    fn node(op: Op) -> Node {
        Node { op, link: None, stage: Stage::Forward, level: 0 }
    }

    fn function(nodes: Vec<Op>, out: Vec<u32>) -> Function {
        Function {
            kind: KernelKind::Rnea,
            inputs: KernelKind::Rnea.inputs().to_vec(),
            dims: dims(1),
            gradient: None,
            solve: None,
            nodes: nodes.into_iter().map(node).collect(),
            outputs: vec![Output {
                name: "c",
                shape: Shape::Vector,
                ids: out.into_iter().map(Id).collect(),
            }],
            product: None,
            program: None,
            call: None,
        }
    }

    #[test]
    fn accepts_a_well_formed_function() {
        let f = function(
            vec![Op::Input(crate::ir::Input::Qd, 0), Op::Const(2.0), Op::Mul(Id(0), Id(1))],
            vec![2],
        );
        assert_eq!(validate(&f, &dims(1)), Ok(()));
    }

    #[test]
    fn rejects_each_kind_of_defect() {
        use crate::ir::Input;
        let f = function(vec![Op::Const(1.0), Op::Add(Id(1), Id(0))], vec![1]);
        assert_eq!(
            validate(&f, &dims(1)),
            Err(ValidationError::OperandOrder { node: 1, operand: 1 })
        );
        let f = function(vec![Op::Const(f64::INFINITY)], vec![0]);
        assert!(matches!(validate(&f, &dims(1)), Err(ValidationError::NotFinite { node: 0, .. })));
        let f = function(vec![Op::Input(Input::Tau, 0)], vec![0]);
        assert!(matches!(validate(&f, &dims(1)), Err(ValidationError::BadInput { .. })));
        let f = function(vec![Op::Input(Input::Q, 3)], vec![0]);
        assert!(matches!(validate(&f, &dims(2)), Err(ValidationError::BadInput { joint: 3, .. })));
        let f = function(vec![Op::Const(1.0)], vec![0]);
        assert_eq!(
            validate(&f, &dims(2)),
            Err(ValidationError::OutputLength { output: "c", got: 1, expected: 2 })
        );
        let f = function(vec![Op::Const(1.0)], vec![5]);
        assert_eq!(
            validate(&f, &dims(1)),
            Err(ValidationError::OutputRange { output: "c", node: 5 })
        );
        let mut f = function(vec![Op::Const(1.0)], vec![0]);
        let store = crate::ir::ColumnStore { row: 0, output: "dc", flat: vec![0], negate: false };
        let block = crate::ir::ColumnBlock { init: vec![], steps: vec![], stores: vec![store] };
        f.program = Some(crate::ir::ColumnProgram { rows: 1, blocks: vec![block], replaces: None });
        assert_eq!(
            validate(&f, &dims(1)),
            Err(ValidationError::UnknownOutput { what: "program", output: "dc" })
        );
    }
}
