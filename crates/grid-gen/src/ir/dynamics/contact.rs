//! Rigid-contact forward dynamics and its derivatives, recorded symbolically, as
//! Pinocchio's `constraintDynamics` and `computeConstraintDynamicsDerivatives` (contacts in
//! `LOCAL_WORLD_ALIGNED`, no Baumgarte correction). The KKT system is solved through the
//! tree and a small contact Schur complement, never as one dense system:
//!
//! - the free acceleration `a₀ = M⁻¹ (τ − c)` (ABA, or M's factorisation),
//! - `G = M⁻¹ Jᵀ`, one solve per contact row by the route `fd_grad` takes,
//! - `K = J G` (nλ x nλ, symmetric positive definite for independent contacts), LDLᵀ,
//! - `λ = −K⁻¹ (J a₀ + γ)`, with `J a₀ + γ` the contacts' acceleration at q̈ = a₀,
//! - `q̈ = a₀ + G λ`.
//!
//! Where M is factorised as `Lᵀ D L`, `contact_fd` forms K as `Yᵀ D⁻¹ Y` with
//! `Y = L⁻ᵀ Jᵀ` (each column's first pass, which reaches only its contact's joints and
//! their ancestors) and `G λ` as one last pass of `D⁻¹ Y λ`. `contact_fd_grad`, whose
//! columns read G, solves it in full and keeps `K = J G` and `q̈ = a₀ + G λ`.
//!
//! Differentiating `M q̈ + c − τ − Jᵀλ = 0` and `acc(q, q̇, q̈) = 0` (Carpentier & Budhiraja,
//! "Analytical derivatives of rigid body dynamics with constraints", 2021): with
//! `F_u = ∂q̈/∂u` at fixed λ (held in world axes, `fd_grad`'s with the contacts' forces as
//! inputs) and `A_u = ∂acc/∂u` at fixed q̈ (forward-mode over the acceleration's graph),
//! `∂λ/∂u = −K⁻¹ (J F_u + A_u)` and `∂q̈/∂u = F_u + G ∂λ/∂u`; for τ, `F_τ = M⁻¹`,
//! `A_τ = 0`, so `J F_τ = Gᵀ`, and `∂q̈/∂τ = M⁻¹ − G K⁻¹ Gᵀ` is symmetric (half of it is
//! formed). `F_u`'s free-flyer columns come without a solve (`fd_grad.rs`).

use super::super::graph::{Graph, Id, Input, Stage};
use super::super::kernel::KernelKind;
use super::super::kernel::Solve;
use super::super::module::{ColumnBlock, ColumnProgram, ColumnStep, ColumnStore, Operand};
use super::super::spatial::{self as sp, k, V3};
use super::fd_grad::run_steps;
use super::lie::quaternion_log;
use super::step::qmul;
use super::{Dynamics, LambdaSource, Mat};
use crate::model::ContactKind;

/// `K = L D Lᵀ`, dense: L strictly below the diagonal, and 1/D.
struct Ldl {
    l: Mat,
    dinv: Vec<Id>,
}

impl Ldl {
    /// Factorises the symmetric `k` (only its lower triangle is read).
    fn new(g: &mut Graph, k: &Mat) -> Self {
        let n = k.len();
        let zero = g.constant(0.0);
        let one = g.constant(1.0);
        // w[i][j] = L_ij D_j, kept so that each update is one multiplication.
        let (mut l, mut w, mut dinv) =
            (vec![vec![zero; n]; n], vec![vec![zero; n]; n], vec![zero; n]);
        for j in 0..n {
            let mut d = k[j][j];
            for p in 0..j {
                let t = g.mul(l[j][p], w[j][p]);
                d = g.sub(d, t);
            }
            dinv[j] = g.div(one, d);
            for i in j + 1..n {
                let mut x = k[i][j];
                for p in 0..j {
                    let t = g.mul(l[i][p], w[j][p]);
                    x = g.sub(x, t);
                }
                w[i][j] = x;
                l[i][j] = g.mul(x, dinv[j]);
            }
        }
        Ldl { l, dinv }
    }

