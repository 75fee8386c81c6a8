//! `fd_grad`'s chip partition as one datapath: the bias forces, M, its LTDL factorisation
//! with one reciprocal per pivot, q̈ = M⁻¹(τ − c), ∂c/∂u at that q̈ and ∂q̈/∂u = −M⁻¹ ∂c/∂u
//! (the seeds' Algorithm 3 with nothing left to the host but sin and cos), composed from
//! the datapaths of `rnea`, `mass_matrix` and `rnea_grad` with their common nodes shared.
//! The factorisation's values carry the bounds positive definiteness proves ([`Clamp`]).

use std::collections::HashMap;

use super::{Clamp, Datapath, DatapathOutput, Factor, HwId, HwOp, Port, SolveStage};
use crate::ir::{Input, Shape};

/// Nodes under construction, each distinct operation once (the three kernels compute the
/// same transforms), with constant zeros, ones and minus ones folded away.
struct Builder {
    ports: Vec<Port>,
    nodes: Vec<HwOp>,
    links: Vec<Option<u16>>,
    clamps: Vec<Option<Clamp>>,
    factor: Factor,
    memo: HashMap<(u8, u64, u32), HwId>,
}

impl Builder {
    fn new() -> Builder {
        Builder {
            ports: Vec::new(),
            nodes: Vec::new(),
            links: Vec::new(),
            clamps: Vec::new(),
            factor: Factor::default(),
            memo: HashMap::new(),
        }
    }

    fn constant(&self, id: HwId) -> Option<f64> {
        match self.nodes[id.0 as usize] {
            HwOp::Const(c) => Some(c),
            _ => None,
        }
    }

    fn push(&mut self, op: HwOp, link: Option<u16>) -> HwId {
        let c = |x: HwId| self.constant(x);
        // Exact identities only: each leaves the fixed-point value unchanged too.
        match op {
            HwOp::Add(a, b) if c(a) == Some(0.0) => return b,
            HwOp::Add(a, b) | HwOp::Sub(a, b) if c(b) == Some(0.0) => return a,
            HwOp::Sub(a, b) if c(a) == Some(0.0) => return self.push(HwOp::Neg(b), link),
            HwOp::Mul(a, b) if c(a) == Some(0.0) || c(b) == Some(0.0) => {
                return if c(a) == Some(0.0) { a } else { b }
            }
            HwOp::Mul(a, b) if c(a) == Some(1.0) => return b,
            HwOp::Mul(a, b) if c(b) == Some(1.0) => return a,
            HwOp::Mul(a, b) if c(a) == Some(-1.0) => return self.push(HwOp::Neg(b), link),
            HwOp::Mul(a, b) if c(b) == Some(-1.0) => return self.push(HwOp::Neg(a), link),
            HwOp::Neg(a) if c(a) == Some(0.0) => return a,
            // Exact: constants round symmetrically (half away from zero).
            HwOp::Neg(a) if c(a).is_some() => {
                return self.push(HwOp::Const(-c(a).expect("constant")), link)
            }
            // A pivot that does not depend on the state (a leaf's own inertia about its
            // axis) is divided by the generator, not the chip.
            HwOp::Recip(a) => {
                if let Some(v) = c(a).filter(|v| *v > 0.0) {
                    return self.push(HwOp::Const(v.recip()), link);
                }
            }
            _ => {}
        }
        let (lo, hi) = (|a: HwId, b: HwId| a.min(b), |a: HwId, b: HwId| a.max(b));
        let key = match op {
            HwOp::Port(p) => (0, p as u64, 0),
            HwOp::Const(v) => (1, v.to_bits(), 0),
            HwOp::Add(a, b) => (2, lo(a, b).0 as u64, hi(a, b).0),
            HwOp::Sub(a, b) => (3, a.0 as u64, b.0),
            HwOp::Mul(a, b) => (4, lo(a, b).0 as u64, hi(a, b).0),
            HwOp::Neg(a) => (5, a.0 as u64, 0),
            HwOp::Recip(a) => (6, a.0 as u64, 0),
        };
        if let Some(&id) = self.memo.get(&key) {
            return id;
        }
        self.nodes.push(op);
        self.links.push(link);
        self.clamps.push(None);
        let id = HwId(self.nodes.len() as u32 - 1);
        self.memo.insert(key, id);
        id
    }

    fn port(&mut self, p: Port) -> HwId {
        match self.ports.iter().position(|&q| q == p) {
            Some(n) => self.push(HwOp::Port(n as u32), None),
            None => {
                self.ports.push(p);
                self.push(HwOp::Port(self.ports.len() as u32 - 1), None)
            }
        }
    }

