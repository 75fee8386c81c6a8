//! `grid-gen eval`: the reference dynamics on a batch of states given as JSON.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::model::Model;
use crate::reference;

/// One input state; vectors in model order.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct State {
    #[serde(deserialize_with = "numbers")]
    pub q: Vec<f64>,
    #[serde(deserialize_with = "numbers")]
    pub qd: Vec<f64>,
    #[serde(default, deserialize_with = "some_numbers")]
    pub qdd: Option<Vec<f64>>,
    #[serde(default, deserialize_with = "some_numbers")]
    pub tau: Option<Vec<f64>>,
    /// A tangent vector (nv entries): `integrate` from q along it, and its Jacobians.
    #[serde(default, deserialize_with = "some_numbers")]
    pub v: Option<Vec<f64>>,
    /// A second configuration (nq entries): `difference` from q to it, and its Jacobians.
    #[serde(default, deserialize_with = "some_numbers")]
    pub q1: Option<Vec<f64>>,
    /// External forces `[fx, fy, fz, tx, ty, tz]` in the joint's frame (Pinocchio's
    /// `fext`), keyed by the name of the joint that moves the body.
    #[serde(default)]
    pub fext: BTreeMap<String, Values>,
    /// Contact forces λ (3 or 6 values, world axes at the frame), keyed by a contact frame
    /// the scene declares; a declared contact left out has λ = 0.
    #[serde(default)]
    pub contacts: BTreeMap<String, Values>,
    /// The step's time step in seconds, for a scene that leaves `[step] dt` to run time
    /// (needed there with `tau`; where the scene folds dt, it may only repeat it).
    #[serde(default)]
    pub dt: Option<f64>,
    /// For a scene that masks its contacts (`contact_mask`): which hold, keyed by contact
    /// frame; a contact left out holds. An inactive contact has λ = 0 and no constraint in
    /// `contact_fd` and the step.
    #[serde(default)]
    pub active: BTreeMap<String, bool>,
    /// For a scene that stabilises its contacts (`baumgarte`): each contact's Baumgarte
    /// corrector, keyed by contact frame; a contact left out has gains 0 (held rigid).
    #[serde(default)]
    pub baumgarte: BTreeMap<String, Corrector>,
}

/// One contact's Baumgarte corrector (Pinocchio's `BaumgarteCorrectorParameters` and the
/// reference placement of `joint2`, the universe): the contact's acceleration is driven to
/// `−kd v − kp e`, e a point's `p − ref`, a wrench's `−log6(oMc⁻¹ oMref)` in world axes.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Corrector {
    pub kp: f64,
    pub kd: f64,
    /// The reference in the world: a point contact's position `[x, y, z]`, a wrench
    /// contact's placement `[x, y, z, qx, qy, qz, qw]` (may be left out where kp is 0).
    #[serde(default, rename = "ref")]
    pub reference: Option<Values>,
}

/// A list of numbers, read as [`State`]'s vectors are (NaN and infinities included, so
/// that [`check_states`] names them).
#[derive(Clone, Debug)]
pub struct Values(pub Vec<f64>);

impl<'de> Deserialize<'de> for Values {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        numbers(d).map(Values)
    }
}

/// A number, or one of the strings that [`quote_non_finite`] makes of NaN and infinities.
#[derive(Deserialize)]
#[serde(untagged)]
enum Number {
    Finite(f64),
    Named(String),
}

fn numbers<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
    let raw: Vec<Number> = Deserialize::deserialize(d)?;
    raw.into_iter()
        .map(|n| match n {
            Number::Finite(x) => Ok(x),
            Number::Named(s) => match s.as_str() {
                "NaN" => Ok(f64::NAN),
                "Infinity" => Ok(f64::INFINITY),
                "-Infinity" => Ok(f64::NEG_INFINITY),
                _ => Err(serde::de::Error::custom(format!(
                    "expected a number, found the string `{s}`"
                ))),
            },
        })
        .collect()
}

fn some_numbers<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<Vec<f64>>, D::Error> {
    numbers(d).map(Some)
}