    /// `K⁻¹ b`.
    fn solve(&self, g: &mut Graph, mut b: Vec<Id>) -> Vec<Id> {
        let n = b.len();
        for i in 0..n {
            for p in 0..i {
                let t = g.mul(self.l[i][p], b[p]);
                b[i] = g.sub(b[i], t);
            }
        }
        for i in 0..n {
            b[i] = g.mul(b[i], self.dinv[i]);
        }
        for i in (0..n).rev() {
            for p in i + 1..n {
                let t = g.mul(self.l[p][i], b[p]);
                b[i] = g.sub(b[i], t);
            }
        }
        b
    }
}

/// What [`Dynamics::contact_fd`] leaves for the gradient.
pub(crate) struct ContactSolution {
    pub qdd: Vec<Id>,
    pub lambda: Vec<Id>,
    /// `−Jᵀ`, one column (nv entries) per entry of λ.
    neg_jt: Vec<Vec<Id>>,
    /// `G = M⁻¹ Jᵀ`, one column per entry of λ; empty where [`Dynamics::contact_fd`]
    /// factorised M and needed only each column's first passes (the gradient solves it).
    g: Vec<Vec<Id>>,
    k: Ldl,
}

impl Dynamics<'_> {
    /// `−M⁻¹ b` per coordinate for each b, by the route [`Self::fd_grad`] takes for its
    /// right-hand sides (so that the two share their nodes).
    fn neg_minv_times(&mut self, rhs: &[Vec<Id>]) -> Vec<Vec<Id>> {
        if matches!(self.solve, Solve::Ltdl | Solve::Crba) && !self.coupled() {
            let m = self.mass_matrix();
            let f = self.ltdl(m);
            return rhs.iter().map(|b| f.solve(&mut self.g, self.model, b.clone())).collect();
        }
        let mi = self.minv_coordinates();
        self.g.at(None, Stage::Combine, 0);
        rhs.iter()
            .map(|b| {
                (0..mi.len())
                    .map(|i| {
                        let d = self.g.dot(&mi[i], b);
                        self.g.neg(d)
                    })
                    .collect()
            })
            .collect()
    }

    /// The contacts' constrained accelerations at per-joint q̇, q̈, stacked as λ: a point's
    /// classical acceleration `R_b (a + ω × v)` at its frame's origin, a wrench's spatial
    /// acceleration `[R_b a; R_b α]` there (world axes, as Pinocchio's `LOCAL_WORLD_ALIGNED`).
    fn contact_accelerations(&mut self, qd: &[Id], qdd: &[Id]) -> Vec<Id> {
        let (v, a) = self.motion(qd, qdd);
        let poses = self.world_poses();
        let mut out = Vec::new();
        let baumgarte = self.model.specialisation.baumgarte;
        let model = self.model;
        for (ci, c) in model.specialisation.contacts.iter().enumerate() {
            let frame = &model.frames[c.frame];
            let b = frame.body.expect("contacts are on moving bodies");
            self.at(b, Stage::Forward);
            let g = &mut self.g;
            let p: V3 = std::array::from_fn(|i| k(g, frame.placement.pos[i]));
            let (r, origin) = poses[b];
            let (al, alpha) = Self::at_point(g, &a[b], &p);
            match c.kind {
                ContactKind::Point => {
                    let (vl, w) = Self::at_point(g, &v[b], &p);
                    let wv = sp::cross(g, &w, &vl);
                    let acc = sp::add3(g, &al, &wv);
                    let acc = sp::mat_vec(g, &r, &acc);
                    if !baumgarte {
                        out.extend(acc);
                        continue;
                    }
                    // Pinocchio's Baumgarte corrector for CONTACT_3D in LOCAL_WORLD_ALIGNED
                    // (RigidConstraintModel with joint2 the universe at the reference): the
                    // constraint is `a + Kd v + Kp (p − p_ref) = 0`, with a, v the point's
                    // classical acceleration and velocity and p its position, all in the
                    // world. Checked against pin.constraintDynamics 4.1 with the corrector set.
                    let (kp, kd) =
                        (g.input(Input::Gains, 2 * ci), g.input(Input::Gains, 2 * ci + 1));
                    let vw = sp::mat_vec(g, &r, &vl);
                    let rp = sp::mat_vec(g, &r, &p);
                    let at = sp::add3(g, &origin, &rp);
                    let base = model.specialisation.contact_ref_at(ci);
                    out.extend((0..3).map(|i| {
                        let reference = g.input(Input::ContactRef, base + i);
                        let e = g.sub(at[i], reference);
                        let pe = g.mul(kp, e);
                        let dv = g.mul(kd, vw[i]);
                        let t = g.add(acc[i], dv);
                        g.add(t, pe)
                    }));
                }
                ContactKind::Wrench => {
                    let lin = sp::mat_vec(g, &r, &al);
                    let ang = sp::mat_vec(g, &r, &alpha);
                    if !baumgarte {
                        out.extend(lin);
                        out.extend(ang);
                        continue;
                    }
                    // Pinocchio's corrector for CONTACT_6D in LOCAL_WORLD_ALIGNED
                    // (constrained-dynamics.hxx, 4.1): the desired acceleration is
                    // `R_c (Kp log6(c1Mc2) − Kd v_c)`, v_c the frame's velocity in its own
                    // axes and c1Mc2 = oMc⁻¹ oMref. In world axes `R_c log6(c1Mc2)` is
                    // `[V⁻¹(ω) (p_ref − p); ω]` with ω = log3(R_ref R_cᵀ) (a logarithm
                    // commutes with the rotation R_c), so the constraint is
                    // `[a; α] + Kd [v; ω_b] − Kp [V⁻¹(ω) (p_ref − p); ω] = 0`.
                    let (kp, kd) =
                        (g.input(Input::Gains, 2 * ci), g.input(Input::Gains, 2 * ci + 1));
                    let (vl, w) = Self::at_point(g, &v[b], &p);
                    let vel: Vec<Id> =
                        sp::mat_vec(g, &r, &vl).into_iter().chain(sp::mat_vec(g, &r, &w)).collect();
                    let rp = sp::mat_vec(g, &r, &p);
                    let at = sp::add3(g, &origin, &rp);
                    let base = model.specialisation.contact_ref_at(ci);
                    let reference: [Id; 7] =
                        std::array::from_fn(|i| self.g.input(Input::ContactRef, base + i));
                    let qc = self.frame_quaternion(frame);
                    let g = &mut self.g;
                    let conj = [g.neg(qc[0]), g.neg(qc[1]), g.neg(qc[2]), qc[3]];
                    let rel =
                        qmul(g, [reference[3], reference[4], reference[5], reference[6]], conj);
                    let log = quaternion_log(g, rel);
                    self.log_signs.push(log.sign);
                    // V⁻¹(ω) d = α d − ½ ω × d + β (ω · d) ω (Pinocchio's `log6`).
                    let d = sp::sub3(g, &[reference[0], reference[1], reference[2]], &at);
                    let w = log.omega;
                    let wd = sp::cross(g, &w, &d);
                    let dot = g.dot(&w, &d);
                    let bd = g.mul(log.beta, dot);
                    let half = k(g, 0.5);
                    let error: Vec<Id> = (0..3)
                        .map(|i| {
                            let x = g.mul(log.alpha, d[i]);
                            let y = g.mul(half, wd[i]);
                            let z = g.mul(bd, w[i]);
                            let s = g.sub(x, y);
                            g.add(s, z)
                        })
                        .chain(w)
                        .collect();
                    out.extend(lin.into_iter().chain(ang).enumerate().map(|(i, a)| {
                        let dv = g.mul(kd, vel[i]);
                        let pe = g.mul(kp, error[i]);
                        let t = g.add(a, dv);
                        g.sub(t, pe)
                    }));
                }
            }
        }
        out
    }

    /// The free acceleration `a₀ = M⁻¹ (τ − c(q, q̇, 0))` (fext included, no contact force):
    /// by M's factorisation when the solve is [`Solve::Crba`], by ABA otherwise.
    fn free_acceleration(&mut self, qd: &[Id], tau: &[Id]) -> Vec<Id> {
        if self.solve == Solve::Crba && !self.coupled() {
            let zero = self.g.constant(0.0);
            let bias = self.rnea(qd, &vec![zero; qd.len()]).c;
            let m = self.mass_matrix();
            let f = self.ltdl(m);
            self.g.at(None, Stage::Combine, 0);
            let b: Vec<Id> = (0..qd.len()).map(|i| self.g.sub(bias[i], tau[i])).collect();
            return f.solve(&mut self.g, self.model, b);
        }
        self.fd(qd, tau)
    }

    /// Rigid-contact forward dynamics: q̈ and λ (see the module's documentation). The
    /// kernel's forces must be loaded with [`LambdaSource::Unknown`].
    pub fn contact_fd(&mut self, qd: &[Id], tau: &[Id]) -> ContactSolution {
        self.contact_fd_solving_g(qd, tau, false)
    }

    /// [`Self::contact_fd`], with G solved in full where `with_g` (the gradient's columns
    /// read it): then K is `J G` and q̈ `a₀ + G λ`, as before 2026-11-30. Held to the
    /// reference at 1e-12 on lavapipe's f64 (`grid-gen-wgpu`'s stabilised contacts), the
    /// gradient formed from `Yᵀ D⁻¹ Y`'s K came to 1.0e-12 to 1.4e-12 on floating HyQ, so
    /// the gradient keeps its K.
    fn contact_fd_solving_g(&mut self, qd: &[Id], tau: &[Id], with_g: bool) -> ContactSolution {
        let model = self.model;
        let a0 = self.free_acceleration(qd, tau);
        let neg_jt = self.lambda_columns();
        // With M factorised as Lᵀ D L, K = J M⁻¹ Jᵀ = (L⁻ᵀ Jᵀ)ᵀ D⁻¹ (L⁻ᵀ Jᵀ) takes each
        // column's first passes only, which reach just its contact's joints and their
        // ancestors; G's last passes, which fill every row on a floating base, are left to
        // the gradient, and q̈ takes one.
        let factor = (!with_g
            && matches!(self.solve, Solve::Ltdl | Solve::Crba)
            && !self.coupled())
        .then(|| {
            let m = self.mass_matrix();
            self.ltdl(m)
        });
        let (halves, g_cols) = match &factor {
            Some(f) => {
                let halves: Vec<(Vec<Id>, Vec<Id>)> =
                    neg_jt.iter().map(|b| f.first_passes(&mut self.g, model, b.clone())).collect();
                (halves, Vec::new())
            }
            None => (Vec::new(), self.neg_minv_times(&neg_jt)),
        };
        let (xqd, xa0) = (self.expand(qd), self.expand(&a0));
        let bias = self.contact_accelerations(&xqd, &xa0);
        self.g.at(None, Stage::Combine, 0);
        let nl = neg_jt.len();
        let g = &mut self.g;
        let zero = g.constant(0.0);
        // K = J G = −(−Jᵀ)ᵀ G, its lower triangle; by the halves, −yᵀ z of −Jᵀ's columns.
        let mut kmat = vec![vec![zero; nl]; nl];
        for r in 0..nl {
            for s in 0..=r {
                let d = match factor {
                    Some(_) => g.dot(&halves[r].0, &halves[s].1),
                    None => g.dot(&neg_jt[r], &g_cols[s]),
                };
                kmat[r][s] = g.neg(d);
                kmat[s][r] = kmat[r][s];
            }
        }
        let mask = mask_rows(g, &self.model.specialisation);
        if let Some(m) = &mask {
            mask_kkt(g, &mut kmat, m);
        }
        let mut k = Ldl::new(g, &kmat);
        if let Some(m) = &mask {
            // An inactive row's 1/D becomes 0: every solve with K leaves it 0.
            for (d, &m) in k.dinv.iter_mut().zip(m) {
                *d = g.mul(*d, m);
            }
        }
        let x = k.solve(g, bias);
        let lambda: Vec<Id> = x.into_iter().map(|x| g.neg(x)).collect();
        let n = a0.len();
        let qdd = match &factor {
            // G λ = Σ λ_s G_s, and G_s is the last pass of z_s: the passes are linear, so
            // one last pass of Σ λ_s z_s.
            Some(f) => {
                let z: Vec<Id> = (0..n)
                    .map(|i| {
                        let row: Vec<Id> = halves.iter().map(|h| h.1[i]).collect();
                        g.dot(&row, &lambda)
                    })
                    .collect();
                let x = f.last_pass(g, model, z);
                (0..n).map(|i| g.add(a0[i], x[i])).collect()
            }
            None => (0..n)
                .map(|i| {
                    let col: Vec<Id> = g_cols.iter().map(|c| c[i]).collect();
                    let t = g.dot(&col, &lambda);
                    g.add(a0[i], t)
                })
                .collect(),
        };
        ContactSolution { qdd, lambda, neg_jt, g: g_cols, k }
    }

    /// [`Self::contact_fd`] and its derivatives: `(q̈, λ, ∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ, ∂λ/∂q,
    /// ∂λ/∂q̇, ∂λ/∂τ)`, each as rows (one row for the vectors); the τ derivatives have one
    /// column per coordinate of `tau_cols` (the step kernels need only the actuated ones).
    pub fn contact_fd_grad(&mut self, qd: &[Id], tau: &[Id], tau_cols: &[usize]) -> Vec<Mat> {
        let mut sol = self.contact_fd_solving_g(qd, tau, true);
        if self.called && !self.own_qdd {
            // A rest: q̈ and λ from the call to `contact_fd` (the free acceleration, the
            // contacts' bias and the last solves drop out when the graph is frozen); J, G and
            // K's factors stay, for the columns.
            sol.qdd = self.called_inputs(Input::called(KernelKind::ContactFd, "qdd"));
            sol.lambda = self.called_inputs(Input::called(KernelKind::ContactFd, "lambda"));
        }
        // `fd_grad` below differentiates at this q̈ instead of solving ABA under λ for it
        // again (the same value to round-off; the kernel's `rnea_grad` call takes it too).
        self.given_qdd = Some(sol.qdd.clone());
        let (nv, nl) = (qd.len(), sol.lambda.len());
        // ∂q̈/∂u at fixed λ: fd_grad with the solved forces as the contacts' forces; its
        // q̈ is sol.qdd by ABA (or the factorisation) under them, so its RNEA gradient is
        // taken at the same point.
        self.load_forces(LambdaSource::Nodes(sol.lambda.clone()));
        self.fd_solves = None;
        let (_, fq, fqd, minv, _) = self.fd_grad(qd, tau, tau_cols, &[]);
        // The dense-product and solve annotations describe fd_grad's outputs, not these;
        // its solves, where it factorised M, go into this kernel's program.
        self.product = None;
        self.program = None;
        let solves = self.fd_solves.take();
        // ∂acc/∂u at fixed q̈, by forward-mode over the acceleration's graph with the q̈
        // nodes held.
        let (xqd, xqdd) = (self.expand(qd), self.expand(&sol.qdd));
        let acc = self.contact_accelerations(&xqd, &xqdd);
        let zero = self.g.constant(0.0);
        // The logarithms' signs (a stabilised wrench's) are held too, as `ddifference` holds
        // them: their tangent is 0 wherever they are differentiable.
        let held: Vec<(Id, Id)> = xqdd.iter().chain(&self.log_signs).map(|&x| (x, zero)).collect();
        let (mut aq, mut aqd) = (Vec::with_capacity(nv), Vec::with_capacity(nv));
        for c in 0..nv {
            if self.exhausted() {
                break;
            }
            let along_q = self.q_seeds(c);
            let (seeds, given) = self.stage_tangents(along_q, qd, &held);
            aq.push(self.g.tangent_at(&acc, &seeds, &given));
            let one = self.g.constant(1.0);
            let (seeds, given) = self.stage_tangents(vec![(Input::Qd, c, one)], qd, &held);
            aqd.push(self.g.tangent_at(&acc, &seeds, &given));
        }
        self.g.at(None, Stage::Combine, 0);
        if self.exhausted() {
            let (z, zt) = (vec![vec![zero; nv]; nv], vec![vec![zero; tau_cols.len()]; nv]);
            let (zl, zlt) = (vec![vec![zero; nv]; nl], vec![vec![zero; tau_cols.len()]; nl]);
            return vec![vec![sol.qdd], vec![sol.lambda], z.clone(), z, zt, zl.clone(), zl, zlt];
        }
        let g = &mut self.g;
        // Per column c of u: dλ = −K⁻¹ (J F e_c + A e_c), dq̈ = F e_c + G dλ; for τ,
        // J F e_c = J M⁻¹ e_c is row c of G.
        let (mut outs_q, mut outs_l): (Vec<Mat>, Vec<Mat>) = (Vec::new(), Vec::new());
        for which in 0..3 {
            let columns = if which == 2 { tau_cols.len() } else { nv };
            let (mut dq_cols, mut dl_cols): (Vec<Vec<Id>>, Vec<Vec<Id>>) =
                (Vec::with_capacity(columns), Vec::with_capacity(columns));
            for c in 0..columns {
                let f: Vec<Id> = (0..nv).map(|i| [&fq, &fqd, &minv][which][i][c]).collect();
                let rhs: Vec<Id> = (0..nl)
                    .map(|r| match which {
                        2 => sol.g[r][tau_cols[c]],
                        _ => {
                            let d = g.dot(&sol.neg_jt[r], &f);
                            let a = if which == 0 { aq[c][r] } else { aqd[c][r] };
                            g.sub(a, d)
                        }
                    })
                    .collect();
                let x = sol.k.solve(g, rhs);
                let dl: Vec<Id> = x.into_iter().map(|x| g.neg(x)).collect();
                let dq: Vec<Id> = (0..nv)
                    .map(|i| {
                        // ∂q̈/∂τ = M⁻¹ − G K⁻¹ Gᵀ is symmetric: an entry whose mirror
                        // is in a column already formed is that entry (Carpentier &
                        // Budhiraja 2021, the KKT inverse's upper-left block).
                        if let Some(at) = mirror(which, tau_cols, i, c) {
                            return dq_cols[at][tau_cols[c]];
                        }
                        let row: Vec<Id> = sol.g.iter().map(|col| col[i]).collect();
                        let t = g.dot(&row, &dl);
                        g.add(f[i], t)
                    })
                    .collect();
                dq_cols.push(dq);
                dl_cols.push(dl);
            }
            outs_q.push(super::transpose(dq_cols, nv));
            outs_l.push(super::transpose(dl_cols, nl));
        }
        // Each contact row's passes before the last on −Jᵀ's column, as the program's solves
        // run them: y = L⁻ᵀ (−Jᵀ) and z = −D⁻¹ y (their nodes are G's solves' own, and
        // reach only the contact's joints and their ancestors).
        let halves: Option<Vec<(Vec<Id>, Vec<Id>)>> = solves.as_ref().map(|solves| {
            let (head, _) = solves.split();
            let (diagonal, first): (Vec<ColumnStep>, Vec<ColumnStep>) =
                head.iter().partition(|s| matches!(s, ColumnStep::Mul { .. }));
            sol.neg_jt
                .iter()
                .map(|b| {
                    let y = run_steps(g, &first, b.clone());
                    let z = run_steps(g, &diagonal, y.clone());
                    (y, z)
                })
                .collect()
        });
        let mut blocks = Vec::new();
        for (which, f) in [&fq, &fqd, &minv].into_iter().enumerate() {
            let a = [Some(&aq), Some(&aqd), None][which];
            let columns = if which == 2 { tau_cols.len() } else { nv };
            let Some(solves) = &solves else {
                let x = |i: usize, c: usize| Operand::Node(f_entry(f, which, tau_cols, i, c));
                let all: Vec<usize> = (0..columns).collect();
                let at = Columns { tau: tau_cols, cols: &all, width: columns, which };
                blocks.push(combination_block(&sol, x, None, a, at));
                continue;
            };
            // F e_c by the factorisation's solves in the program: ∂c/∂u's column, or −e
            // for τ (M⁻¹ e = −M⁻¹ (−e)); the free-flyer's known columns as they are.
            let (solved, known): (Vec<usize>, Vec<usize>) =
                (0..columns).partition(|&c| which == 2 || solves.known[which][c].is_none());
            let rhs = |i: usize, c: usize| match which {
                2 => Operand::Const(if i == tau_cols[c] { -1.0 } else { 0.0 }),
                _ => Operand::Node(solves.dc[which][i][c]),
            };
            let given = |i: usize, c: usize| Operand::Node(f[i][c]);
            if !solved.is_empty() {
                let at = Columns { tau: tau_cols, cols: &solved, width: columns, which };
                let (head, tail) = solves.split();
                let halves = halves.as_deref().expect("formed where the solves are");
                let passes = Passes { head, tail, halves };
                blocks.push(combination_block(&sol, rhs, Some(passes), a, at));
            }
            if !known.is_empty() {
                let at = Columns { tau: tau_cols, cols: &known, width: columns, which };
                blocks.push(combination_block(&sol, given, None, a, at));
            }
        }
        self.program = Some(ColumnProgram { rows: nv + nl, blocks, replaces: None });
        let mut out = vec![vec![sol.qdd], vec![sol.lambda]];
        out.extend(outs_q);
        out.extend(outs_l);
        out
    }
}