    fn clamp(&mut self, id: HwId, c: Clamp) {
        // A node met twice (shared, or folded onto an operand) keeps its first bound: any
        // of them holds. An entry of M itself (an update folded away) keeps its interval
        // where the bound names a later node.
        if self.nodes[id.0 as usize].is_operation()
            && c.reads(&self.factor)
                .iter()
                .all(|&x| x < id || (x == id && !matches!(c, Clamp::Solve { .. })))
        {
            let slot = &mut self.clamps[id.0 as usize];
            match (*slot, c) {
                // A root's scaled value is its solution: the error analysis needs to know
                // it is one (both bounds hold for its range).
                (
                    Some(Clamp::Solve { solve, k, stage: SolveStage::Scaled }),
                    Clamp::Solve { solve: s2, k: k2, stage: SolveStage::Solution },
                ) if solve == s2 && k == k2 => *slot = Some(c),
                _ => {
                    slot.get_or_insert(c);
                }
            }
        }
    }

    /// Copies `dp`'s nodes in; `subst` replaces ports (e.g. q̈ by computed values).
    fn import(
        &mut self,
        dp: &Datapath,
        subst: impl Fn(&mut Builder, Port) -> Option<HwId>,
    ) -> Vec<HwId> {
        let mut new = Vec::with_capacity(dp.nodes.len());
        for (i, op) in dp.nodes.iter().enumerate() {
            let m = |x: HwId| new[x.0 as usize];
            let link = dp.links[i];
            let id = match *op {
                HwOp::Port(n) => {
                    let p = dp.ports[n as usize];
                    match subst(self, p) {
                        Some(id) => id,
                        None => self.port(p),
                    }
                }
                HwOp::Const(c) => self.push(HwOp::Const(c), None),
                HwOp::Add(a, b) => self.push(HwOp::Add(m(a), m(b)), link),
                HwOp::Sub(a, b) => self.push(HwOp::Sub(m(a), m(b)), link),
                HwOp::Mul(a, b) => self.push(HwOp::Mul(m(a), m(b)), link),
                HwOp::Neg(a) => self.push(HwOp::Neg(m(a)), link),
                HwOp::Recip(a) => self.push(HwOp::Recip(m(a)), link),
            };
            new.push(id);
        }
        new
    }
}

/// M = Lᵀ D L (Featherstone 2005, "Efficient factorization of the joint-space inertia
/// matrix", table 2), with −1/D: what the solves read.
struct Factors {
    /// L's entries, `l[k][i]` for i a strict ancestor of k.
    l: Vec<Vec<Option<HwId>>>,
    neg_dinv: Vec<HwId>,
    parents: Vec<Option<usize>>,
}

fn ancestors(parents: &[Option<usize>], k: usize) -> Vec<usize> {
    std::iter::successors(parents[k], |&j| parents[j]).collect()
}

impl Factors {
    /// −M⁻¹ b: Lᵀ y = b leaves first, z = −D⁻¹ y, L x = z root first; the values after
    /// each stage carry [`Clamp::Solve`]'s bounds.
    fn solve(&self, g: &mut Builder, mut b: Vec<HwId>) -> Vec<HwId> {
        let n = b.len();
        let solve = g.factor.rhs.len() as u32;
        // Zero entries add nothing to β (and may be read by nothing).
        let rhs = (0..n).filter(|&k| g.constant(b[k]) != Some(0.0)).map(|k| (k as u16, b[k]));
        let rhs = rhs.collect();
        g.factor.rhs.push(rhs);
        let bound = |g: &mut Builder, x: HwId, k: usize, stage: SolveStage| {
            g.clamp(x, Clamp::Solve { solve, k: k as u16, stage });
        };
        for k in (0..n).rev() {
            bound(g, b[k], k, SolveStage::Lower);
            for j in ancestors(&self.parents, k) {
                let t = g.push(HwOp::Mul(self.l[k][j].expect("factored"), b[k]), None);
                b[j] = g.push(HwOp::Sub(b[j], t), None);
            }
        }
        for (k, x) in b.iter_mut().enumerate() {
            *x = g.push(HwOp::Mul(*x, self.neg_dinv[k]), None);
            bound(g, *x, k, SolveStage::Scaled);
        }
        for k in 0..n {
            for j in ancestors(&self.parents, k) {
                let t = g.push(HwOp::Mul(self.l[k][j].expect("factored"), b[j]), None);
                b[k] = g.push(HwOp::Sub(b[k], t), None);
            }
            bound(g, b[k], k, SolveStage::Solution);
        }
        b
    }
}