/// Python's `json.dump` writes NaN and infinities as bare `NaN`, `Infinity`,
/// `-Infinity`, which are not JSON. Quoting them outside strings lets the state checks
/// name the offending entry instead of failing on a syntax error.
fn quote_non_finite(json: &str) -> String {
    let mut out = String::with_capacity(json.len());
    let mut in_string = false;
    let mut escaped = false;
    let mut rest = json;
    while let Some(c) = rest.chars().next() {
        if in_string {
            in_string = escaped || c != '"';
            escaped = !escaped && c == '\\';
        } else if c == '"' {
            in_string = true;
        } else if let Some(word) =
            ["-Infinity", "Infinity", "NaN"].into_iter().find(|w| rest.starts_with(w))
        {
            out.push('"');
            out.push_str(word);
            out.push('"');
            rest = &rest[word.len()..];
            continue;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StatesFile {
    pub states: Vec<State>,
}

type Matrix = Vec<Vec<f64>>;

/// Results for one state. Entries that need `qdd` (RNEA and its gradient) or `tau`
/// (forward dynamics and its gradient) are present only when those were given.
#[derive(Clone, Debug, Serialize)]
pub struct Output {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rnea: Option<Vec<f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drnea_dq: Option<Matrix>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drnea_dqd: Option<Matrix>,
    #[serde(rename = "M")]
    pub m: Matrix,
    /// Absent when M is singular ([`Model::singular`]).
    #[serde(rename = "Minv", skip_serializing_if = "Option::is_none")]
    pub minv: Option<Matrix>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fd: Option<Vec<f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dfd_dq: Option<Matrix>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dfd_dqd: Option<Matrix>,
    /// The selected frames' kinematics, by link name (absent when no frames were asked for).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frames: Option<BTreeMap<String, FrameOutput>>,
    /// With a step (`--step`, `[step]`) and `tau`: the next state and `[A | B]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub step: Option<StepOutput>,
    /// With `qdd`: `∂c/∂fext` (nv × 6) for each body with a force (the state's and the
    /// scene's), keyed by joint.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drnea_dfext: Option<BTreeMap<String, Matrix>>,
    /// With `tau`: `∂q̈/∂fext`, likewise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dfd_dfext: Option<BTreeMap<String, Matrix>>,
    /// With `qdd` and contacts declared: `∂c/∂λ` (nv × 3 or 6) per contact frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drnea_dlambda: Option<BTreeMap<String, Matrix>>,
    /// With `tau` and contacts declared: `∂q̈/∂λ`, likewise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dfd_dlambda: Option<BTreeMap<String, Matrix>>,
    /// With `tau` and contacts declared: rigid-contact forward dynamics and its
    /// derivatives (the state's `contacts` are not read: λ is solved for).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact_fd: Option<ContactOutput>,
    /// With `v`: `q ⊕ v` and its Jacobians (Pinocchio's `integrate`, `dIntegrate`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub integrate: Option<IntegrateOutput>,
    /// With `q1`: `q1 ⊖ q` and its Jacobians (Pinocchio's `difference`, `dDifference`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub difference: Option<DifferenceOutput>,
}

/// `integrate(q, v)` and its Jacobians in the tangent space (`ARG0`, `ARG1`).
#[derive(Clone, Debug, Serialize)]
pub struct IntegrateOutput {
    pub q_next: Vec<f64>,
    pub dq: Matrix,
    pub dv: Matrix,
}

/// `difference(q, q1)` and its Jacobians in the tangent space (`ARG0`, `ARG1`).
#[derive(Clone, Debug, Serialize)]
pub struct DifferenceOutput {
    pub v: Vec<f64>,
    pub dq: Matrix,
    pub dq1: Matrix,
}

/// Rigid-contact forward dynamics at one state (see [`crate::reference::contact_fd`]):
/// q̈, λ per contact frame (world axes at the frame, Pinocchio's `lambda_c`), and their
/// derivatives, q in the tangent space; λ's as `rows x nv` per frame.
#[derive(Clone, Debug, Serialize)]
pub struct ContactOutput {
    pub qdd: Vec<f64>,
    pub lambda: BTreeMap<String, Vec<f64>>,
    pub dqdd_dq: Matrix,
    pub dqdd_dqd: Matrix,
    pub dqdd_dtau: Matrix,
    pub dlambda_dq: BTreeMap<String, Matrix>,
    pub dlambda_dqd: BTreeMap<String, Matrix>,
    pub dlambda_dtau: BTreeMap<String, Matrix>,
}

/// The reference's contact dynamics at one state, when the model declares contacts and
/// the state has a `tau`; an error where the contacts' Jacobian loses rank at the state.
fn contact_output(
    fm: &Model,
    s: &State,
    index: usize,
    fext: &[f64],
    gravity: [f64; 3],
) -> Result<Option<ContactOutput>, EvalError> {
    let Some(tau) = s.tau.as_ref().filter(|_| !fm.specialisation.contacts.is_empty()) else {
        return Ok(None);
    };
    // The model holding just the state's active contacts; the others get zero rows below.
    let held = holding(fm, s);
    let (gains, refs) = correctors(&held, s);
    let corr = reference::Baumgarte { gains: &gains, refs: &refs };
    let (sol, d) =
        reference::contact_fd_derivatives_with(&held, &s.q, &s.qd, tau, gravity, fext, corr)
            .ok_or(EvalError::ContactsSingular { index })?;
    if sol.qdd.iter().chain(&sol.lambda).any(|x| !x.is_finite()) {
        return Err(EvalError::ContactsSingular { index });
    }
    let per_frame = |m: &nalgebra::DMatrix<f64>| per_contact(fm, s, m);
    Ok(Some(ContactOutput {
        qdd: sol.qdd,
        lambda: per_contact(
            fm,
            s,
            &nalgebra::DMatrix::from_column_slice(sol.lambda.len(), 1, &sol.lambda),
        )
        .into_iter()
        .map(|(name, rows)| (name, rows.into_iter().flatten().collect()))
        .collect(),
        dqdd_dq: rows(&d.dqdd_dq),
        dqdd_dqd: rows(&d.dqdd_dqd),
        dqdd_dtau: rows(&d.dqdd_dtau),
        dlambda_dq: per_frame(&d.dlambda_dq),
        dlambda_dqd: per_frame(&d.dlambda_dqd),
        dlambda_dtau: per_frame(&d.dlambda_dtau),
    }))
}

/// The rows of `m` (λ's layout for the contacts `s` holds) per contact frame of `fm`: each
/// held contact's own rows, and zeros for one the state turns off.
fn per_contact(fm: &Model, s: &State, m: &nalgebra::DMatrix<f64>) -> BTreeMap<String, Matrix> {
    let mut at = 0;
    fm.specialisation
        .contacts
        .iter()
        .map(|c| {
            let (name, width) = (fm.frames[c.frame].name.clone(), c.kind.dim());
            if s.active.get(&name).copied().unwrap_or(true) {
                at += width;
                (name, rows(&m.rows(at - width, width).into_owned()))
            } else {
                (name, vec![vec![0.0; m.ncols()]; width])
            }
        })
        .collect()
}

/// The model holding just the contacts a state's `active` leaves on (all of them unless
/// the state turns some off).
fn holding<'m>(model: &'m Model, s: &State) -> std::borrow::Cow<'m, Model> {
    if s.active.values().all(|&a| a) {
        return std::borrow::Cow::Borrowed(model);
    }
    let contacts = &model.specialisation.contacts;
    let flags: Vec<bool> = contacts
        .iter()
        .map(|c| s.active.get(&model.frames[c.frame].name) != Some(&false))
        .collect();
    std::borrow::Cow::Owned(model.holding_contacts(&flags))
}

/// A state's forces as the reference takes them: the model with the state's bodies
/// added to the declared ones, and the flat `fext` and λ.
fn state_forces<'m>(
    model: &'m Model,
    s: &State,
) -> (std::borrow::Cow<'m, Model>, Vec<f64>, Vec<f64>) {
    // A copy of the model only when the state names a body the scene does not declare.
    let mut m = std::borrow::Cow::Borrowed(model);
    for name in s.fext.keys() {
        let b = model.body_of_joint(name).expect("checked");
        if !m.specialisation.fext.contains(&b) {
            m.to_mut().specialisation.fext.push(b);
        }
    }
    let mut fext = vec![0.0; 6 * m.nfext()];
    for (j, &b) in m.specialisation.fext.iter().enumerate() {
        if let Some(v) = s.fext.get(model.joint_name(b)) {
            fext[6 * j..6 * j + 6].copy_from_slice(&v.0);
        }
    }
    let mut lambda = Vec::with_capacity(m.nlambda());
    for c in &m.specialisation.contacts {
        match s.contacts.get(&m.frames[c.frame].name) {
            Some(v) => lambda.extend(&v.0),
            None => lambda.extend(vec![0.0; c.kind.dim()]),
        }
    }
    (m, fext, lambda)
}

/// Splits a derivative's columns by force: 6 per fext body, 3 or 6 per contact.
fn by_force(m: &nalgebra::DMatrix<f64>, names: &[(String, usize)]) -> BTreeMap<String, Matrix> {
    let mut at = 0;
    names
        .iter()
        .map(|(name, width)| {
            at += width;
            (name.clone(), rows(&m.columns(at - width, *width).into_owned()))
        })
        .collect()
}

/// One step from a state (see [`crate::reference::step_derivatives`]): q⁺ in q's layout,
/// q̇⁺, and A (2nv × 2nv), B (2nv × nu), rows and columns `[δq; δq̇]` in the tangent
/// space, base first; B's columns are the actuated joints in model order.
#[derive(Clone, Debug, Serialize)]
pub struct StepOutput {
    pub q_next: Vec<f64>,
    pub qd_next: Vec<f64>,
    #[serde(rename = "A")]
    pub a: Matrix,
    #[serde(rename = "B")]
    pub b: Matrix,
    /// With contacts: their forces at the state (its first stage under RK4), per contact
    /// frame as `contact_fd`'s, and their derivatives by the state (`rows x 2nv`, columns
    /// `[δq; δq̇]`) and by the actuated τ (`rows x nu`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lambda: Option<BTreeMap<String, Vec<f64>>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dlambda_dx: Option<BTreeMap<String, Matrix>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dlambda_du: Option<BTreeMap<String, Matrix>>,
}

