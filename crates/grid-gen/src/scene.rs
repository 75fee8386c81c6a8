//! Scene specialisation: what a user's scene fixes about the robot,
//! read from a TOML file and applied while the model is built, so that every kernel of
//! every backend shrinks with it: joints locked at a value (merged as fixed joints, as
//! Pinocchio's `buildReducedModel` does), subtrees kept or dropped, payloads added to
//! links, gravity, and the kernels to generate.
//!
//! ```toml
//! outputs = ["rnea_grad", "fd_grad"]   # kernels to generate (default: all)
//! gravity = [0.0, 0.0, -9.81]          # --gravity replaces it
//! drop = ["left_gripper_base"]         # these links and everything below them go
//! keep = ["right_arm_base"]            # only these subtrees (and the path to them) stay
//!
//! [lock]                               # joint = position (rad or m): becomes fixed
//! torso_joint = 0.0
//!
//! static = true                        # q̇ = 0 is known: kernels ignore `qd`
//! floating_base = true                 # a free-flyer under the root link (--floating-base)
//! mimic = "coupled"                    # <mimic> joints follow their joint (--mimic coupled)
//!
//! [gradient]                           # gradient entries needed (default: all)
//! rows = ["right_s0"]                  # by joint: the rows computed
//! columns = ["right_s0", "right_s1"]   # the columns computed; the rest are written 0
//!
//! [frames]                             # frames the frame kernels compute (link names)
//! names = ["iiwa_link_7"]
//! reference = "local_world_aligned"    # or "local", "world" (Pinocchio's ReferenceFrame)
//!
//! [step]                               # the step kernels: one time step and [A | B]
//! scheme = "semi_implicit_euler"       # or "explicit_euler", "rk4"
//! dt = 0.01                            # s, folded into the kernels; left out, the
//!                                      # step kernels take dt at run time, per state
//!
//! [actuation]                          # the step's tau and B's columns (default: every
//! joints = ["lf_haa_joint"]            # joint but a floating base; multi-dof by name)
//!
//! [fd_grad]
//! minv = true                          # fd_grad also returns dqdd_dtau = M^-1
//!
//! [external_forces]                    # bodies that take a force `fext` (by the name of
//! joints = ["lf_kfe_joint"]            # the joint that moves them; "*" for every body)
//! derivatives = false                  # no d/dfext outputs (default true)
//!
//! [[contact]]                          # a contact force lambda at a frame, in world axes
//! frame = "lf_lowerleg"                # at the frame's origin (LOCAL_WORLD_ALIGNED)
//! type = "point"                       # 3-D force; or "wrench", [force; torque]
//!
//! [[payload]]                          # or [payload] for one
//! link = "right_gripper"
//! mass = 1.5                           # kg
//! com = [0.0, 0.0, 0.1]                # m, in the link frame
//! inertia = [0.01, 0.0, 0.0, 0.01, 0.0, 0.01]   # ixx ixy ixz iyy iyz izz about the com
//! ```

use std::collections::BTreeMap;

use serde::Deserialize;

use crate::diagnostic::Diagnostic;
use crate::ir::KernelKind;
use crate::model::JointIndex;
use crate::model::{Edits, Model, ReferenceFrame, Specialisation};
use crate::urdf::{Inertial, JointKind, Pose, Tree, Urdf};