/// `contact_fd_grad`'s derivatives of q̈ by q, q̇ and τ: the outputs its program's blocks
/// store into, in the order of `which` (and [`step_program`] reads back).
///
/// [`step_program`]: super::step
pub(super) const DQDD_BY: [&str; 3] = ["dqdd_dq", "dqdd_dqd", "dqdd_dtau"];

/// The contact mask per row of λ (each contact's `active` input repeated over its 3 or 6
/// rows), when the model masks its contacts.
fn mask_rows(g: &mut Graph, spec: &crate::model::Specialisation) -> Option<Vec<Id>> {
    if !spec.contact_mask {
        return None;
    }
    let mut rows = Vec::new();
    for (c, contact) in spec.contacts.iter().enumerate() {
        let m = g.input(Input::Active, c);
        rows.extend(std::iter::repeat_n(m, contact.kind.dim()));
    }
    Some(rows)
}

/// Masks the contacts' Schur complement in place: `K_rs ← m_r m_s K_rs + δ_rs (1 − m_r)`.
/// With each m 0 or 1, an inactive contact's rows and columns become the identity's, so K
/// stays positive definite and the active contacts' block is theirs alone; with 1/D of the
/// inactive rows then zeroed (in [`Dynamics::contact_fd`]), every solve `K⁻¹ b` gives 0 on
/// them and the active contacts' solution on the rest, so λ and every derivative of λ are 0
/// for an inactive contact and q̈ is that of the active contacts alone, branch-free.
fn mask_kkt(g: &mut Graph, k: &mut Mat, m: &[Id]) {
    let one = g.constant(1.0);
    let n = m.len();
    for r in 0..n {
        for s in 0..=r {
            let both = g.mul(m[r], m[s]);
            let mut x = g.mul(both, k[r][s]);
            if r == s {
                let off = g.sub(one, m[r]);
                x = g.add(x, off);
            }
            k[r][s] = x;
            k[s][r] = x;
        }
    }
}