/// The reference's step at one state, when the model has a step and the state a `tau`:
/// the state's `fext` held over the step, the model's contacts rigid (their λ solved, so a
/// state's `contacts` do not enter it).
fn step_output(
    model: &Model,
    s: &State,
    index: usize,
    fext: &[f64],
    gravity: [f64; 3],
) -> Result<Option<StepOutput>, EvalError> {
    let (Some(step), Some(tau)) = (model.specialisation.step, s.tau.as_ref()) else {
        return Ok(None);
    };
    // check_states made sure that a run-time step has its dt.
    let step = step.at(s.dt.unwrap_or(f64::NAN));
    let held = holding(model, s);
    let (gains, refs) = correctors(&held, s);
    let corr = reference::Baumgarte { gains: &gains, refs: &refs };
    let d = reference::step_derivatives_with(
        &held,
        &s.q,
        &s.qd,
        tau,
        gravity,
        step,
        &model.actuated(),
        fext,
        corr,
    )
    .ok_or(EvalError::ContactsSingular { index })?;
    let mut out = StepOutput {
        q_next: d.q_next,
        qd_next: d.qd_next,
        a: rows(&d.a),
        b: rows(&d.b),
        lambda: None,
        dlambda_dx: None,
        dlambda_du: None,
    };
    if !model.specialisation.contacts.is_empty() {
        let (lambda, dx, du) = reference::step_lambda_with(
            &held,
            &s.q,
            &s.qd,
            tau,
            gravity,
            &model.actuated(),
            fext,
            corr,
        )
        .ok_or(EvalError::ContactsSingular { index })?;
        let lambda = nalgebra::DMatrix::from_column_slice(lambda.len(), 1, &lambda);
        out.lambda = Some(
            per_contact(model, s, &lambda)
                .into_iter()
                .map(|(name, rows)| (name, rows.into_iter().flatten().collect()))
                .collect(),
        );
        out.dlambda_dx = Some(per_contact(model, s, &dx));
        out.dlambda_du = Some(per_contact(model, s, &du));
    }
    Ok(Some(out))
}

/// One frame's kinematics at a state, in Pinocchio's conventions: 6-vectors and Jacobian
/// rows [linear; angular], Jacobian columns in model (velocity) order; each quantity keyed
/// by reference frame (`local`, `world`, `local_world_aligned`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameOutput {
    /// World position of the frame's origin.
    pub translation: Vec<f64>,
    /// The frame's axes in world coordinates (rows of the rotation matrix).
    pub rotation: Matrix,
    /// 6 × nv.
    pub jacobian: BTreeMap<&'static str, Matrix>,
    /// The spatial velocity (local and local_world_aligned).
    pub velocity: BTreeMap<&'static str, Vec<f64>>,
    /// The classical acceleration of the frame's origin, when the state has `qdd` (local
    /// and local_world_aligned).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub classical_acceleration: BTreeMap<&'static str, Vec<f64>>,
}

/// The reference's frame kinematics of the model's selected frames at one state.
fn frame_outputs(model: &Model, s: &State) -> Option<BTreeMap<String, FrameOutput>> {
    use crate::model::ReferenceFrame;
    if model.specialisation.frames.is_empty() {
        return None;
    }
    let mut out = BTreeMap::new();
    for f in model.selected_frames() {
        let (r, p) = reference::frame_placement(model, &s.q, f);
        let mut o = FrameOutput {
            translation: p.iter().copied().collect(),
            rotation: rows(&nalgebra::DMatrix::from_fn(3, 3, |i, j| r[(i, j)])),
            ..FrameOutput::default()
        };
        for rf in ReferenceFrame::ALL {
            o.jacobian.insert(rf.name(), rows(&reference::frame_jacobian(model, &s.q, f, rf)));
        }
        for rf in [ReferenceFrame::Local, ReferenceFrame::LocalWorldAligned] {
            o.velocity
                .insert(rf.name(), reference::frame_velocity(model, &s.q, &s.qd, f, rf).to_vec());
            if let Some(qdd) = &s.qdd {
                o.classical_acceleration.insert(
                    rf.name(),
                    reference::frame_classical_acceleration(model, &s.q, &s.qd, qdd, f, rf)
                        .to_vec(),
                );
            }
        }
        out.insert(f.name.clone(), o);
    }
    Some(out)
}

#[derive(Clone, Debug, Serialize)]
pub struct EvalOutput {
    pub joint_names: Vec<String>,
    pub states: Vec<Output>,
}

