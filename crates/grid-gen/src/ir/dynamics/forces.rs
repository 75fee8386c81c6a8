//! External forces and contact forces, recorded symbolically, as
//! `reference::forces` computes them: each becomes one spatial force per body in the
//! body's frame, which RNEA subtracts and ABA adds to its bias forces. A contact's force λ
//! is fixed in world axes, so the gradient's q-columns gain `J_bᵀ (m ×* f)` (see
//! [`Dynamics::add_contact_q_terms`]); the derivatives with respect to the forces
//! themselves are `−Jᵀ` columns, walked up the tree as RNEA's backward pass walks a force.

use super::super::graph::{Id, Input};
use super::super::spatial::{self as sp, k, Sv, V3};
use super::{Dynamics, Mat};
use crate::model::ContactKind;

/// Where the contact forces λ come from.
#[derive(Clone, Debug)]
pub(crate) enum LambdaSource {
    /// The kernel's `lambda` input.
    Inputs,
    /// Not known yet (the contact kernels solve for them): the contacts' geometry is
    /// recorded, their forces are not applied.
    Unknown,
    /// These nodes, 3 or 6 per contact.
    Nodes(Vec<Id>),
}

/// The forces a kernel takes, once read from its inputs.
#[derive(Clone, Debug, Default)]
pub(crate) struct Forces {
    /// Per model joint, the total force on its body in its frame, `[angular; linear]`.
    body: Vec<Option<Sv>>,
    /// Per contact: its body, the world rotation of that body, the frame's origin in the
    /// body, and the contact's force on the body in the body's frame.
    contacts: Vec<ContactForce>,
}

#[derive(Clone, Debug)]
struct ContactForce {
    body: usize,
    kind: ContactKind,
    rotation: [[Id; 3]; 3],
    point: V3,
    force: Sv,
    /// `R_b aᵤ` per ancestor u of the body that turns: u's axis in world coordinates.
    axes: Vec<(usize, V3)>,
}

impl Forces {
    /// The force on body i, if some force acts on it.
    pub fn on(&self, i: usize) -> Option<Sv> {
        self.body.get(i).copied().flatten()
    }

    /// Whether some force is held in world axes (a contact's λ, applied or not yet known).
    pub fn any_in_world_axes(&self) -> bool {
        !self.contacts.is_empty()
    }
}