/// For τ (`which` 2), the earlier column of `tau_cols` whose coordinate is row i: entry
/// (i, c) of the symmetric ∂q̈/∂τ is that column's entry in row `tau_cols[c]`.
fn mirror(which: usize, tau_cols: &[usize], i: usize, c: usize) -> Option<usize> {
    (which == 2).then(|| super::mirrored_column(tau_cols, i, c)).flatten()
}

/// For τ (`which` 2), column c of M⁻¹ read as the graph keeps it: where the graph took an
/// entry of ∂q̈/∂τ from its mirror, M⁻¹'s entry from the mirror too (M⁻¹ is symmetric).
fn f_entry(f: &Mat, which: usize, tau_cols: &[usize], i: usize, c: usize) -> Id {
    match mirror(which, tau_cols, i, c) {
        Some(at) => f[tau_cols[c]][at],
        None => f[i][c],
    }
}

/// Which columns a block of the combination runs: `cols` of u = q, q̇, τ (`which` 0, 1,
/// 2), which has `width` columns (τ's the coordinates `tau`).
struct Columns<'a> {
    tau: &'a [usize],
    cols: &'a [usize],
    width: usize,
    which: usize,
}

/// The factorisation's passes for a block that solves its F e_c: `head` (`Lᵀ y = b`, then
/// `z = −D⁻¹ y`) and `tail` (`L x = z`, root first), and each contact row's `(y, z)` on
/// −Jᵀ's column (`halves`).
#[derive(Clone, Copy)]
struct Passes<'a> {
    head: &'a [ColumnStep],
    tail: &'a [ColumnStep],
    halves: &'a [(Vec<Id>, Vec<Id>)],
}

