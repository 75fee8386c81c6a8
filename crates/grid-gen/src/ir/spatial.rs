//! Symbolic spatial algebra over graph nodes, [angular; linear] like the reference.
//! Transforms are kept as Featherstone's (E, r) pair, never as 6x6 matrices, so that a
//! product costs what its nonzero entries cost.

use super::graph::{Graph, Id};
use crate::model::{Inertia, Joint, Model};
use crate::model::{JointIndex, QIndex};

pub type V3 = [Id; 3];
pub type Sv = [Id; 6];

/// Model constants within this distance of 0 or ±1 are taken as exact: they are the
/// round-off of rpy angles like π/2 written in decimal (cos(1.570796326794897) = 6e-17).
/// The change is below 1e-15 relative, far under every tolerance, and turns rotations
/// by multiples of π/2 into sparse permutations.
pub const SNAP: f64 = 1e-15;

pub fn snap(x: f64) -> f64 {
    if x.abs() <= SNAP {
        0.0
    } else if (x.abs() - 1.0).abs() <= SNAP {
        x.signum()
    } else {
        x
    }
}

/// A model constant (snapped when folding).
pub fn k(g: &mut Graph, x: f64) -> Id {
    let x = if g.folding() { snap(x) } else { x };
    g.constant(x)
}

pub fn zero(g: &mut Graph) -> Sv {
    let z = g.constant(0.0);
    [z; 6]
}

/// A spatial vector's angular (first) half.
pub fn ang(v: &Sv) -> V3 {
    [v[0], v[1], v[2]]
}

/// A spatial vector's linear (second) half.
pub fn lin(v: &Sv) -> V3 {
    [v[3], v[4], v[5]]
}

/// `[a; b]`.
pub fn join(a: V3, b: V3) -> Sv {
    [a[0], a[1], a[2], b[0], b[1], b[2]]
}

pub fn cross(g: &mut Graph, a: &V3, b: &V3) -> V3 {
    let mut out = [a[0]; 3];
    for i in 0..3 {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        let p = g.mul(a[j], b[k]);
        let q = g.mul(a[k], b[j]);
        out[i] = g.sub(p, q);
    }
    out
}

pub fn add3(g: &mut Graph, a: &V3, b: &V3) -> V3 {
    std::array::from_fn(|i| g.add(a[i], b[i]))
}

pub fn sub3(g: &mut Graph, a: &V3, b: &V3) -> V3 {
    std::array::from_fn(|i| g.sub(a[i], b[i]))
}

pub fn add(g: &mut Graph, a: &Sv, b: &Sv) -> Sv {
    std::array::from_fn(|i| g.add(a[i], b[i]))
}

pub fn sub(g: &mut Graph, a: &Sv, b: &Sv) -> Sv {
    std::array::from_fn(|i| g.sub(a[i], b[i]))
}

pub fn scale(g: &mut Graph, a: &Sv, s: Id) -> Sv {
    std::array::from_fn(|i| g.mul(a[i], s))
}

pub fn dot(g: &mut Graph, a: &Sv, b: &Sv) -> Id {
    g.dot(a, b)
}

/// `iXλ` as (E, r): `X m = [E ω; E (v − r × ω)]`.
pub struct Xform {
    pub e: [[Id; 3]; 3],
    pub r: V3,
}

pub fn mat_vec(g: &mut Graph, e: &[[Id; 3]; 3], v: &V3) -> V3 {
    std::array::from_fn(|i| g.dot(&e[i], v))
}

pub fn mat_t_vec(g: &mut Graph, e: &[[Id; 3]; 3], v: &V3) -> V3 {
    std::array::from_fn(|i| {
        let col = [e[0][i], e[1][i], e[2][i]];
        g.dot(&col, v)
    })
}

impl Xform {
    /// `X m` for a motion vector.
    pub fn apply(&self, g: &mut Graph, m: &Sv) -> Sv {
        let w = ang(m);
        let rw = cross(g, &self.r, &w);
        let v = sub3(g, &lin(m), &rw);
        join(mat_vec(g, &self.e, &w), mat_vec(g, &self.e, &v))
    }