/// A states file that cannot be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("cannot read the states file: {0}")]
    Json(#[from] serde_json::Error),
    #[error("state {index}: `{field}` has {found} entries, the robot has {expected} {unit}")]
    Length { index: usize, field: &'static str, found: usize, expected: usize, unit: &'static str },
    #[error("the states file is a bare array: write it as an object, {{\"states\": [{{\"q\": [...], \"qd\": [...]}}, ...]}}")]
    BareArray,
    #[error(
        "state {index}: `{field}` has {found} entries, expected {expected}: the floating base's position and quaternion \
         `[x, y, z, qx, qy, qz, qw]`, then one per joint after the base (nq = nv + 1, Pinocchio's layout)"
    )]
    FloatingLength { index: usize, field: &'static str, found: usize, expected: usize },
    #[error(
        "state {index}: `{field}` has {found} entries, expected {expected}: one per joint, with a quaternion `[qx, qy, qz, qw]` \
         for each spherical joint ({layout}) (Pinocchio's layout)"
    )]
    SphericalLength {
        index: usize,
        field: &'static str,
        found: usize,
        expected: usize,
        layout: String,
    },
    #[error(
        "state {index}: the base quaternion `{field}[3..7]` has norm {norm}, not 1 (more than {QUATERNION_TOLERANCE:e} off): \
         is it stored `[qx, qy, qz, qw]`, after the position `[x, y, z]`?"
    )]
    Quaternion { index: usize, field: &'static str, norm: f64 },
    #[error(
        "state {index}: the quaternion of spherical joint `{joint}`, `{field}[{at}..{end}]`, has norm {norm}, not 1 (more \
         than {QUATERNION_TOLERANCE:e} off): is it stored `[qx, qy, qz, qw]`?", end = at + 4
    )]
    SphericalQuaternion { index: usize, field: &'static str, joint: String, at: usize, norm: f64 },
    #[error("state {index}: `{field}[{entry}]` is not finite")]
    NotFinite { index: usize, field: &'static str, entry: usize },
    #[error(
        "state {index}: `tau[{entry}]` ({joint}) is {value}, but that joint is not actuated and the step takes only the \
         actuated joints' forces; give 0 there, or name the joint in the scene's [actuation] joints"
    )]
    NotActuated { index: usize, entry: usize, joint: String, value: f64 },
    #[error("state {index}: `qd[{entry}]` is {value}, and the scene is static (`static = true`: q̇ = 0 is assumed and the kernels ignore `qd`); give q̇ = 0 or leave `static` out")]
    NotStatic { index: usize, entry: usize, value: f64 },
    #[error("state {index}: `tau` asks for forward dynamics, which needs M⁻¹, and M is singular (joint `{joint}` moves no inertia); leave `tau` out")]
    Singular { index: usize, joint: String },
    #[error("state {index}: `fext` names `{key}`, which is no joint of the model that moves a body; joints: {known}")]
    UnknownForce { index: usize, key: String, known: String },
    #[error("state {index}: `contacts` names `{key}`, which is not a contact the scene declares; declared: {declared} (declare contacts with [[contact]] or --contact FRAME:point)")]
    UnknownContact { index: usize, key: String, declared: String },
    #[error("state {index}: `{field}.{key}` has {found} values, expected {expected} ({what})")]
    ForceLength {
        index: usize,
        field: &'static str,
        key: String,
        found: usize,
        expected: usize,
        what: &'static str,
    },
    #[error("state {index}: `{field}.{key}[{entry}]` is not finite")]
    ForceNotFinite { index: usize, field: &'static str, key: String, entry: usize },
    #[error("external and contact forces are evaluated by the reference only (`eval` without --backend); the generated Rust and WGSL kernels take them, and the tests compare those with the reference")]
    ForcesOnBackend,
    #[error("state {index}: the step takes its time step at run time (the scene's [step] has no dt): give `dt` (seconds) beside `tau`")]
    NoDt { index: usize },
    #[error("state {index}: `dt` is {value}, not a finite, positive number of seconds")]
    BadDt { index: usize, value: f64 },
    #[error("state {index}: `dt` is {value}, but the step's dt = {folded} s is folded into the kernels ({why}); leave `dt` out, or leave [step] dt out to give it per state")]
    FoldedDt { index: usize, value: f64, folded: f64, why: &'static str },
    #[error("state {index}: `active` is given, but the scene does not mask its contacts; add `contact_mask = true` (or --contact-mask) to choose them per state")]
    NotMasked { index: usize },
    #[error("state {index}: `active` names `{key}`, which is not a contact the scene declares; declared: {declared}")]
    UnknownActive { index: usize, key: String, declared: String },
    #[error("state {index}: `baumgarte` is given, but the scene does not stabilise its contacts; add `baumgarte = true` (or --baumgarte)")]
    NotStabilised { index: usize },
    #[error("state {index}: `baumgarte` names `{key}`, which is not a contact the scene declares; declared: {declared}")]
    UnknownCorrector { index: usize, key: String, declared: String },
    #[error("state {index}: `baumgarte` of `{key}`: {why}")]
    BadCorrector { index: usize, key: String, why: &'static str },
    #[error("state {index}: `dt` is given, but the model takes no step; add [step] to the scene, or --step")]
    DtWithoutStep { index: usize },
    #[error("state {index}: the contacts' Jacobian loses rank at this configuration, so rigid-contact dynamics has no unique solution (contact_fd, and a step that integrates it); move the state away from the singularity or declare fewer contacts")]
    ContactsSingular { index: usize },
}

fn rows(m: &nalgebra::DMatrix<f64>) -> Matrix {
    m.row_iter().map(|r| r.iter().copied().collect()).collect()
}

/// A gradient as the scene's kernels give it: the entries the scene does not read are 0
/// ([`crate::model::Specialisation`]).
fn gradient_rows(model: &Model, m: &nalgebra::DMatrix<f64>) -> Matrix {
    let mut out = rows(m);
    for (i, row) in out.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            if !model.specialisation.keeps(i, j) {
                *x = 0.0;
            }
        }
    }
    out
}

/// Parses a states file (see [`StatesFile`]); bare `NaN`/`Infinity` are read so that
/// [`check_states`] can point at them.
pub fn parse_states(json: &str) -> Result<StatesFile, EvalError> {
    if json.trim_start().starts_with('[') {
        return Err(EvalError::BareArray);
    }
    Ok(serde_json::from_str(&quote_non_finite(json))?)
}

pub use crate::model::QUATERNION_TOLERANCE;

/// Where each spherical joint's quaternion is in q, for an error message.
fn spherical_layout(model: &Model) -> String {
    let base = if model.floating {
        "the floating base's `[x, y, z, qx, qy, qz, qw]` at q[0..7]; "
    } else {
        ""
    };
    let joints: Vec<String> = model
        .spherical
        .iter()
        .map(|&s| {
            format!(
                "`{}` at q[{}..{}]",
                model.joint_name(s.0),
                model.group_q(s).0,
                model.group_q(s).0 + 4
            )
        })
        .collect();
    format!("{base}{}", joints.join(", "))
}

/// Checks every state's lengths and values against the model.
pub fn check_states(model: &Model, file: &StatesFile) -> Result<(), EvalError> {
    let n = model.nv();
    for (index, s) in file.states.iter().enumerate() {
        let fields = [
            ("q", Some(&s.q)),
            ("qd", Some(&s.qd)),
            ("qdd", s.qdd.as_ref()),
            ("tau", s.tau.as_ref()),
            ("v", s.v.as_ref()),
            ("q1", s.q1.as_ref()),
        ];
        for (field, v) in fields {
            let Some(v) = v else { continue };
            let config = field == "q" || field == "q1";
            if config && !model.spherical.is_empty() && v.len() != model.nq() {
                return Err(EvalError::SphericalLength {
                    index,
                    field,
                    found: v.len(),
                    expected: model.nq(),
                    layout: spherical_layout(model),
                });
            }
            if config && model.floating && v.len() != model.nq() {
                return Err(EvalError::FloatingLength {
                    index,
                    field,
                    found: v.len(),
                    expected: model.nq(),
                });
            }
            if v.len() != n && !(config && model.nq() != n) {
                // q has one entry per joint here; the others one per velocity coordinate,
                // which a floating base's six make more than its joints.
                let unit = match (field, model.floating) {
                    ("q" | "q1", _) => "joints",
                    (_, true) => {
                        "velocity coordinates (nv: the floating base's six, then one per joint)"
                    }
                    _ => "joints (one velocity coordinate each)",
                };
                return Err(EvalError::Length { index, field, found: v.len(), expected: n, unit });
            }
            if let Some(entry) = v.iter().position(|x| !x.is_finite()) {
                return Err(EvalError::NotFinite { index, field, entry });
            }
        }
        for (field, q) in [("q", Some(&s.q)), ("q1", s.q1.as_ref())] {
            let Some(q) = q else { continue };
            if model.floating {
                let norm = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
                if (norm - 1.0).abs() > QUATERNION_TOLERANCE {
                    return Err(EvalError::Quaternion { index, field, norm });
                }
            }
            for &first in &model.spherical {
                let at = model.group_q(first).0;
                let norm = q[at..at + 4].iter().map(|x| x * x).sum::<f64>().sqrt();
                if (norm - 1.0).abs() > QUATERNION_TOLERANCE {
                    return Err(EvalError::SphericalQuaternion {
                        index,
                        field,
                        joint: model.joint_name(first.0).to_string(),
                        at,
                        norm,
                    });
                }
            }
        }
        if let (true, Some(entry)) =
            (model.specialisation.static_velocity, s.qd.iter().position(|&x| x != 0.0))
        {
            return Err(EvalError::NotStatic { index, entry, value: s.qd[entry] });
        }
        if let (Some(joint), Some(_)) = (&model.singular, &s.tau) {
            return Err(EvalError::Singular { index, joint: joint.clone() });
        }
        check_forces(model, index, s)?;
        check_dt(model, index, s)?;
        check_active(model, index, s)?;
        check_baumgarte(model, index, s)?;
        if let (Some(_), Some(tau)) = (model.specialisation.step, &s.tau) {
            let actuated = model.actuated();
            if let Some(entry) = (0..n).find(|k| !actuated.contains(k) && tau[*k] != 0.0) {
                let joint = model.joint(model.coordinate_joints()[entry]).name.clone();
                return Err(EvalError::NotActuated { index, entry, joint, value: tau[entry] });
            }
        }
    }
    Ok(())
}