/// A scene file's contents (see the module documentation for the format).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Who replaced a setting's value from the file, by setting key
    /// ([`crate::settings::SETTINGS`]): what errors name instead of the file.
    #[serde(skip)]
    pub origins: BTreeMap<&'static str, crate::settings::Source>,
    /// Where the file sets each setting, by setting key: the line errors name.
    #[serde(skip)]
    pub lines: Lines,
    /// Joints held at a position: each becomes a fixed joint there.
    #[serde(default)]
    pub lock: BTreeMap<String, f64>,
    /// Links whose subtrees are modelled, with the links on their paths from the root;
    /// every other link is left out. Empty: every link.
    #[serde(default)]
    pub keep: Vec<String>,
    /// Links left out, with everything below them.
    #[serde(default)]
    pub drop: Vec<String>,
    /// Gravity in the root frame, m/s² (`--gravity` and `Builder::gravity` replace it).
    pub gravity: Option<[f64; 3]>,
    /// Rigid bodies added to links.
    #[serde(default, deserialize_with = "one_or_many")]
    pub payload: Vec<Payload>,
    /// The kernels to generate and measure (default: all).
    pub outputs: Option<Vec<String>>,
    /// q̇ = 0 is known (a robot holding still, a statics or quasi-static study): the
    /// velocity terms vanish and every kernel ignores its `qd` argument.
    #[serde(default, rename = "static")]
    pub static_velocity: bool,
    /// Which rows and columns of the gradient matrices are needed.
    #[serde(default)]
    pub gradient: GradientEntries,
    /// A free-flyer between the world and the root link (as `--floating-base`).
    #[serde(default)]
    pub floating_base: bool,
    /// How `<mimic>` joints are modelled (as `--mimic`).
    #[serde(default)]
    pub mimic: MimicMode,
    /// The frames the frame kernels compute (as `--frames`).
    #[serde(default)]
    pub frames: FramesSection,
    /// The discrete step the step kernels take (as `--step` and `--dt`).
    pub step: Option<StepSection>,
    /// The actuated joints: the step's τ and B's columns.
    pub actuation: Option<ActuationSection>,
    /// `fd_grad`'s options.
    #[serde(default)]
    pub fd_grad: FdGradSection,
    /// The bodies that take an external force (the dynamics kernels' `fext`).
    #[serde(default)]
    pub external_forces: ExternalForcesSection,
    /// Contacts at frames (the dynamics kernels' `lambda`), in the order declared.
    #[serde(default)]
    pub contact: Vec<ContactEntry>,
    /// The contacts are candidates: the kernels that solve for their forces (`contact_fd`,
    /// `contact_fd_grad`, `step`, `step_grad`) take `active`, one 0 or 1 per contact and
    /// state, and an inactive contact has λ = 0 and no constraint (as `--contact-mask`).
    #[serde(default)]
    pub contact_mask: bool,
    /// The contacts are stabilised as Pinocchio's Baumgarte corrector (`BaumgarteCorrectorParameters`):
    /// the kernels that solve for their forces take `gains` (Kp, Kd per contact) and
    /// `contact_ref` (a point's world position, a wrench's world placement) at run time (as
    /// `--baumgarte`).
    #[serde(default)]
    pub baumgarte: bool,
    /// Read every `<origin rpy>` angle within this many radians of a multiple of π/2 as
    /// that multiple (`urdf::round_angles`; at most `urdf::MAX_ROUND_ANGLES`). Off by
    /// default: the URDF's numbers are taken as written, as Pinocchio takes them.
    pub round_angles: Option<f64>,
}

/// `[external_forces]`: the bodies that take a spatial force, each named by the joint that
/// moves it, as Pinocchio keys `fext` (`root_joint` for a floating base).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ExternalForcesSection {
    /// Joint names in the order `fext` lists the forces; `"*"` stands for every body.
    #[serde(default)]
    pub joints: Vec<String>,
    /// Whether `rnea_grad` and `fd_grad` return `∂/∂fext` (default true).
    pub derivatives: Option<bool>,
}

/// `[[contact]]`: a contact at a frame.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ContactEntry {
    /// A link name (the frames of `[frames]`), not the fixed root's.
    pub frame: String,
    /// `point` (3-D force) or `wrench` (6-D).
    #[serde(rename = "type")]
    pub kind: crate::model::ContactKind,
}

/// `[fd_grad]`: what `fd_grad` returns besides `(qdd, dqdd_dq, dqdd_dqd)`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FdGradSection {
    /// Also `dqdd_dtau = M⁻¹` (as `--fd-grad-minv`).
    #[serde(default)]
    pub minv: bool,
}

/// `[step]`: the step kernels' scheme and time step.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StepSection {
    /// Default `semi_implicit_euler`.
    pub scheme: Option<crate::model::Scheme>,
    /// Seconds, finite and positive, folded into the kernels; left out, `step` and
    /// `step_grad` take `dt` at run time, one value per state.
    pub dt: Option<f64>,
}

/// `[actuation]`: the joints with a motor.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ActuationSection {
    /// Joint names (a free-flyer's `root_joint` or a spherical joint's own name stands for
    /// all its coordinates), listed in any order; B's columns follow the model's order.
    pub joints: Vec<String>,
}

/// `[frames]`: the links whose placement, Jacobian, velocity and acceleration the frame
/// kernels compute, and the reference frame they are expressed in.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FramesSection {
    /// Link names, in the order the kernels' outputs list them. Empty: no frame kernels.
    #[serde(default)]
    pub names: Vec<String>,
    /// Default `local_world_aligned`.
    pub reference: Option<ReferenceFrame>,
}

/// How `<mimic>` joints are modelled.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum MimicMode {
    /// Each is a joint with its own coordinate, as urdfdom and Pinocchio's default
    /// `buildModelFromUrdf` do: the dynamics are those of the robot without the mimic
    /// constraint, and the caller enforces it.
    #[default]
    Independent,
    /// Each follows its joint, `q_m = multiplier · q + offset`, and has no coordinate
    /// (Pinocchio's `buildModelFromUrdf(..., mimic=True)`): one entry fewer in q, q̇, q̈,
    /// τ and every matrix per mimic joint.
    Coupled,
}

impl MimicMode {
    pub fn name(self) -> &'static str {
        match self {
            MimicMode::Independent => "independent",
            MimicMode::Coupled => "coupled",
        }
    }

    pub fn parse(name: &str) -> Option<MimicMode> {
        [MimicMode::Independent, MimicMode::Coupled].into_iter().find(|m| m.name() == name)
    }
}