    /// `Xᵀ f` for a force vector: [Eᵀ n + r × Eᵀ f; Eᵀ f].
    pub fn apply_t(&self, g: &mut Graph, f: &Sv) -> Sv {
        let ef = mat_t_vec(g, &self.e, &lin(f));
        let en = mat_t_vec(g, &self.e, &ang(f));
        let rf = cross(g, &self.r, &ef);
        join(add3(g, &en, &rf), ef)
    }
}

/// `v × m` (motion cross product).
pub fn crm(g: &mut Graph, v: &Sv, m: &Sv) -> Sv {
    let (w, vl) = (ang(v), lin(v));
    let a = cross(g, &w, &ang(m));
    let b1 = cross(g, &w, &lin(m));
    let b2 = cross(g, &vl, &ang(m));
    join(a, add3(g, &b1, &b2))
}

/// `v ×* f` (force cross product).
pub fn crf(g: &mut Graph, v: &Sv, f: &Sv) -> Sv {
    let (w, vl) = (ang(v), lin(v));
    let a1 = cross(g, &w, &ang(f));
    let a2 = cross(g, &vl, &lin(f));
    let b = cross(g, &w, &lin(f));
    join(add3(g, &a1, &a2), b)
}

/// A matrix of rigid-body-inertia shape, [I_o, h×; −h×, m 1] (10 parameters): a body's
/// inertia as constants, or a composite inertia or its rate as graph nodes. The shape
/// is closed under sums and frame changes, which is why the gradient keeps composites
/// in it instead of as general 6x6 matrices (10 entries to move, not 36).
#[derive(Clone, Copy)]
pub struct SymInertia {
    i: [[Id; 3]; 3],
    h: V3,
    m: Id,
}

impl SymInertia {
    pub fn new(g: &mut Graph, inertia: &Inertia) -> Self {
        SymInertia {
            i: std::array::from_fn(|r| std::array::from_fn(|c| k(g, inertia.i_origin[r][c]))),
            h: std::array::from_fn(|r| k(g, inertia.h[r])),
            m: k(g, inertia.mass),
        }
    }

    /// `a + b`.
    pub fn add(&self, g: &mut Graph, b: &SymInertia) -> SymInertia {
        let mut i = self.i;
        for r in 0..3 {
            for c in r..3 {
                i[r][c] = g.add(self.i[r][c], b.i[r][c]);
                i[c][r] = i[r][c];
            }
        }
        SymInertia { i, h: add3(g, &self.h, &b.h), m: g.add(self.m, b.m) }
    }

    /// `Xᵀ I X` for X = iXλ = (E, r): the same matrix in the parent's frame. With h' = Eᵀh,
    /// `h_λ = m r + h'` and `I_λ = Eᵀ I_o E + m (r·r 1 − r rᵀ) − (h' rᵀ + r h'ᵀ) + 2 (r·h') 1`
    /// (the parallel-axis theorem with the first moment; Featherstone, RBDA §2.13). Linear
    /// in (m, h, I_o), so it holds for rates and composites as for bodies.
    pub fn to_parent(self, g: &mut Graph, x: &Xform) -> SymInertia {
        let e = &x.e;
        let hp = mat_t_vec(g, e, &self.h);
        // J E, then Eᵀ (J E) on the upper triangle.
        let je: [[Id; 3]; 3] = std::array::from_fn(|r| {
            std::array::from_fn(|c| g.dot(&self.i[r], &[e[0][c], e[1][c], e[2][c]]))
        });
        let rr = g.dot(&x.r, &x.r);
        let rh = g.dot(&x.r, &hp);
        let two = g.constant(2.0);
        let rh2 = g.mul(two, rh);
        let mut i = self.i;
        for a in 0..3 {
            for b in a..3 {
                let rot = g.dot(&[e[0][a], e[1][a], e[2][a]], &[je[0][b], je[1][b], je[2][b]]);
                let rab = g.mul(x.r[a], x.r[b]);
                let geo = if a == b { g.sub(rr, rab) } else { g.neg(rab) };
                let mg = g.mul(self.m, geo);
                let t1 = g.mul(hp[a], x.r[b]);
                let t2 = g.mul(x.r[a], hp[b]);
                let hr = g.add(t1, t2);
                let mut v = g.add(rot, mg);
                v = g.sub(v, hr);
                if a == b {
                    v = g.add(v, rh2);
                }
                i[a][b] = v;
                i[b][a] = v;
            }
        }
        let mr: V3 = std::array::from_fn(|k| g.mul(self.m, x.r[k]));
        SymInertia { i, h: add3(g, &mr, &hp), m: self.m }
    }