/// A state's `baumgarte`: only for a scene that stabilises its contacts, keyed by its
/// contacts, gains finite and non-negative, a reference of three finite numbers where kp is
/// not 0.
fn check_baumgarte(model: &Model, index: usize, s: &State) -> Result<(), EvalError> {
    if s.baumgarte.is_empty() {
        return Ok(());
    }
    if !model.specialisation.baumgarte {
        return Err(EvalError::NotStabilised { index });
    }
    let declared: Vec<&str> =
        model.specialisation.contacts.iter().map(|c| model.frames[c.frame].name.as_str()).collect();
    for (key, c) in &s.baumgarte {
        let Some(at) = declared.iter().position(|d| d == key) else {
            let declared = declared.join(", ");
            return Err(EvalError::UnknownCorrector { index, key: key.clone(), declared });
        };
        let bad = |why| Err(EvalError::BadCorrector { index, key: key.clone(), why });
        if !(c.kp.is_finite() && c.kd.is_finite() && c.kp >= 0.0 && c.kd >= 0.0) {
            return bad("kp and kd are finite and >= 0 (0: no correction)");
        }
        let wrench = model.specialisation.contacts[at].kind == crate::model::ContactKind::Wrench;
        match &c.reference {
            Some(r) if !wrench && (r.0.len() != 3 || !r.0.iter().all(|x| x.is_finite())) => {
                return bad("`ref` is a world position, three finite numbers")
            }
            Some(r) if wrench && (r.0.len() != 7 || !r.0.iter().all(|x| x.is_finite())) => {
                return bad("`ref` of a wrench contact is a world placement, seven finite numbers: [x, y, z, qx, qy, qz, qw]")
            }
            Some(r) if wrench && (r.0[3..].iter().map(|x| x * x).sum::<f64>().sqrt() - 1.0).abs() > QUATERNION_TOLERANCE => {
                return bad("`ref`'s quaternion [qx, qy, qz, qw] must have norm 1 (within 1e-6)")
            }
            None if c.kp != 0.0 => return bad("kp pulls the contact towards `ref`: give `ref`"),
            _ => {}
        }
    }
    Ok(())
}

/// The state's Baumgarte gains and references for the contacts `held` holds (zeros for a
/// contact the state leaves out), as the reference takes them.
fn correctors(held: &Model, s: &State) -> (Vec<f64>, Vec<f64>) {
    let (mut gains, mut refs) = (Vec::new(), Vec::new());
    if !held.specialisation.baumgarte {
        return (gains, refs);
    }
    for c in &held.specialisation.contacts {
        let corr = s.baumgarte.get(&held.frames[c.frame].name);
        gains.extend(corr.map_or([0.0; 2], |c| [c.kp, c.kd]));
        // Left out (kp 0): the origin, and for a wrench the identity rotation, whose
        // logarithm is finite, so that 0 · e adds nothing.
        let unset = match c.kind {
            crate::model::ContactKind::Point => vec![0.0; 3],
            crate::model::ContactKind::Wrench => vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        };
        refs.extend(corr.and_then(|c| c.reference.as_ref()).map_or(unset, |r| r.0.clone()));
    }
    (gains, refs)
}

/// A state's `active`: only for a scene that masks its contacts, keyed by its contacts.
fn check_active(model: &Model, index: usize, s: &State) -> Result<(), EvalError> {
    if s.active.is_empty() {
        return Ok(());
    }
    if !model.specialisation.contact_mask {
        return Err(EvalError::NotMasked { index });
    }
    let declared: Vec<&str> =
        model.specialisation.contacts.iter().map(|c| model.frames[c.frame].name.as_str()).collect();
    match s.active.keys().find(|k| !declared.contains(&k.as_str())) {
        Some(key) => {
            Err(EvalError::UnknownActive { index, key: key.clone(), declared: declared.join(", ") })
        }
        None => Ok(()),
    }
}

/// A state's `dt`: finite and positive; required by a run-time step where the state asks
/// for the step (`tau`), and only a repetition of a folded one.
fn check_dt(model: &Model, index: usize, s: &State) -> Result<(), EvalError> {
    let step = model.specialisation.step;
    match (s.dt, step.map(|st| st.dt)) {
        (Some(value), _) if !(value.is_finite() && value > 0.0) => {
            Err(EvalError::BadDt { index, value })
        }
        (Some(value), Some(Some(folded))) if value != folded => {
            Err(EvalError::FoldedDt { index, value, folded, why: "the scene's [step] dt or --dt" })
        }
        (Some(_), None) => Err(EvalError::DtWithoutStep { index }),
        (None, Some(None)) if s.tau.is_some() => Err(EvalError::NoDt { index }),
        _ => Ok(()),
    }
}

/// A state's `fext` and `contacts`: known keys, the right number of finite values.
fn check_forces(model: &Model, index: usize, s: &State) -> Result<(), EvalError> {
    for (key, v) in &s.fext {
        if model.body_of_joint(key).is_none() {
            return Err(EvalError::UnknownForce {
                index,
                key: key.clone(),
                known: model.body_joint_names().join(", "),
            });
        }
        if v.0.len() != 6 {
            return Err(EvalError::ForceLength {
                index,
                field: "fext",
                key: key.clone(),
                found: v.0.len(),
                expected: 6,
                what: "[fx, fy, fz, tx, ty, tz]",
            });
        }
        if let Some(entry) = v.0.iter().position(|x| !x.is_finite()) {
            return Err(EvalError::ForceNotFinite {
                index,
                field: "fext",
                key: key.clone(),
                entry,
            });
        }
    }
    let declared: Vec<(&str, crate::model::ContactKind)> = model
        .specialisation
        .contacts
        .iter()
        .map(|c| (model.frames[c.frame].name.as_str(), c.kind))
        .collect();
    for (key, v) in &s.contacts {
        let Some(&(_, kind)) = declared.iter().find(|(n, _)| n == key) else {
            let names: Vec<&str> = declared.iter().map(|(n, _)| *n).collect();
            let declared = if names.is_empty() { "none".to_string() } else { names.join(", ") };
            return Err(EvalError::UnknownContact { index, key: key.clone(), declared });
        };
        if v.0.len() != kind.dim() {
            let what = if kind == crate::model::ContactKind::Point {
                "a point contact's force [fx, fy, fz]"
            } else {
                "a wrench [fx, fy, fz, tx, ty, tz]"
            };
            return Err(EvalError::ForceLength {
                index,
                field: "contacts",
                key: key.clone(),
                found: v.0.len(),
                expected: kind.dim(),
                what,
            });
        }
        if let Some(entry) = v.0.iter().position(|x| !x.is_finite()) {
            return Err(EvalError::ForceNotFinite {
                index,
                field: "contacts",
                key: key.clone(),
                entry,
            });
        }
    }
    Ok(())
}