/// `[gradient]`: the entries of `dc_dq`, `dc_dqd`, `dqdd_dq` and `dqdd_dqd` a task reads,
/// by joint name; the others are not computed and are written as 0. A row is the output
/// joint (the force or acceleration of that joint), a column the joint differentiated by.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GradientEntries {
    /// Rows computed (default: all).
    pub rows: Option<Vec<String>>,
    /// Columns computed (default: all).
    pub columns: Option<Vec<String>>,
}

/// A rigid body carried by a link.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Payload {
    pub link: String,
    /// kg.
    pub mass: f64,
    /// Centre of mass in the link frame, m.
    #[serde(default)]
    pub com: [f64; 3],
    /// `ixx, ixy, ixz, iyy, iyz, izz` about the centre of mass, link axes, kg·m².
    #[serde(default)]
    pub inertia: [f64; 6],
}

fn one_or_many<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<Payload>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum OneOrMany {
        One(Payload),
        Many(Vec<Payload>),
    }
    Ok(match OneOrMany::deserialize(d)? {
        OneOrMany::One(p) => vec![p],
        OneOrMany::Many(v) => v,
    })
}

/// Top-level keys of a scene file: in TOML they must come before the first `[table]`, or
/// they belong to it.
const TOP_LEVEL: [&str; 7] =
    ["outputs", "gravity", "drop", "keep", "static", "floating_base", "mimic"];

/// When a scene fails to parse: a top-level key written after a table header (`static =
/// true` after `[lock]` reads as a joint to lock), as the reason.
fn misplaced_key(text: &str) -> Option<String> {
    let mut table = None;
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.starts_with('[') {
            table = Some(line.trim_matches(|c| c == '[' || c == ']').trim().to_string());
            continue;
        }
        let key = line.split('=').next().map(str::trim).unwrap_or("");
        if let (Some(t), true) = (&table, line.contains('=') && TOP_LEVEL.contains(&key)) {
            return Some(format!(
                "line {}: `{key}` is a top-level key, but it comes after `[{t}]`, so TOML reads it as part of that table; \
                 move it above the first [table] header",
                n + 1
            ));
        }
    }
    None
}

/// The caller's changes to a scene (command-line flags, `Builder` calls, the Python
/// package's arguments): each value that is set replaces the scene file's. [`Scene::apply`]
/// is the one place they are merged.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneOverrides {
    pub gravity: Option<[f64; 3]>,
    pub floating_base: Option<bool>,
    pub mimic: Option<MimicMode>,
    pub frames: Option<Vec<String>>,
    pub reference_frame: Option<ReferenceFrame>,
    pub scheme: Option<crate::model::Scheme>,
    pub dt: Option<f64>,
    /// Leave the step's dt to run time even where the scene folds one.
    pub runtime_dt: bool,
    pub actuated: Option<Vec<String>>,
    pub fd_grad_minv: Option<bool>,
    pub fext: Option<Vec<String>>,
    pub fext_derivatives: Option<bool>,
    pub contacts: Option<Vec<ContactEntry>>,
    pub round_angles: Option<f64>,
    pub contact_mask: Option<bool>,
    pub baumgarte: Option<bool>,
    /// Who gives these values, for errors ([`crate::settings::Source`]).
    pub source: crate::settings::Source,
}

/// `round_angles` must round off digits, not change the robot.
pub fn check_round_angles(tol: f64) -> Result<(), String> {
    let max = crate::urdf::MAX_ROUND_ANGLES;
    match tol.is_finite() && tol > 0.0 && tol <= max {
        true => Ok(()),
        false => Err(format!(
            "round_angles = {tol} rad: give a tolerance above 0 and at most {max:e} rad (an angle's round-off, single precision at worst)"
        )),
    }
}

/// A scene file that cannot be read.
#[derive(Debug, thiserror::Error)]
#[error("scene `{path}`: {message}")]
pub struct SceneError {
    pub path: String,
    pub message: String,
}