    /// `v ×* I − I v×`: the rate of change of this inertia carried with velocity v, again
    /// inertia-shaped, with mass rate 0, `ḣ = ω × h + m v_lin` and
    /// `İ_o = ω×I_o − I_o ω× − (v_lin× h× + h× v_lin×)`.
    pub fn rate(&self, g: &mut Graph, v: &Sv) -> SymInertia {
        let (w, vl) = (ang(v), lin(v));
        let wh = cross(g, &w, &self.h);
        let mv: V3 = std::array::from_fn(|r| g.mul(self.m, vl[r]));
        let h = add3(g, &wh, &mv);
        let wx = skew(g, &w);
        // A = ω× I_o; ω×I_o − I_o ω× = A + Aᵀ (I_o symmetric).
        let a: [[Id; 3]; 3] = std::array::from_fn(|r| {
            std::array::from_fn(|c| g.dot(&wx[r], &[self.i[0][c], self.i[1][c], self.i[2][c]]))
        });
        // v× h× + h× v× = h vᵀ + v hᵀ − 2 (v·h) 1.
        let vh = g.dot(&vl, &self.h);
        let two = g.constant(2.0);
        let vh2 = g.mul(two, vh);
        let mut i = self.i;
        for r in 0..3 {
            for c in r..3 {
                let t = g.add(a[r][c], a[c][r]);
                let p1 = g.mul(self.h[r], vl[c]);
                let p2 = g.mul(vl[r], self.h[c]);
                let p = g.add(p1, p2);
                let mut x = g.sub(t, p);
                if r == c {
                    x = g.add(x, vh2);
                }
                i[r][c] = x;
                i[c][r] = x;
            }
        }
        SymInertia { i, h, m: g.constant(0.0) }
    }

    /// `I v = [I_o ω + h × v; m v − h × ω]`.
    pub fn apply(&self, g: &mut Graph, v: &Sv) -> Sv {
        let (w, vl) = (ang(v), lin(v));
        let iw = mat_vec(g, &self.i, &w);
        let hv = cross(g, &self.h, &vl);
        let hw = cross(g, &self.h, &w);
        let mv: V3 = std::array::from_fn(|r| g.mul(self.m, vl[r]));
        join(add3(g, &iw, &hv), sub3(g, &mv, &hw))
    }

    /// `I + Δ`, for composite and articulated inertias: returned as a full symmetric 6x6.
    pub fn to_matrix(self, g: &mut Graph) -> [[Id; 6]; 6] {
        let z = g.constant(0.0);
        let mut out = [[z; 6]; 6];
        let hx = skew(g, &self.h);
        for r in 0..3 {
            for c in 0..3 {
                out[r][c] = self.i[r][c];
                out[r][c + 3] = hx[r][c];
                out[r + 3][c] = hx[c][r];
            }
            out[r + 3][r + 3] = self.m;
        }
        out
    }
}

fn skew(g: &mut Graph, v: &V3) -> [[Id; 3]; 3] {
    let z = g.constant(0.0);
    let n: V3 = std::array::from_fn(|i| g.neg(v[i]));
    [[z, n[2], v[1]], [v[2], z, n[0]], [n[1], v[0], z]]
}