/// The chip partition of `fd_grad` (module doc). `bias` is `rnea`'s datapath (its q̈
/// ports become 0), `mass` `mass_matrix`'s, `dc` `rnea_grad`'s restricted to ∂c/∂q and
/// ∂c/∂q̇ (its q̈ ports become the computed q̈); `parents` the coordinates' tree and
/// `floor[k]` a lower bound on the k-th pivot of M's factorisation, which
/// [`crate::ir::Robot::pivot_floor`] derives from the link inertias, `minv_floor[k]` one
/// on 1 / M⁻¹_kk ([`crate::ir::Robot::minv_floor`]); τ is an input where `actuated`, else
/// zero. Inputs: sin q, cos q, q̇ (and what else the kernels read) and τ; outputs `qdd`,
/// `dqdd_dq`, `dqdd_dqd`.
pub fn fd_grad_chip(
    bias: &Datapath,
    mass: &Datapath,
    dc: &Datapath,
    parents: &[Option<usize>],
    floor: &[f64],
    minv_floor: &[f64],
    actuated: &[bool],
) -> Datapath {
    let nv = mass.nv;
    let mut g = Builder::new();
    let zero = g.push(HwOp::Const(0.0), None);
    let at_rest =
        |_: &mut Builder, p: Port| matches!(p, Port::Value(Input::Qdd, _)).then_some(zero);
    let c = g.import(bias, at_rest);
    let c: Vec<HwId> = bias.outputs[0].ids.iter().map(|id| c[id.0 as usize]).collect();
    let m_ids = g.import(mass, |_, _| None);
    let mut m: Vec<Vec<HwId>> = (0..nv)
        .map(|i| (0..nv).map(|j| m_ids[mass.outputs[0].ids[i * nv + j].0 as usize]).collect())
        .collect();
    let diagonal: Vec<HwId> = (0..nv).map(|i| m[i][i]).collect();
    let entries = (0..nv)
        .flat_map(|i| {
            let m = &m;
            std::iter::once(i)
                .chain(ancestors(parents, i))
                .map(move |j| (i as u16, j as u16, m[i][j]))
        })
        .collect();
    g.factor = Factor {
        diagonal: diagonal.clone(),
        floor: floor.to_vec(),
        minv: minv_floor.iter().map(|f| f.recip()).collect(),
        rhs: Vec::new(),
        parents: parents.iter().map(|p| p.map(|p| p as u16)).collect(),
        entries,
    };

    // The factorisation, rows leaves first; every value a Schur complement's entry (the
    // rows below it eliminated) or L's, bounded as [`Clamp`] says.
    let mut l = vec![vec![None; nv]; nv];
    let mut neg_dinv = vec![zero; nv];
    for k in (0..nv).rev() {
        let link = Some(k as u16);
        g.clamp(m[k][k], Clamp::Pivot { floor: floor[k], diagonal: diagonal[k] });
        let r = g.push(HwOp::Recip(m[k][k]), link);
        neg_dinv[k] = g.push(HwOp::Neg(r), link);
        let up = ancestors(parents, k);
        for (at, &i) in up.iter().enumerate() {
            let lki = g.push(HwOp::Mul(m[k][i], r), link);
            g.clamp(lki, Clamp::Multiplier { diagonal: diagonal[i], floor: floor[k] });
            for &j in &up[at..] {
                let t = g.push(HwOp::Mul(lki, m[k][j]), link);
                g.clamp(t, Clamp::Schur(diagonal[i], diagonal[j]));
                let s = g.push(HwOp::Sub(m[i][j], t), link);
                g.clamp(
                    s,
                    if i == j {
                        Clamp::Pivot { floor: floor[i], diagonal: diagonal[i] }
                    } else {
                        Clamp::Schur(diagonal[i], diagonal[j])
                    },
                );
                m[i][j] = s;
                m[j][i] = s;
            }
            l[k][i] = Some(lki);
        }
    }
    let f = Factors { l, neg_dinv, parents: parents.to_vec() };

    // q̈ = −M⁻¹ (c − τ), with τ = 0 where nothing acts (a floating base).
    let b: Vec<HwId> = (0..nv)
        .map(|j| match actuated[j] {
            true => {
                let tau = g.port(Port::Value(Input::Tau, j as u16));
                g.push(HwOp::Sub(c[j], tau), None)
            }
            false => c[j],
        })
        .collect();
    let qdd = f.solve(&mut g, b);

    let dc_ids = g.import(dc, |_, p| match p {
        Port::Value(Input::Qdd, j) => Some(qdd[j as usize]),
        _ => None,
    });
    let mut outputs = vec![DatapathOutput { name: "qdd", shape: Shape::Vector, ids: qdd.clone() }];
    for (o, name) in dc.outputs.iter().zip(["dqdd_dq", "dqdd_dqd"]) {
        let mut ids = vec![zero; nv * nv];
        for col in 0..nv {
            let b = (0..nv).map(|row| dc_ids[o.ids[row * nv + col].0 as usize]).collect();
            for (row, x) in f.solve(&mut g, b).into_iter().enumerate() {
                ids[row * nv + col] = x;
            }
        }
        outputs.push(DatapathOutput { name, shape: o.shape, ids });
    }
    let _ = qdd;
    // The bounds read M's entries and the right-hand sides: kept (an entry only a folded
    // division read is a constant, which costs nothing).
    let roots: Vec<HwId> = g
        .factor
        .diagonal
        .iter()
        .copied()
        .chain(g.factor.rhs.iter().flat_map(|b| b.iter().map(|r| r.1)))
        .chain(g.factor.entries.iter().map(|e| e.2))
        .collect();
    let live = live_nodes(&g.nodes, &outputs, &roots);
    compact(g, live, outputs, nv, mass.dims)
}