/// The coordinates' joint names, the order of every vector and matrix in the output.
fn coordinate_names(model: &Model) -> Vec<String> {
    model.coordinate_joints().iter().map(|&i| model.joint(i).name.clone()).collect()
}

/// Evaluates the reference dynamics on every state.
pub fn evaluate(
    model: &Model,
    file: &StatesFile,
    gravity: [f64; 3],
) -> Result<EvalOutput, EvalError> {
    check_states(model, file)?;
    let states = file
        .states
        .iter()
        .enumerate()
        .map(|(index, s)| {
            let (fm, fext, lambda) = state_forces(model, s);
            let ext = reference::External { fext: &fext, lambda: &lambda };
            let (rnea, drnea_dq, drnea_dqd) = match &s.qdd {
                Some(qdd) => {
                    let (dq, dqd) =
                        reference::rnea_derivatives_with(&fm, &s.q, &s.qd, qdd, gravity, ext);
                    (
                        Some(reference::rnea_with(&fm, &s.q, &s.qd, qdd, gravity, ext)),
                        Some(gradient_rows(model, &dq)),
                        Some(gradient_rows(model, &dqd)),
                    )
                }
                None => (None, None, None),
            };
            let (fd, dfd_dq, dfd_dqd) = match &s.tau {
                Some(tau) => {
                    let (qdd, dq, dqd) = reference::forward_dynamics_derivatives_with(
                        &fm, &s.q, &s.qd, tau, gravity, ext,
                    );
                    (Some(qdd), Some(gradient_rows(model, &dq)), Some(gradient_rows(model, &dqd)))
                }
                None => (None, None, None),
            };
            let minv = model.singular.is_none().then(|| rows(&reference::minv(model, &s.q)));
            let frames = frame_outputs(model, s);
            let step = step_output(&fm, s, index, &fext, gravity)?;
            let mut out = Output {
                rnea,
                drnea_dq,
                drnea_dqd,
                m: rows(&reference::crba(model, &s.q)),
                minv,
                fd,
                dfd_dq,
                dfd_dqd,
                frames,
                step,
                drnea_dfext: None,
                dfd_dfext: None,
                drnea_dlambda: None,
                dfd_dlambda: None,
                contact_fd: contact_output(&fm, s, index, &fext, gravity)?,
                integrate: s.v.as_ref().map(|v| {
                    let (dq, dv) = reference::d_integrate(model, v);
                    IntegrateOutput {
                        q_next: reference::integrate(model, &s.q, v),
                        dq: rows(&dq),
                        dv: rows(&dv),
                    }
                }),
                difference: s.q1.as_ref().map(|q1| {
                    let (dq, dq1) = reference::d_difference(model, &s.q, q1);
                    DifferenceOutput {
                        v: reference::difference(model, &s.q, q1),
                        dq: rows(&dq),
                        dq1: rows(&dq1),
                    }
                }),
            };
            if fm.nfext() + fm.nlambda() > 0 {
                let d = reference::force_derivatives(&fm, &s.q);
                let bodies: Vec<(String, usize)> = fm
                    .specialisation
                    .fext
                    .iter()
                    .map(|&b| (fm.joint_name(b).to_string(), 6))
                    .collect();
                let contacts: Vec<(String, usize)> = fm
                    .specialisation
                    .contacts
                    .iter()
                    .map(|c| (fm.frames[c.frame].name.clone(), c.kind.dim()))
                    .collect();
                let fext_present = !bodies.is_empty();
                let lambda_present = !contacts.is_empty();
                if s.qdd.is_some() {
                    out.drnea_dfext = fext_present.then(|| by_force(&d.dc_dfext, &bodies));
                    out.drnea_dlambda = lambda_present.then(|| by_force(&d.dc_dlambda, &contacts));
                }
                if s.tau.is_some() {
                    out.dfd_dfext = fext_present.then(|| by_force(&d.dqdd_dfext, &bodies));
                    out.dfd_dlambda = lambda_present.then(|| by_force(&d.dqdd_dlambda, &contacts));
                }
            }
            Ok(out)
        })
        .collect::<Result<_, EvalError>>()?;
    Ok(EvalOutput { joint_names: coordinate_names(model), states })
}

/// Results of the Verilog netlists for one state: the keys of [`Output`] that the
/// datapath kernels compute, in f64 (raw · 2^-FRAC), and whether each kernel's netlist
/// raised `overflow` (or an input did not fit its format), in which case its numbers are
/// saturated and wrong.
#[derive(Clone, Debug, Serialize)]
pub struct VerilogOutput {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drnea_dq: Option<Matrix>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drnea_dqd: Option<Matrix>,
    #[serde(rename = "M")]
    pub m: Matrix,
    /// `fd_grad`'s chip partition (`--fd-grad-netlist chip`), on states with `tau`: q̈.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fd: Option<Vec<f64>>,
    /// `fd_grad`'s netlist, on states with `tau`: ∂q̈/∂q and ∂q̈/∂q̇. The host partition
    /// (`--fd-grad-netlist host`) takes the host's q̈ and M⁻¹ (the reference's, in f64);
    /// the chip partition computes them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dfd_dq: Option<Matrix>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dfd_dqd: Option<Matrix>,
    pub overflow: std::collections::BTreeMap<&'static str, bool>,
}

/// Each netlist's kernel, format and architecture, for the JSON's header.
#[derive(Clone, Debug, Serialize)]
pub struct VerilogEvalOutput {
    pub joint_names: Vec<String>,
    pub netlists: Vec<crate::back::verilog::NetlistStats>,
    pub states: Vec<VerilogOutput>,
}