/// The line (from 1) where a scene file sets each setting, by setting key
/// ([`crate::settings::lines`]). Where a key sits is not part of the scene's value: any two
/// compare equal.
#[derive(Clone, Debug, Default)]
pub struct Lines(pub BTreeMap<&'static str, usize>);

impl PartialEq for Lines {
    fn eq(&self, _: &Lines) -> bool {
        true
    }
}

impl Scene {
    /// Parses a scene file's text; `path` names it in errors.
    pub fn parse(path: &str, text: &str) -> Result<Scene, SceneError> {
        let mut scene: Scene = toml::from_str(text).map_err(|e| SceneError {
            path: path.to_string(),
            message: misplaced_key(text).unwrap_or_else(|| e.to_string().trim_end().to_string()),
        })?;
        scene.lines = Lines(crate::settings::lines(text));
        let err = |message: String| Err(SceneError { path: path.to_string(), message });
        if let Some(g) = scene.gravity {
            if g.iter().any(|x| !x.is_finite()) {
                return err(format!("gravity {g:?} is not finite"));
            }
        }
        for (joint, value) in &scene.lock {
            if !value.is_finite() {
                return err(format!("[lock] {joint} = {value} is not finite"));
            }
        }
        for p in &scene.payload {
            let finite =
                p.mass.is_finite() && p.com.iter().chain(&p.inertia).all(|x| x.is_finite());
            if !finite || p.mass < 0.0 {
                return err(format!("payload on `{}`: mass, com and inertia must be finite and the mass not negative", p.link));
            }
        }
        if let Some(tol) = scene.round_angles {
            if let Err(message) = check_round_angles(tol) {
                return err(message);
            }
        }
        scene.kernels().map_err(|message| SceneError { path: path.to_string(), message })?;
        Ok(scene)
    }

    /// The first setting `overrides` gives that this scene sets too: its keyword (as
    /// `grid_gen.load` names it) and what it is, for [`crate::Config::exclusive`].
    pub fn clash(&self, o: &SceneOverrides) -> Option<(&'static str, &'static str)> {
        let both = [
            (
                o.frames.is_some() && !self.frames.names.is_empty(),
                "frames",
                "the frames ([frames] names)",
            ),
            (
                o.contacts.is_some() && !self.contact.is_empty(),
                "contacts",
                "the contacts ([[contact]])",
            ),
            (o.scheme.is_some() && self.step.is_some(), "step", "the step ([step])"),
            (
                o.dt.is_some() && self.step.as_ref().is_some_and(|s| s.dt.is_some()),
                "dt",
                "the step's dt ([step] dt)",
            ),
            (
                o.actuated.is_some() && self.actuation.is_some(),
                "actuated",
                "the actuated joints ([actuation] joints)",
            ),
            (
                o.fext.is_some() && !self.external_forces.joints.is_empty(),
                "external_forces",
                "the bodies that take fext ([external_forces] joints)",
            ),
            (o.contact_mask.is_some() && self.contact_mask, "contact_mask", "contact_mask"),
            (o.baumgarte.is_some() && self.baumgarte, "baumgarte", "baumgarte"),
            (o.gravity.is_some() && self.gravity.is_some(), "gravity", "gravity"),
        ];
        both.into_iter().find(|b| b.0).map(|(_, key, what)| (key, what))
    }

    /// Replaces this scene's values with those `overrides` sets.
    pub fn apply(&mut self, overrides: &SceneOverrides) {
        let o = overrides.clone();
        let given = [
            ("gravity", o.gravity.is_some()),
            ("floating_base", o.floating_base.is_some()),
            ("frames", o.frames.is_some()),
            ("step", o.scheme.is_some()),
            ("dt", o.dt.is_some()),
            ("actuated", o.actuated.is_some()),
            ("external_forces", o.fext.is_some()),
            ("contacts", o.contacts.is_some()),
            ("contact_mask", o.contact_mask.is_some()),
            ("baumgarte", o.baumgarte.is_some()),
            ("round_angles", o.round_angles.is_some()),
        ];
        for (key, _) in given.into_iter().filter(|g| g.1) {
            self.origins.insert(key, o.source.clone());
        }
        self.gravity = o.gravity.or(self.gravity);
        self.floating_base = o.floating_base.unwrap_or(self.floating_base);
        self.mimic = o.mimic.unwrap_or(self.mimic);
        if let Some(names) = o.frames {
            self.frames.names = names;
        }
        self.frames.reference = o.reference_frame.or(self.frames.reference);
        if o.scheme.is_some() || o.dt.is_some() {
            let step = self.step.get_or_insert_with(Default::default);
            step.scheme = o.scheme.or(step.scheme);
            step.dt = if o.runtime_dt { None } else { o.dt.or(step.dt) };
        }
        if let Some(joints) = o.actuated {
            self.actuation = Some(ActuationSection { joints });
        }
        self.fd_grad.minv = o.fd_grad_minv.unwrap_or(self.fd_grad.minv);
        if let Some(joints) = o.fext {
            self.external_forces.joints = joints;
        }
        self.external_forces.derivatives = o.fext_derivatives.or(self.external_forces.derivatives);
        if let Some(contacts) = o.contacts {
            self.contact = contacts;
        }
        self.contact_mask = o.contact_mask.unwrap_or(self.contact_mask);
        self.baumgarte = o.baumgarte.unwrap_or(self.baumgarte);
        self.round_angles = o.round_angles.or(self.round_angles);
    }

    /// The kernels `outputs` names, in generation order; `None` when it names none.
    pub fn kernels(&self) -> Result<Option<Vec<KernelKind>>, String> {
        let Some(names) = &self.outputs else { return Ok(None) };
        let mut kinds = Vec::new();
        for name in names {
            match KernelKind::parse(name) {
                Some(k) => kinds.push(k),
                None => {
                    return Err(format!(
                        "outputs: unknown kernel `{name}`; available: {}",
                        KernelKind::ALL.map(|k| k.name()).join(", ")
                    ))
                }
            }
        }
        Ok(Some(KernelKind::ALL.into_iter().filter(|k| kinds.contains(k)).collect()))
    }

    /// Whether the scene sets nothing (who set what is not a setting).
    pub fn is_empty(&self) -> bool {
        Scene { origins: BTreeMap::new(), ..self.clone() } == Scene::default()
    }

    /// How an error names setting `key` of this scene, read from `path` (empty: no file).
    pub fn whence(&self, key: &str, path: &str) -> String {
        let line = self.lines.0.get(key).copied();
        crate::settings::whence(key, path, self.origins.get(key), line)
    }
}

/// Checks every name the scene uses against the URDF and resolves them; a name the robot
/// does not have is an error naming the scene file, the key and what exists.
pub(crate) fn resolve(
    scene: &Scene,
    scene_path: &str,
    urdf: &Urdf,
    tree: &Tree,
    diags: &mut Vec<Diagnostic>,
) -> Edits {
    let mut edits = Edits::none(urdf);
    let link_index = |name: &str| urdf.links.iter().position(|l| l.name == name);
    let some_names = |names: Vec<&str>| {
        let shown: Vec<&str> = names.iter().take(12).copied().collect();
        format!("{}{}", shown.join(", "), if names.len() > 12 { ", ..." } else { "" })
    };
    let unknown_link = |key: &str, name: &str| {
        Diagnostic::error(
            format!(
                "scene `{scene_path}`: {key} names link `{name}`, which robot `{}` does not have",
                urdf.name
            ),
            None,
            "unknown link",
        )
        .with_help(format!(
            "links: {}",
            some_names(urdf.links.iter().map(|l| l.name.as_str()).collect())
        ))
    };
    for (name, &value) in &scene.lock {
        match urdf.joints.iter().position(|j| &j.name == name) {
            None => diags.push(
                Diagnostic::error(
                    format!("scene `{scene_path}`: [lock] names joint `{name}`, which robot `{}` does not have", urdf.name),
                    None,
                    "unknown joint",
                )
                .with_help(format!(
                    "movable joints: {}",
                    some_names(urdf.joints.iter().filter(|j| j.kind != JointKind::Fixed).map(|j| j.name.as_str()).collect())
                )),
            ),
            Some(j) if urdf.joints[j].kind == JointKind::Fixed => diags.push(Diagnostic::warning(
                format!("scene `{scene_path}`: [lock] names `{name}`, which is fixed already"),
                Some(urdf.joints[j].span.clone()),
                "already fixed",
            )),
            Some(j) if urdf.joints[j].kind == JointKind::Floating => diags.push(
                Diagnostic::error(
                    format!("scene `{scene_path}`: [lock] names floating joint `{name}`"),
                    Some(urdf.joints[j].span.clone()),
                    "a floating joint cannot be locked at one value",
                )
                .with_help("to model the robot with a fixed base, make the joint fixed in the URDF"),
            ),
            Some(j) if urdf.joints[j].kind == JointKind::Spherical => diags.push(
                Diagnostic::error(
                    format!("scene `{scene_path}`: [lock] names spherical joint `{name}`"),
                    Some(urdf.joints[j].span.clone()),
                    "a spherical joint cannot be locked at one value",
                )
                .with_help("to hold it, make the joint fixed in the URDF with the rotation in its <origin rpy>"),
            ),
            Some(j) => {
                let joint = &urdf.joints[j];
                if let (Some((lo, hi)), false) = (joint.limit, joint.kind == JointKind::Continuous) {
                    if value < lo || value > hi {
                        diags.push(Diagnostic::warning(
                            format!("scene `{scene_path}`: [lock] holds `{name}` at {value}, outside its limits [{lo}, {hi}]"),
                            Some(joint.span.clone()),
                            "locked outside the limits",
                        ));
                    }
                }
                edits.locked[j] = Some(value);
            }
        }
    }
    // The parent link of each link, for the paths that `keep` retains.
    let mut parent_link = vec![None; urdf.links.len()];
    for &(p, c) in &tree.joint_links {
        parent_link[c] = Some(p);
    }
    let subtree = |root: usize, mark: &mut Vec<bool>| {
        let mut stack = vec![root];
        while let Some(l) = stack.pop() {
            mark[l] = true;
            stack.extend(tree.child_joints[l].iter().map(|&j| tree.joint_links[j].1));
        }
    };
    if !scene.keep.is_empty() {
        let mut kept = vec![false; urdf.links.len()];
        for name in &scene.keep {
            match link_index(name) {
                None => diags.push(unknown_link("keep", name)),
                Some(l) => {
                    subtree(l, &mut kept);
                    let mut up = parent_link[l];
                    while let Some(p) = up {
                        kept[p] = true;
                        up = parent_link[p];
                    }
                }
            }
        }
        edits.dropped = kept.iter().map(|k| !k).collect();
    }
    for name in &scene.drop {
        match link_index(name) {
            None => diags.push(unknown_link("drop", name)),
            Some(l) if l == tree.root => diags.push(
                Diagnostic::error(format!("scene `{scene_path}`: drop names the root link `{name}`, which would leave no robot"), None, "root link dropped")
                    .with_help("drop the links below it instead"),
            ),
            Some(l) => subtree(l, &mut edits.dropped),
        }
    }
    for p in &scene.payload {
        match link_index(&p.link) {
            None => diags.push(unknown_link("payload", &p.link)),
            Some(l) => {
                if l == tree.root {
                    diags.push(Diagnostic::warning(
                        format!("scene `{scene_path}`: the payload on `{}` sits on the fixed root link and changes no dynamics", p.link),
                        None,
                        "payload on the root",
                    ));
                }
                let span = urdf.links[l].span.clone();
                let inertial = Inertial {
                    span: span.clone(),
                    origin: Pose { xyz: p.com, rpy: [0.0; 3] },
                    mass: p.mass,
                    mass_span: span.clone(),
                    inertia: p.inertia,
                    inertia_span: span,
                };
                edits.payload[l].push(inertial);
            }
        }
    }
    edits
}

/// Resolves the scene's facts about the state and the outputs against the built model
/// (whose joints are what remains after the locks, keeps and drops): a `[gradient]` joint
/// that is not one of the model's movable joints is an error naming it and why.
pub(crate) fn specialise(
    scene: &Scene,
    scene_path: &str,
    urdf: &Urdf,
    model: &Model,
    diags: &mut Vec<Diagnostic>,
) -> Specialisation {
    let mut resolve = |key: &str, names: &Option<Vec<String>>| -> Option<Vec<usize>> {
        let names = names.as_ref()?;
        let mut picked = Vec::new();
        for name in names {
            match model.joints.iter().position(|j| &j.name == name) {
                Some(i) if model.coupling(i).is_none() => picked.push(model.coordinate_of(JointIndex(i)).0),
                Some(i) => diags.push(
                    Diagnostic::error(
                        format!("scene `{scene_path}`: [gradient] {key} names `{name}`, a coupled mimic joint"),
                        None,
                        "a coupled mimic joint has no coordinate",
                    )
                    .with_help(format!("name the joint it follows, `{}`", model.joints[model.coupling(i).map_or(i, |c| c.of)].name)),
                ),
                None => {
                    let why = if scene.lock.contains_key(name) {
                        "locked by the scene's [lock]".to_string()
                    } else if let Some(j) = urdf.joints.iter().find(|j| &j.name == name) {
                        if j.kind == JointKind::Fixed {
                            "a fixed joint".to_string()
                        } else if j.kind == JointKind::Spherical {
                            format!("a spherical joint: name its coordinates `{name}_wx`, `{name}_wy`, `{name}_wz`")
                        } else {
                            "left out by the scene's keep or drop".to_string()
                        }
                    } else {
                        format!("not a joint of robot `{}`", urdf.name)
                    };
                    diags.push(
                        Diagnostic::error(format!("scene `{scene_path}`: [gradient] {key} names `{name}`, which is {why}"), None, "not a movable joint")
                            .with_help(format!(
                                "movable joints of the scene's model: {}",
                                model.coordinate_joints().iter().map(|&i| model.joint(i).name.as_str()).collect::<Vec<_>>().join(", ")
                            )),
                    );
                }
            }
        }
        picked.sort_unstable();
        picked.dedup();
        Some(picked)
    };
    let rows = resolve("rows", &scene.gradient.rows);
    let columns = resolve("columns", &scene.gradient.columns);
    let frames = select_frames(scene, scene_path, urdf, model, diags);
    let step = select_step(scene, scene_path, diags);
    let actuated = scene
        .actuation
        .as_ref()
        .map(|a| select_actuated(&a.joints, &scene.whence("actuated", scene_path), model, diags));
    let fext_whence = scene.whence("external_forces", scene_path);
    let fext = select_fext(&scene.external_forces.joints, &fext_whence, model, diags);
    let contacts = select_contacts(scene, scene_path, urdf, model, diags);
    if scene.contact_mask && contacts.is_empty() {
        let whence = scene.whence("contact_mask", scene_path);
        diags.push(
            Diagnostic::error(
                format!("{whence} without contacts: there is nothing to mask"),
                None,
                "no contacts",
            )
            .with_help("declare the candidate contacts with [[contact]] or --contact FRAME:point"),
        );
    }
    let whence = |key: &str, _flag: &str| scene.whence(key, scene_path);
    if scene.baumgarte && contacts.is_empty() {
        diags.push(
            Diagnostic::error(
                format!(
                    "{} without contacts: there is nothing to stabilise",
                    whence("baumgarte", "--baumgarte")
                ),
                None,
                "no contacts",
            )
            .with_help("declare the contacts with [[contact]] or --contact FRAME:point"),
        );
    }
    Specialisation {
        static_velocity: scene.static_velocity,
        rows,
        columns,
        frames,
        reference: scene.frames.reference.unwrap_or_default(),
        step,
        actuated,
        fd_grad_minv: scene.fd_grad.minv,
        fext,
        no_fext_derivatives: !scene.external_forces.derivatives.unwrap_or(true),
        contacts,
        contact_mask: scene.contact_mask,
        baumgarte: scene.baumgarte,
    }
}

/// `[external_forces] joints` (or `--fext`): each name is a joint as Pinocchio names
/// it (a multi-dof joint by its own name), or `*` for every body; an unknown or repeated
/// name is an error that lists the closest names.
fn select_fext(
    names: &[String],
    whence: &str,
    model: &Model,
    diags: &mut Vec<Diagnostic>,
) -> Vec<usize> {
    let known = model.body_joint_names();
    let mut picked = Vec::new();
    for name in names {
        if name == "*" {
            picked = known.iter().filter_map(|n| model.body_of_joint(n)).collect();
            if names.len() > 1 {
                diags.push(
                    Diagnostic::error(
                        format!("{whence}: `*` names every body, so no other name may follow it"),
                        None,
                        "`*` with names",
                    )
                    .with_help("give `*` alone, or the names"),
                );
            }
            break;
        }
        match model.body_of_joint(name) {
            Some(b) if picked.contains(&b) => diags.push(
                Diagnostic::error(
                    format!("{whence} names joint `{name}` twice"),
                    None,
                    "duplicate joint",
                )
                .with_help("name each joint once"),
            ),
            Some(b) => picked.push(b),
            None => {
                let mut by_distance: Vec<(usize, &str)> =
                    known.iter().map(|k| (strsim::levenshtein(name, k), *k)).collect();
                by_distance.sort();
                let closest: Vec<&str> = by_distance.iter().take(5).map(|(_, k)| *k).collect();
                diags.push(
                    Diagnostic::error(format!("{whence} names `{name}`, which is no joint of the model that moves a body"), None, "unknown joint")
                        .with_help(format!("closest joints: {}", closest.join(", "))),
                );
            }
        }
    }
    picked
}

/// `[[contact]]` (or `--contact FRAME:TYPE`): each frame must be a frame of a moving body,
/// named once.
fn select_contacts(
    scene: &Scene,
    scene_path: &str,
    urdf: &Urdf,
    model: &Model,
    diags: &mut Vec<Diagnostic>,
) -> Vec<crate::model::Contact> {
    let whence = scene.whence("contacts", scene_path);
    let mut picked: Vec<crate::model::Contact> = Vec::new();
    for entry in &scene.contact {
        let name = &entry.frame;
        let Some(frame) = model.frame(name) else {
            diags.push(unknown_frame(name, &whence, scene, urdf, model));
            continue;
        };
        if model.frames[frame].body.is_none() {
            diags.push(
                Diagnostic::error(
                    format!("{whence} puts a contact on `{name}`, which is fixed to the world: a force there moves nothing"),
                    None,
                    "contact on the fixed root",
                )
                .with_help("put contacts on frames of moving bodies"),
            );
        } else if picked.iter().any(|c| c.frame == frame) {
            diags.push(
                Diagnostic::error(
                    format!("{whence} declares a contact at `{name}` twice"),
                    None,
                    "duplicate contact",
                )
                .with_help("one contact per frame; a wrench holds both force and torque"),
            );
        } else {
            picked.push(crate::model::Contact { frame, kind: entry.kind });
        }
    }
    if let Err(set) = crate::reference::check_contact_rank(model, &picked) {
        let names: Vec<String> =
            set.iter().map(|&i| format!("`{}`", model.frames[picked[i].frame].name)).collect();
        diags.push(
            Diagnostic::error(
                format!(
                    "{whence}: the contacts at {} constrain dependent motions (their stacked Jacobian loses rank at every configuration tried), so contact dynamics has no unique contact force",
                    names.join(", ")
                ),
                None,
                "dependent contacts",
            )
            .with_help("drop one of them or make it a point contact: two wrenches on one body, or on bodies one joint apart, fix the same motion"),
        );
    }
    picked
}

/// `[step]` (or `--step`, `--dt`): a scheme and a finite, positive time step, or none (then
/// the kernels take it at run time).
fn select_step(
    scene: &Scene,
    scene_path: &str,
    diags: &mut Vec<Diagnostic>,
) -> Option<crate::model::StepSpec> {
    let s = scene.step.as_ref()?;
    let whence = scene.whence("step", scene_path);
    let scheme = s.scheme.unwrap_or_default();
    let dt = s.dt;
    if let Some(dt) = dt.filter(|dt| !(dt.is_finite() && *dt > 0.0)) {
        diags.push(
            Diagnostic::error(
                format!(
                    "{}: dt = {dt} is not a finite, positive number of seconds",
                    scene.whence("dt", scene_path)
                ),
                None,
                "bad dt",
            )
            .with_help("a time step such as `dt = 0.01`"),
        );
        return None;
    }
    if scene.static_velocity {
        diags.push(
            Diagnostic::error(format!("{whence} with `static = true`: a step moves the robot, so q̇ is not known to be 0"), None, "step in a static scene")
                .with_help("drop `static = true` or the step"),
        );
        return None;
    }
    // No dt: the step kernels take it at run time.
    Some(crate::model::StepSpec { scheme, dt })
}

/// `[actuation] joints`: each name is a coordinate's joint, or a multi-dof joint's own name
/// for all its coordinates; an unknown or repeated name is an error.
fn select_actuated(
    names: &[String],
    whence: &str,
    model: &Model,
    diags: &mut Vec<Diagnostic>,
) -> Vec<usize> {
    let coordinates = model.coordinate_joints();
    let mut picked = Vec::new();
    for name in names {
        let found: Vec<usize> = coordinates
            .iter()
            .enumerate()
            .filter(|(_, &JointIndex(j))| {
                model.joints[j].name == *name
                    || (model.group(j).is_some() && model.joint_name(j) == name)
            })
            .map(|(k, _)| k)
            .collect();
        if found.is_empty() {
            let mut known: Vec<&str> =
                coordinates.iter().map(|&JointIndex(j)| model.joint_name(j)).collect();
            known.dedup();
            let mut by_distance: Vec<(usize, &str)> =
                known.iter().map(|k| (strsim::levenshtein(name, k), *k)).collect();
            by_distance.sort();
            let closest: Vec<&str> = by_distance.iter().take(5).map(|(_, k)| *k).collect();
            diags.push(
                Diagnostic::error(
                    format!("{whence} names `{name}`, which is not a movable joint of the model"),
                    None,
                    "unknown joint",
                )
                .with_help(format!("closest joints: {}", closest.join(", "))),
            );
        } else if found.iter().any(|k| picked.contains(k)) {
            diags.push(
                Diagnostic::error(
                    format!("{whence} names joint `{name}` twice"),
                    None,
                    "duplicate joint",
                )
                .with_help("name each joint once"),
            );
        } else {
            picked.extend(found);
        }
    }
    picked.sort_unstable();
    picked
}

/// Resolves `[frames] names` (or `--frames`) against the model's frames: an unknown name
/// is an error that lists the closest link names, a link the scene removed one that says
/// which scene entry removed it.
fn select_frames(
    scene: &Scene,
    scene_path: &str,
    urdf: &Urdf,
    model: &Model,
    diags: &mut Vec<Diagnostic>,
) -> Vec<usize> {
    let mut picked = Vec::new();
    let whence = scene.whence("frames", scene_path);
    for name in &scene.frames.names {
        if let Some(f) = model.frame(name) {
            if picked.contains(&f) {
                diags.push(
                    Diagnostic::error(
                        format!("{whence} names frame `{name}` twice"),
                        None,
                        "duplicate frame",
                    )
                    .with_help("name each frame once"),
                );
            }
            picked.push(f);
            continue;
        }
        diags.push(unknown_frame(name, &whence, scene, urdf, model));
    }
    picked
}

/// The error for a frame name that is not one of the model's frames: a link the scene
/// removed (and by which entry), a joint's name, or no link at all, with the closest names.
fn unknown_frame(
    name: &str,
    whence: &str,
    scene: &Scene,
    urdf: &Urdf,
    model: &Model,
) -> Diagnostic {
    let message = match urdf.links.iter().position(|l| l.name == name) {
        Some(l) => {
            let by = if scene.drop.iter().any(|d| removes(urdf, d, l)) {
                format!(
                    "`drop = [..., \"{}\"]`",
                    scene.drop.iter().find(|d| removes(urdf, d, l)).expect("found above")
                )
            } else {
                "`keep`, which does not keep it".to_string()
            };
            format!("{whence} names link `{name}`, which the scene removes (by {by})")
        }
        None => {
            let joint = urdf.joints.iter().any(|j| j.name == name);
            let what = if joint {
                "a joint, not a link: frames are link names"
            } else {
                "not a link of this robot"
            };
            format!("{whence} names `{name}`, which is {what}")
        }
    };
    Diagnostic::error(message, None, "unknown frame")
        .with_help(format!("closest frames: {}", closest(name, model)))
}

/// Whether dropping link `dropped` removes link `l` (it is `l` or an ancestor of it).
fn removes(urdf: &Urdf, dropped: &str, l: usize) -> bool {
    let mut at = Some(l);
    while let Some(x) = at {
        if urdf.links[x].name == dropped {
            return true;
        }
        at = urdf
            .joints
            .iter()
            .find(|j| j.child == urdf.links[x].name)
            .and_then(|j| urdf.links.iter().position(|k| k.name == j.parent));
    }
    false
}

/// The model's five frame names nearest to `name` by edit distance.
fn closest(name: &str, model: &Model) -> String {
    let mut names: Vec<(usize, &str)> = model
        .frames
        .iter()
        .map(|f| (strsim::levenshtein(name, &f.name), f.name.as_str()))
        .collect();
    names.sort();
    names.iter().take(5).map(|(_, n)| *n).collect::<Vec<_>>().join(", ")
}