/// Which nodes some output reads (the imports bring in outputs nobody uses, e.g. `rnea`'s
/// is read but the transforms of a leaf's M column may not be).
fn live_nodes(nodes: &[HwOp], outputs: &[DatapathOutput], roots: &[HwId]) -> Vec<bool> {
    let mut live = vec![false; nodes.len()];
    for id in roots {
        live[id.0 as usize] = true;
    }
    for o in outputs {
        for id in &o.ids {
            live[id.0 as usize] = true;
        }
    }
    for i in (0..nodes.len()).rev() {
        if live[i] {
            for a in nodes[i].operands() {
                live[a.0 as usize] = true;
            }
        }
    }
    live
}

/// The live nodes renumbered (the builder's order is topological), and the ports they read.
fn compact(
    g: Builder,
    live: Vec<bool>,
    outputs: Vec<DatapathOutput>,
    nv: usize,
    dims: crate::ir::Dims,
) -> Datapath {
    let mut new = vec![HwId(u32::MAX); g.nodes.len()];
    let (mut ports, mut nodes, mut links, mut clamps) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (i, op) in g.nodes.iter().enumerate() {
        if !live[i] {
            continue;
        }
        let m = |x: HwId| new[x.0 as usize];
        let op = match *op {
            HwOp::Port(n) => {
                ports.push(g.ports[n as usize]);
                HwOp::Port(ports.len() as u32 - 1)
            }
            HwOp::Const(c) => HwOp::Const(c),
            HwOp::Add(a, b) => HwOp::Add(m(a), m(b)),
            HwOp::Sub(a, b) => HwOp::Sub(m(a), m(b)),
            HwOp::Mul(a, b) => HwOp::Mul(m(a), m(b)),
            HwOp::Neg(a) => HwOp::Neg(m(a)),
            HwOp::Recip(a) => HwOp::Recip(m(a)),
        };
        // A clamp's nodes (M's diagonal) are live wherever the factorisation is; an
        // original diagonal entry's pivot bound names the node itself.
        new[i] = HwId(nodes.len() as u32);
        let m = |x: HwId| new[x.0 as usize];
        clamps.push(g.clamps[i].map(|c| match c {
            Clamp::Schur(a, b) => Clamp::Schur(m(a), m(b)),
            Clamp::Pivot { floor, diagonal } => Clamp::Pivot { floor, diagonal: m(diagonal) },
            Clamp::Multiplier { diagonal, floor } => {
                Clamp::Multiplier { diagonal: m(diagonal), floor }
            }
            solve @ Clamp::Solve { .. } => solve,
        }));
        nodes.push(op);
        links.push(g.links[i]);
    }
    let outputs = outputs
        .into_iter()
        .map(|o| DatapathOutput { ids: o.ids.iter().map(|id| new[id.0 as usize]).collect(), ..o })
        .collect();
    // Every node a bound reads is live (a root of `live_nodes`).
    let remap = |x: &HwId| match new[x.0 as usize] {
        HwId(u32::MAX) => unreachable!("a bound reads a dead node"),
        y => y,
    };
    let factor = Factor {
        diagonal: g.factor.diagonal.iter().map(remap).collect(),
        floor: g.factor.floor,
        minv: g.factor.minv,
        rhs: g.factor.rhs.iter().map(|b| b.iter().map(|(k, x)| (*k, remap(x))).collect()).collect(),
        parents: g.factor.parents,
        entries: g.factor.entries.iter().map(|&(i, j, x)| (i, j, remap(&x))).collect(),
    };
    Datapath { kernel: "fd_grad", nv, dims, ports, nodes, links, clamps, factor, outputs }
}