#[derive(Debug, thiserror::Error)]
pub enum VerilogEvalError {
    #[error(transparent)]
    States(#[from] EvalError),
    #[error(transparent)]
    Lower(#[from] crate::ir::LowerError),
    #[error(transparent)]
    Back(#[from] crate::back::verilog::VerilogError),
    #[error(transparent)]
    Sim(#[from] crate::tools::icarus::SimError),
    #[error("state {index}: `tau` acts on the floating base ({value} at entry {entry}); fd_grad's chip partition takes no τ for the unactuated base: give 0 there, or use --fd-grad-netlist host")]
    BaseTau { index: usize, entry: usize, value: f64 },
}

/// Simulates the `rnea_grad` and `mass_matrix` netlists (built with `options`, whose
/// kernel list is ignored) on every state; `rnea_grad` only where `qdd` is given; and
/// `fd_grad`'s host partition where `options` asks for it, on the states with `tau`.
pub fn evaluate_verilog(
    model: &Model,
    file: &StatesFile,
    gravity: [f64; 3],
    options: &crate::back::verilog::VerilogOptions,
) -> Result<VerilogEvalOutput, VerilogEvalError> {
    use crate::back::verilog::{plan, DEFAULT_KERNELS};
    use crate::datapath::quantize_ports;
    use crate::ir::{self, KernelKind, LowerOptions};
    use crate::tools::icarus as sim;
    check_states(model, file)?;
    // The netlists' force ports would read nothing here: refused, as on the other backends.
    if model.nfext() + model.nlambda() > 0 {
        return Err(EvalError::ForcesOnBackend.into());
    }
    let nv = model.nv();
    let mut kernels = DEFAULT_KERNELS.to_vec();
    use crate::back::verilog::FdGradPartition;
    let (host, chip) = match options.fd_grad {
        None => (false, false),
        Some(FdGradPartition::Host) => (true, false),
        Some(FdGradPartition::Chip) => (false, true),
        Some(FdGradPartition::Auto) => (true, true),
    };
    if host && options.minv_max.is_none() {
        // The host partition's bound on M⁻¹ samples the minv kernel.
        kernels.push(KernelKind::Minv);
    }
    if chip {
        // The chip partition's bias forces (and its measurement's τ).
        kernels.push(KernelKind::Rnea);
    }
    let module = ir::lower(model, gravity, &LowerOptions { kernels, ..LowerOptions::default() })?;
    let netlists = plan(
        &module,
        &crate::back::verilog::VerilogOptions {
            kernels: DEFAULT_KERNELS.to_vec(),
            ..options.clone()
        },
    )?;
    // The chip partition takes no τ for a floating base: a wrench there is refused.
    if model.floating && netlists.iter().any(|n| n.measured.is_some()) {
        for (index, s) in file.states.iter().enumerate() {
            let tau = s.tau.as_deref().unwrap_or(&[]);
            if let Some(entry) = tau.iter().take(6).position(|t| *t != 0.0) {
                return Err(VerilogEvalError::BaseTau { index, entry, value: tau[entry] });
            }
        }
    }
    let mut states: Vec<VerilogOutput> = file
        .states
        .iter()
        .map(|_| VerilogOutput {
            drnea_dq: None,
            drnea_dqd: None,
            m: Vec::new(),
            fd: None,
            dfd_dq: None,
            dfd_dqd: None,
            overflow: Default::default(),
        })
        .collect();
    for n in &netlists {
        let chosen: Vec<usize> = (0..file.states.len())
            .filter(|&i| match n.kind {
                KernelKind::RneaGrad => file.states[i].qdd.is_some(),
                KernelKind::FdGrad => file.states[i].tau.is_some(),
                _ => true,
            })
            .collect();
        let mut input_overflow = Vec::new();
        let ports: Vec<Vec<i128>> = chosen
            .iter()
            .map(|&i| {
                let s = &file.states[i];
                let (qdd, rest) = match (n.kind, &s.tau) {
                    // The chip partition takes τ itself.
                    (KernelKind::FdGrad, Some(tau)) if n.measured.is_some() => {
                        (Vec::new(), tau.clone())
                    }
                    // What the host computes: q̈ = FD(q, q̇, τ) and M⁻¹, row-major.
                    (KernelKind::FdGrad, Some(tau)) => (
                        crate::reference::forward_dynamics(model, &s.q, &s.qd, tau, gravity),
                        crate::reference::minv(model, &s.q).transpose().iter().copied().collect(),
                    ),
                    _ => (s.qdd.clone().unwrap_or_else(|| vec![0.0; nv]), Vec::new()),
                };
                let (p, o) = quantize_ports(&n.datapath, &n.format, &s.q, &s.qd, &qdd, &rest);
                input_overflow.push(o);
                p
            })
            .collect();
        let results = sim::simulate(n, &module.robot, &ports)?;
        for ((&i, r), in_o) in chosen.iter().zip(results).zip(input_overflow) {
            // Every entry, structural zeros included, row-major per output.
            let mut outs: Vec<Vec<f64>> =
                n.datapath.outputs.iter().map(|o| vec![0.0; o.ids.len()]).collect();
            for ((o, e, _), raw) in n.datapath.nonzero_outputs().into_iter().zip(&r.outputs) {
                outs[o][e] = n.format.to_f64(*raw);
            }
            let matrix = |v: &[f64]| v.chunks(nv).map(|row| row.to_vec()).collect::<Matrix>();
            let st = &mut states[i];
            match n.kind {
                KernelKind::RneaGrad => {
                    st.drnea_dq = Some(matrix(&outs[0]));
                    st.drnea_dqd = Some(matrix(&outs[1]));
                }
                KernelKind::FdGrad => {
                    // The chip partition's outputs begin with q̈.
                    let at = usize::from(n.measured.is_some());
                    if at == 1 {
                        st.fd = Some(outs[0].clone());
                    }
                    st.dfd_dq = Some(matrix(&outs[at]));
                    st.dfd_dqd = Some(matrix(&outs[at + 1]));
                }
                _ => st.m = matrix(&outs[0]),
            }
            st.overflow.insert(n.kind.name(), r.overflow || in_o);
        }
    }
    Ok(VerilogEvalOutput {
        joint_names: module.robot.joint_names.clone(),
        netlists: netlists.iter().map(|n| n.stats()).collect(),
        states,
    })
}

/// Why [`evaluate_with`] failed: the states, or the backend that ran the kernels.
#[derive(Debug, thiserror::Error)]
pub enum BackendEvalError<E: std::error::Error + 'static> {
    #[error(transparent)]
    States(#[from] EvalError),
    #[error(transparent)]
    Backend(E),
}

/// The JSON of [`evaluate`], with the kernels run by a backend: `run(kind, q, qd, u)`
/// takes state-major inputs (`q[s * nq + j]`, `qd[s * nv + j]`; `u` is q̈ or τ, empty for kernels
/// without it) and returns the kernel's outputs concatenated per state (`out[s * len + k]`,
/// matrices row-major), as the generated kernels lay them out. rnea and rnea_grad run on the states
/// with `qdd`, fd_grad (whose outputs give fd) on those with `tau`.
pub fn evaluate_with<E: std::error::Error + 'static>(
    model: &Model,
    file: &StatesFile,
    mut run: impl FnMut(crate::ir::KernelKind, &[f64], &[f64], &[f64]) -> Result<Vec<f64>, E>,
) -> Result<EvalOutput, BackendEvalError<E>> {
    use crate::ir::KernelKind;
    check_states(model, file)?;
    if model.nfext() + model.nlambda() > 0
        || file.states.iter().any(|s| !s.fext.is_empty() || !s.contacts.is_empty())
    {
        return Err(EvalError::ForcesOnBackend.into());
    }
    let nv = model.nv();
    let matrix = |v: &[f64]| v.chunks(nv.max(1)).map(|r| r.to_vec()).collect::<Matrix>();
    let mut states: Vec<Output> = file
        .states
        .iter()
        .map(|_| Output {
            rnea: None,
            drnea_dq: None,
            drnea_dqd: None,
            m: Vec::new(),
            minv: None,
            fd: None,
            dfd_dq: None,
            dfd_dqd: None,
            frames: None,
            step: None,
            drnea_dfext: None,
            dfd_dfext: None,
            drnea_dlambda: None,
            dfd_dlambda: None,
            contact_fd: None,
            integrate: None,
            difference: None,
        })
        .collect();
    /// The input a kernel takes from a state (q̈ or τ), if the state has it.
    type Pick = dyn Fn(&State) -> Option<&Vec<f64>>;
    let flat = |chosen: &[usize], pick: &Pick| -> Vec<f64> {
        chosen
            .iter()
            .flat_map(|&i| {
                pick(&file.states[i]).map(|v| v.as_slice()).unwrap_or(&[]).iter().copied()
            })
            .collect()
    };
    let all: Vec<usize> = (0..file.states.len()).collect();
    let with_qdd: Vec<usize> =
        all.iter().copied().filter(|&i| file.states[i].qdd.is_some()).collect();
    let with_tau: Vec<usize> =
        all.iter().copied().filter(|&i| file.states[i].tau.is_some()).collect();
    let plan: [(KernelKind, &[usize], &Pick); 5] = [
        (KernelKind::Rnea, &with_qdd, &|s: &State| s.qdd.as_ref()),
        (KernelKind::RneaGrad, &with_qdd, &|s: &State| s.qdd.as_ref()),
        (KernelKind::MassMatrix, &all, &|_: &State| None),
        (KernelKind::Minv, if model.singular.is_some() { &[] } else { &all }, &|_: &State| None),
        (KernelKind::FdGrad, &with_tau, &|s: &State| s.tau.as_ref()),
    ];
    for (kind, chosen, u) in plan {
        if chosen.is_empty() {
            continue;
        }
        let velocity = !matches!(kind, KernelKind::MassMatrix | KernelKind::Minv);
        let q = flat(chosen, &|s: &State| Some(&s.q));
        let qd = if velocity { flat(chosen, &|s: &State| Some(&s.qd)) } else { Vec::new() };
        let out = run(kind, &q, &qd, &flat(chosen, u)).map_err(BackendEvalError::Backend)?;
        let per = out.len() / chosen.len();
        for (k, &i) in chosen.iter().enumerate() {
            let values = &out[k * per..(k + 1) * per];
            let st = &mut states[i];
            let m = nv * nv;
            match kind {
                KernelKind::Rnea => st.rnea = Some(values.to_vec()),
                KernelKind::RneaGrad => {
                    st.drnea_dq = Some(matrix(&values[..m]));
                    st.drnea_dqd = Some(matrix(&values[m..2 * m]));
                }
                KernelKind::MassMatrix => st.m = matrix(values),
                KernelKind::Minv => st.minv = Some(matrix(values)),
                _ => {
                    st.fd = Some(values[..nv].to_vec());
                    st.dfd_dq = Some(matrix(&values[nv..nv + m]));
                    st.dfd_dqd = Some(matrix(&values[nv + m..nv + 2 * m]));
                }
            }
        }
    }
    // The Lie-group kernels: `v` rides in q̇'s place, `q1` in u's.
    let with_v: Vec<usize> = all.iter().copied().filter(|&i| file.states[i].v.is_some()).collect();
    let with_q1: Vec<usize> =
        all.iter().copied().filter(|&i| file.states[i].q1.is_some()).collect();
    for (value, jacobians, chosen) in [
        (KernelKind::Integrate, KernelKind::DIntegrate, &with_v),
        (KernelKind::Difference, KernelKind::DDifference, &with_q1),
    ] {
        if chosen.is_empty() {
            continue;
        }
        let q = flat(chosen, &|s: &State| Some(&s.q));
        let (qd, u) = if value == KernelKind::Integrate {
            (flat(chosen, &|s: &State| s.v.as_ref()), Vec::new())
        } else {
            (Vec::new(), flat(chosen, &|s: &State| s.q1.as_ref()))
        };
        let out = run(value, &q, &qd, &u).map_err(BackendEvalError::Backend)?;
        let d = run(jacobians, &q, &qd, &u).map_err(BackendEvalError::Backend)?;
        let (per, m) = (out.len() / chosen.len(), nv * nv);
        for (k, &i) in chosen.iter().enumerate() {
            let x = out[k * per..(k + 1) * per].to_vec();
            let j = &d[k * 2 * m..(k + 1) * 2 * m];
            let (a, b) = (matrix(&j[..m]), matrix(&j[m..]));
            if value == KernelKind::Integrate {
                states[i].integrate = Some(IntegrateOutput { q_next: x, dq: a, dv: b });
            } else {
                states[i].difference = Some(DifferenceOutput { v: x, dq: a, dq1: b });
            }
        }
    }
    // The frame kernels compute in the model's one reference frame: that key alone.
    let names: Vec<String> = model.selected_frames().map(|f| f.name.clone()).collect();
    let rf = model.specialisation.reference.name();
    let frame_plan: [(KernelKind, &[usize]); 4] = [
        (KernelKind::FramePlacement, &all),
        (KernelKind::FrameJacobian, &all),
        (KernelKind::FrameVelocity, &all),
        (KernelKind::FrameAcceleration, &with_qdd),
    ];
    for (kind, chosen) in frame_plan {
        if names.is_empty() || chosen.is_empty() {
            continue;
        }
        let q = flat(chosen, &|s: &State| Some(&s.q));
        let qd = if kind == KernelKind::FramePlacement || kind == KernelKind::FrameJacobian {
            Vec::new()
        } else {
            flat(chosen, &|s: &State| Some(&s.qd))
        };
        let u = if kind == KernelKind::FrameAcceleration {
            flat(chosen, &|s: &State| s.qdd.as_ref())
        } else {
            Vec::new()
        };
        let out = run(kind, &q, &qd, &u).map_err(BackendEvalError::Backend)?;
        let per = out.len() / chosen.len();
        let nf = names.len();
        for (k, &i) in chosen.iter().enumerate() {
            let values = &out[k * per..(k + 1) * per];
            let frames = states[i].frames.get_or_insert_with(|| {
                names.iter().map(|n| (n.clone(), FrameOutput::default())).collect()
            });
            for (f, name) in names.iter().enumerate() {
                let o = frames.get_mut(name).expect("inserted above");
                match kind {
                    KernelKind::FramePlacement => {
                        o.translation = values[3 * f..3 * f + 3].to_vec();
                        o.rotation = values[3 * nf + 9 * f..3 * nf + 9 * f + 9]
                            .chunks(3)
                            .map(|r| r.to_vec())
                            .collect();
                    }
                    KernelKind::FrameJacobian => {
                        let j = &values[6 * nv * f..6 * nv * (f + 1)];
                        o.jacobian.insert(rf, j.chunks(nv.max(1)).map(|r| r.to_vec()).collect());
                    }
                    KernelKind::FrameVelocity => {
                        o.velocity.insert(rf, values[6 * f..6 * f + 6].to_vec());
                    }
                    _ => {
                        o.classical_acceleration.insert(rf, values[3 * f..3 * f + 3].to_vec());
                    }
                }
            }
        }
    }
    Ok(EvalOutput { joint_names: coordinate_names(model), states })
}