/// A general 6x6 (composite or articulated inertia) times a vector.
pub fn mat6_vec(g: &mut Graph, m: &[[Id; 6]; 6], v: &Sv) -> Sv {
    std::array::from_fn(|i| g.dot(&m[i], v))
}

/// `Xᵀ A X` for a symmetric 6x6 A, by columns: X e_j, then A, then Xᵀ.
pub fn congruence(g: &mut Graph, x: &Xform, a: &[[Id; 6]; 6]) -> [[Id; 6]; 6] {
    let z = g.constant(0.0);
    let one = g.constant(1.0);
    let mut out = [[z; 6]; 6];
    for j in 0..6 {
        let mut e = [z; 6];
        e[j] = one;
        let xe = x.apply(g, &e);
        let axe = mat6_vec(g, a, &xe);
        let col = x.apply_t(g, &axe);
        for i in 0..6 {
            out[i][j] = col[i];
        }
    }
    // Exactly symmetric: take the upper triangle.
    for i in 0..6 {
        for j in 0..i {
            out[i][j] = out[j][i];
        }
    }
    out
}

/// The joint's motion subspace S as constants.
pub fn subspace(g: &mut Graph, joint: &Joint) -> Sv {
    let z = g.constant(0.0);
    let mut s = [z; 6];
    let off = if joint.joint_type.is_rotation() { 0 } else { 3 };
    for i in 0..3 {
        s[off + i] = k(g, joint.axis[i]);
    }
    s
}

/// `iXλ(q_i) = X_J(q_i) X_T` with E = E_J E_T built once per joint. Rotation entries are
/// `α cos q + β sin q + γ` with α = δ − a aᵀ, β = −[a]× (transposed), γ = a aᵀ, so that an
/// axis-aligned joint leaves exact zeros and ones (Rodrigues, R = c I + s [a]× + (1 − c) a aᵀ).
pub fn joint_xform(g: &mut Graph, model: &Model, i: usize) -> Xform {
    joint_xform_at(g, model, i, None)
}

/// [`joint_xform`] at the configuration `q` (nodes, one per entry of q) instead of the
/// kernel's input: the step's RK4 stages evaluate the dynamics at `q ⊕ c dt k`.
pub fn joint_xform_at(g: &mut Graph, model: &Model, i: usize, q_at: Option<&[Id]>) -> Xform {
    let joint = &model.joints[i];
    let tree_r = joint.tree.rot;
    // E_T = Rᵀ (rows of E_T are columns of R); r_T = position.
    let et: [[Id; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| k(g, tree_r[c][r])));
    let rt: V3 = std::array::from_fn(|r| k(g, joint.tree.pos[r]));
    let Some((QIndex(qi), multiplier, offset)) = model.joint_q(JointIndex(i)) else {
        return group_xform(g, model, i, et, rt, q_at);
    };
    let mut q = q_at.map_or_else(|| g.input(super::graph::Input::Q, qi), |q| q[qi]);
    // A coupled mimic joint: q_m = multiplier · q + offset.
    if multiplier != 1.0 {
        let m = k(g, multiplier);
        q = g.mul(m, q);
    }
    if offset != 0.0 {
        let o = k(g, offset);
        q = g.add(q, o);
    }
    let a = joint.axis;
    if joint.joint_type.is_rotation() {
        let (s, c) = (g.sin(q), g.cos(q));
        let ax = [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]];
        // E_J = R(a, q)ᵀ: entry (r, c) is R[c][r].
        let ej: [[Id; 3]; 3] = std::array::from_fn(|r| {
            std::array::from_fn(|cc| {
                let delta = if r == cc { 1.0 } else { 0.0 };
                let alpha = k(g, delta - a[cc] * a[r]);
                let beta = k(g, ax[cc][r]);
                let gamma = k(g, a[cc] * a[r]);
                let t1 = g.mul(alpha, c);
                let t2 = g.mul(beta, s);
                let t = g.add(t1, t2);
                g.add(t, gamma)
            })
        });
        let e = std::array::from_fn(|r| {
            std::array::from_fn(|cc| g.dot(&ej[r], &[et[0][cc], et[1][cc], et[2][cc]]))
        });
        Xform { e, r: rt }
    } else {
        // Prismatic: E = E_T, r = r_T + E_Tᵀ a q.
        let aq: V3 = std::array::from_fn(|r| {
            let ar = k(g, a[r]);
            g.mul(ar, q)
        });
        let shift = mat_t_vec(g, &et, &aq);
        let r = add3(g, &rt, &shift);
        Xform { e: et, r }
    }
}