impl Dynamics<'_> {
    /// Whether `rnea_grad` and `fd_grad` return `∂/∂fext`.
    pub fn wants_fext_grads(&self) -> bool {
        !self.model.specialisation.fext.is_empty() && !self.model.specialisation.no_fext_derivatives
    }

    /// Whether the model's dynamics kernels take contact forces λ.
    pub fn declares_contacts(&self) -> bool {
        !self.model.specialisation.contacts.is_empty()
    }

    /// Reads the model's `fext` input and the contact forces λ (from `lambda`) into
    /// per-body forces (nothing when the model declares neither): fext is Pinocchio's
    /// `[linear; angular]` in the joint's frame; λ is in world axes at the contact frame's
    /// origin p, so its body sees `[p × Rᵀf + Rᵀτ; Rᵀf]`, R the body's world rotation.
    pub fn load_forces(&mut self, lambda: LambdaSource) {
        let spec = &self.model.specialisation;
        if spec.fext.is_empty() && spec.contacts.is_empty() {
            return;
        }
        let n = self.n();
        let mut forces = Forces { body: vec![None; n], contacts: Vec::new() };
        let add = |forces: &mut Forces, g: &mut super::Graph, b: usize, f: Sv| {
            forces.body[b] = Some(match forces.body[b] {
                Some(old) => sp::add(g, &old, &f),
                None => f,
            });
        };
        for (j, &b) in spec.fext.iter().enumerate() {
            self.at(b, super::Stage::Forward);
            let x: [Id; 6] = std::array::from_fn(|c| self.g.input(Input::Fext, 6 * j + c));
            add(&mut forces, &mut self.g, b, [x[3], x[4], x[5], x[0], x[1], x[2]]);
        }
        if !spec.contacts.is_empty() {
            let poses = self.world_poses();
            let mut at = 0;
            for c in &spec.contacts {
                let frame = &self.model.frames[c.frame];
                let b = frame.body.expect("contacts are on moving bodies");
                self.at(b, super::Stage::Forward);
                let g = &mut self.g;
                let here: Option<Vec<Id>> = match &lambda {
                    LambdaSource::Inputs => {
                        Some((0..c.kind.dim()).map(|i| g.input(Input::Lambda, at + i)).collect())
                    }
                    LambdaSource::Unknown => None,
                    LambdaSource::Nodes(l) => Some(l[at..at + c.kind.dim()].to_vec()),
                };
                at += c.kind.dim();
                let rotation = poses[b].0;
                let point: V3 = std::array::from_fn(|i| k(g, frame.placement.pos[i]));
                let force = match &here {
                    Some(l) => contact_force(g, &rotation, &point, c.kind, l),
                    None => sp::zero(g),
                };
                let axes = self
                    .model
                    .ancestors(b)
                    .into_iter()
                    .filter(|&u| self.model.joints[u].joint_type.is_rotation())
                    .map(|u| {
                        let axis: V3 = std::array::from_fn(|i| k(g, self.model.joints[u].axis[i]));
                        (u, sp::mat_vec(g, &poses[u].0, &axis))
                    })
                    .collect();
                if here.is_some() {
                    add(&mut forces, g, b, force);
                }
                forces.contacts.push(ContactForce {
                    body: b,
                    kind: c.kind,
                    rotation,
                    point,
                    force,
                    axes,
                });
            }
        }
        self.forces = forces;
    }

    /// `J_bᵀ w` per model joint for a force w on body b in b's frame (0 off b's path).
    fn jacobian_t(&mut self, b: usize, mut w: Sv) -> Vec<Id> {
        let zero = self.g.constant(0.0);
        let mut out = vec![zero; self.n()];
        let mut at = Some(b);
        while let Some(j) = at {
            self.at(j, super::Stage::Backward);
            out[j] = sp::dot(&mut self.g, &self.s[j], &w);
            at = self.model.joints[j].parent;
            if at.is_some() {
                w = self.x[j].apply_t(&mut self.g, &w);
            }
        }
        out
    }

    /// λ held in world axes: joint u turns body b by ω = R_bᵀ (R_u a_u) under the
    /// contact's world-aligned frame, so the body-frame force f changes by `−m ×* f`, m =
    /// `[ω; p × ω]` the rotation about the contact point; RNEA subtracts f, so `∂c/∂q_u`
    /// gains `J_bᵀ (m ×* f)` (checked against central differences in
    /// `scripts/make_fixtures.py` and `tests/forces.rs`). Per model joint.
    pub(super) fn add_contact_q_terms(&mut self, dq: &mut Mat) {
        for c in self.forces.contacts.clone() {
            for &(u, axis) in &c.axes {
                let g = &mut self.g;
                let w = sp::mat_t_vec(g, &c.rotation, &axis);
                let pw = sp::cross(g, &c.point, &w);
                let m = [w[0], w[1], w[2], pw[0], pw[1], pw[2]];
                let t = sp::crf(g, &m, &c.force);
                for (i, x) in self.jacobian_t(c.body, t).into_iter().enumerate() {
                    if self.model.is_ancestor_or_self(i, c.body) {
                        dq[i][u] = self.g.add(dq[i][u], x);
                    }
                }
            }
        }
    }

    /// The columns of `(∂c/∂fext, ∂c/∂λ)` per coordinate (nv entries each), in the inputs'
    /// order: `−J_bᵀ` for each body's force (`[fx, fy, fz, tx, ty, tz]`), `−J_cᵀ` for each
    /// contact (J_c its frame's `LOCAL_WORLD_ALIGNED` Jacobian, the linear rows for a point).
    /// No fext columns unless [`Self::wants_fext_grads`].
    pub fn force_grad_columns(&mut self) -> (Vec<Vec<Id>>, Vec<Vec<Id>>) {
        (self.fext_columns(), self.lambda_columns())
    }

    /// The columns of `∂c/∂fext` (see [`Self::force_grad_columns`]).
    fn fext_columns(&mut self) -> Vec<Vec<Id>> {
        let bodies = if self.wants_fext_grads() {
            self.model.specialisation.fext.clone()
        } else {
            Vec::new()
        };
        let mut by_fext: Vec<Vec<Id>> = Vec::new();
        for b in bodies {
            for c in 0..6 {
                let (zero, minus_one) = (self.g.constant(0.0), self.g.constant(-1.0));
                let mut w = [zero; 6];
                w[(c + 3) % 6] = minus_one;
                let col = self.jacobian_t(b, w);
                by_fext.push(self.reduce(&col));
            }
        }
        by_fext
    }

    /// The columns of `∂c/∂λ = −J_cᵀ`, per coordinate (see [`Self::force_grad_columns`]).
    pub(super) fn lambda_columns(&mut self) -> Vec<Vec<Id>> {
        let mut by_lambda: Vec<Vec<Id>> = Vec::new();
        for c in self.forces.contacts.clone() {
            for i in 0..c.kind.dim() {
                let g = &mut self.g;
                let (zero, minus_one) = (g.constant(0.0), g.constant(-1.0));
                let mut e: Vec<Id> = vec![zero; 6];
                e[i] = minus_one;
                let w = contact_force(g, &c.rotation, &c.point, ContactKind::Wrench, &e);
                let col = self.jacobian_t(c.body, w);
                by_lambda.push(self.reduce(&col));
            }
        }
        by_lambda
    }
}

/// Columns to a row-major `rows x columns.len()` matrix.
pub(crate) fn transpose(columns: Vec<Vec<Id>>, rows: usize) -> Mat {
    (0..rows).map(|r| columns.iter().map(|c| c[r]).collect()).collect()
}

/// A contact's force on its body in the body's frame: `[p × Rᵀf + Rᵀτ; Rᵀf]` (τ only for
/// a wrench).
fn contact_force(
    g: &mut super::Graph,
    r: &[[Id; 3]; 3],
    p: &V3,
    kind: ContactKind,
    lambda: &[Id],
) -> Sv {
    let f = sp::mat_t_vec(g, r, &[lambda[0], lambda[1], lambda[2]]);
    let mut n = sp::cross(g, p, &f);
    if kind == ContactKind::Wrench {
        let t = sp::mat_t_vec(g, r, &[lambda[3], lambda[4], lambda[5]]);
        n = sp::add3(g, &n, &t);
    }
    [n[0], n[1], n[2], f[0], f[1], f[2]]
}
