//! Forward-mode differentiation of a graph under construction: the derivative of some
//! nodes along one direction of the inputs, recorded as new nodes of the same graph. With
//! folding on, every term with a zero tangent folds away, so the derivative keeps the
//! graph's structural sparsity (a frame's acceleration gets no column for a joint off its
//! path). The rules are the usual ones (d(ab) = da·b + a·db, d sin a = cos a·da, ...).

use super::graph::{Graph, Id, Input, Op};

impl Graph {
    /// The derivatives of `outputs` along the direction whose input tangents `seeds` lists
    /// (`(input, entry, tangent node)`; every other input entry has tangent 0).
    pub fn tangent(&mut self, outputs: &[Id], seeds: &[(Input, usize, Id)]) -> Vec<Id> {
        self.tangent_at(outputs, seeds, &[])
    }

    /// [`Graph::tangent`] with the tangents of some nodes given (`(node, tangent)`): what
    /// those nodes depend on is not followed, so the derivative is the partial one that
    /// holds them at their values (the step's `∂(q ⊕ w)/∂q` at fixed `w`).
    pub fn tangent_at(
        &mut self,
        outputs: &[Id],
        seeds: &[(Input, usize, Id)],
        nodes: &[(Id, Id)],
    ) -> Vec<Id> {
        // Only nodes up to the last output can feed one: a column's tangent then costs what
        // its outputs depend on, not the whole graph (the contacts take one per column).
        let n = outputs.iter().map(|o| o.0 as usize + 1).max().unwrap_or(0);
        let given: std::collections::HashMap<usize, Id> =
            nodes.iter().map(|&(x, t)| (x.0 as usize, t)).collect();
        let mut live = vec![false; n];
        for o in outputs {
            live[o.0 as usize] = true;
        }
        for i in (0..n).rev() {
            if live[i] && !given.contains_key(&i) {
                for operand in self.nodes[i].op.operands() {
                    live[operand.0 as usize] = true;
                }
            }
        }
        let zero = self.constant(0.0);
        let mut dt = vec![zero; n];
        for i in 0..n {
            if !live[i] {
                continue;
            }
            if let Some(&t) = given.get(&i) {
                dt[i] = t;
                continue;
            }
            let d = |x: Id| dt[x.0 as usize];
            dt[i] = match self.nodes[i].op {
                Op::Input(which, j) => {
                    seeds.iter().find(|s| s.0 == which && s.1 == j as usize).map_or(zero, |s| s.2)
                }
                Op::Const(_) => zero,
                Op::Add(a, b) => {
                    let (da, db) = (d(a), d(b));
                    self.add(da, db)
                }
                Op::Sub(a, b) => {
                    let (da, db) = (d(a), d(b));
                    self.sub(da, db)
                }
                Op::Mul(a, b) => {
                    let (da, db) = (d(a), d(b));
                    let x = self.mul(da, b);
                    let y = self.mul(a, db);
                    self.add(x, y)
                }
                // d(a/b) = (da − (a/b)·db) / b.
                Op::Div(a, b) => {
                    let (da, db) = (d(a), d(b));
                    let y = self.mul(Id(i as u32), db);
                    let num = self.sub(da, y);
                    if self.value(num) == Some(0.0) {
                        zero
                    } else {
                        self.div(num, b)
                    }
                }
                Op::Neg(a) => {
                    let da = d(a);
                    self.neg(da)
                }
                Op::Sin(a) if d(a) != zero => {
                    let (c, da) = (self.cos(a), d(a));
                    self.mul(c, da)
                }
                Op::Cos(a) if d(a) != zero => {
                    let (s, da) = (self.sin(a), d(a));
                    let m = self.mul(s, da);
                    self.neg(m)
                }
                Op::Sin(_) | Op::Cos(_) => zero,
                // d√a = da / (2√a).
                Op::Sqrt(a) => {
                    let da = d(a);
                    if da == zero {
                        zero
                    } else {
                        let two = self.constant(2.0);
                        let r = self.mul(two, Id(i as u32));
                        self.div(da, r)
                    }
                }
            };
        }
        outputs.iter().map(|o| dt[o.0 as usize]).collect()
    }
}