/// The combination above on the columns `at`, as a per-column program over rows
/// `[F e_c (nv); x (nλ)]`, stored as ∂q̈/∂u (outputs 2 + which) and ∂λ/∂u = −x (outputs
/// 5 + which), the rows starting from `x_init` (row, column of u) and, below them,
/// `A e_c` (for τ, G's row `tau[c]`, which is `J F e_c`).
///
/// Where the block solves F e_c (`passes`), it never forms it. With `−M⁻¹ b = L⁻¹ (−D⁻¹)
/// L⁻ᵀ b` and the halves `(y_r, z_r)` of −Jᵀ's columns: the rows run `head` to
/// `z = −D⁻¹ L⁻ᵀ b`; `x = A e_c + J F e_c = A e_c − Σ_i y_r,i z_i` (J L⁻¹ = (L⁻ᵀ Jᵀ)ᵀ,
/// and y_r is sparse, as Jᵀ is); `x ← K⁻¹ x`; then, the last pass being linear,
/// `F e_c − G x = L⁻¹ (z − Σ_r z_r x_r)`: per row, its terms of x, then the last pass's.
/// On a floating humanoid that is 1,086 terms per column where forming F e_c and
/// subtracting the dense `G x` took 1,338.
/// Otherwise (F given, `x_init` is F itself): `x = A e_c + (−Jᵀ)ᵀ F e_c`, `x ← K⁻¹ x`,
/// `F e_c −= G x`.
/// The graph's products, but each row's terms subtracted one by one where the graph sums
/// a dot product first (so the two round differently), which the Rust backend runs with
/// the columns innermost.
fn combination_block(
    sol: &ContactSolution,
    x_init: impl Fn(usize, usize) -> Operand,
    passes: Option<Passes>,
    a: Option<&Vec<Vec<Id>>>,
    at: Columns,
) -> ColumnBlock {
    let (nv, nl) = (sol.qdd.len(), sol.lambda.len());
    let Columns { tau: tau_cols, cols, width, which } = at;
    let node = Operand::Node;
    let mut init: Vec<Vec<Operand>> =
        (0..nv).map(|i| cols.iter().map(|&c| x_init(i, c)).collect()).collect();
    for r in 0..nl {
        init.push(
            cols.iter()
                .map(|&c| match a {
                    Some(a) => node(a[c][r]),
                    None => node(sol.g[r][tau_cols[c]]),
                })
                .collect(),
        );
    }
    let mut steps = passes.map_or_else(Vec::new, |p| p.head.to_vec());
    if a.is_some() {
        // x_r = a_r − (−Jᵀ)_r · F, or a_r − y_r · z.
        for r in 0..nl {
            for i in 0..nv {
                let coef = match passes {
                    Some(p) => p.halves[r].0[i],
                    None => sol.neg_jt[r][i],
                };
                steps.push(ColumnStep::Sub { dst: nv + r, coef: node(coef), src: i });
            }
        }
    }
    // K⁻¹ as `Ldl::solve`.
    for i in 0..nl {
        for p in 0..i {
            steps.push(ColumnStep::Sub { dst: nv + i, coef: node(sol.k.l[i][p]), src: nv + p });
        }
    }
    for i in 0..nl {
        steps.push(ColumnStep::Mul { dst: nv + i, coef: node(sol.k.dinv[i]) });
    }
    for i in (0..nl).rev() {
        for p in i + 1..nl {
            steps.push(ColumnStep::Sub { dst: nv + i, coef: node(sol.k.l[p][i]), src: nv + p });
        }
    }
    match passes {
        // Row by row, root first: z_i − Σ_r z_r,i x_r, then the last pass's terms of row i
        // (its ancestors', final by then).
        Some(p) => {
            let mut tail = p.tail.iter().peekable();
            for i in 0..nv {
                for (r, (_, z)) in p.halves.iter().enumerate() {
                    steps.push(ColumnStep::Sub { dst: i, coef: node(z[i]), src: nv + r });
                }
                while let Some(&&step) = tail.peek().filter(|s| s.dst() == i) {
                    steps.push(step);
                    tail.next();
                }
            }
            debug_assert!(tail.next().is_none(), "the last pass runs root first, row by row");
        }
        // dq = F + G dλ = F − G x.
        None => {
            for i in 0..nv {
                for r in 0..nl {
                    steps.push(ColumnStep::Sub { dst: i, coef: node(sol.g[r][i]), src: nv + r });
                }
            }
        }
    }
    let mut stores: Vec<ColumnStore> = (0..nv)
        .map(|i| ColumnStore {
            row: i,
            output: DQDD_BY[which],
            flat: cols.iter().map(|&c| i * width + c).collect(),
            negate: false,
        })
        .collect();
    stores.extend((0..nl).map(|r| ColumnStore {
        row: nv + r,
        output: ["dlambda_dq", "dlambda_dqd", "dlambda_dtau"][which],
        flat: cols.iter().map(|&c| r * width + c).collect(),
        negate: true,
    }));
    ColumnBlock { init, steps, stores }
}