/// The transform of a multi-dof joint's member (see [`crate::model`]): every member is at
/// its zero position, and the first carries the joint's pose, `X_pose X_T` =
/// plux(E_p E_T, r_T + E_Tᵀ p) with E_p = Rᵀ from q's quaternion (`[qx, qy, qz, qw]`,
/// scaled by 1/|q|² as in `spatial::quaternion_matrix`) and p the free-flyer's position
/// (q's entries 0..3; a spherical joint has none).
/// The rotation of quaternion `[x, y, z, w]` (axes of the rotated frame in the parent's,
/// row-major), scaled by s = 2/|q|² as `spatial::quaternion_matrix` (Eigen's
/// `toRotationMatrix`), so that a slightly non-unit quaternion rotates as its normalised self.
pub fn quaternion_rotation(g: &mut Graph, [x, y, z, w]: [Id; 4]) -> [[Id; 3]; 3] {
    let norm2 = g.dot(&[x, y, z, w], &[x, y, z, w]);
    let two = k(g, 2.0);
    let s = g.div(two, norm2);
    let one = k(g, 1.0);
    // s·(a·b ± c·d) and 1 − s·(a² + b²): the entries of R (Eigen's toRotationMatrix).
    let pair = |g: &mut Graph, a: Id, b: Id, c: Id, d: Id, plus: bool| {
        let ab = g.mul(a, b);
        let cd = g.mul(c, d);
        let t = if plus { g.add(ab, cd) } else { g.sub(ab, cd) };
        g.mul(s, t)
    };
    let diag = |g: &mut Graph, a: Id, b: Id| {
        let t = g.dot(&[a, b], &[a, b]);
        let t = g.mul(s, t);
        g.sub(one, t)
    };
    [
        [diag(g, y, z), pair(g, x, y, z, w, false), pair(g, x, z, y, w, true)],
        [pair(g, x, y, z, w, true), diag(g, x, z), pair(g, y, z, x, w, false)],
        [pair(g, x, z, y, w, false), pair(g, y, z, x, w, true), diag(g, x, y)],
    ]
}

fn group_xform(
    g: &mut Graph,
    model: &Model,
    i: usize,
    et: [[Id; 3]; 3],
    rt: V3,
    q_at: Option<&[Id]>,
) -> Xform {
    if model.group(i).is_none_or(|m| m.start != i) {
        return Xform { e: et, r: rt };
    }
    let input =
        |g: &mut Graph, k: usize| q_at.map_or_else(|| g.input(super::graph::Input::Q, k), |q| q[k]);
    let free = model.is_free_flyer(i);
    let at = if free { 3 } else { model.group_q(JointIndex(i)).0 };
    let p: Option<V3> = free.then(|| std::array::from_fn(|k| input(g, k)));
    let [x, y, z, w] = std::array::from_fn(|k| input(g, at + k));
    let r = quaternion_rotation(g, [x, y, z, w]);
    // E = E_p E_T with E_p = Rᵀ: entry (a, b) = Σ_c R[c][a] E_T[c][b].
    let e = std::array::from_fn(|a| {
        std::array::from_fn(|b| {
            g.dot(&[r[0][a], r[1][a], r[2][a]], &[et[0][b], et[1][b], et[2][b]])
        })
    });
    let r = match p {
        Some(p) => {
            let shift = mat_t_vec(g, &et, &p);
            add3(g, &rt, &shift)
        }
        None => rt,
    };
    Xform { e, r }
}
