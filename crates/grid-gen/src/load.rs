//! Loading a robot: URDF text to a checked [`Model`], with every diagnostic. This is
//! the one place that runs the reference dynamics during loading (the massless-joint
//! check), so that `model` does not depend on `reference` (which depends on `model`).

use crate::diagnostic::{Diagnostic, LoadError, Severity};
use crate::model::JointIndex;
use crate::model::{build, Model};
use crate::scene::{self, Scene};
use crate::urdf::{self, Urdf};

impl Model {
    /// Parses, checks and builds the model from URDF text. Warnings come back with the
    /// model; with `strict`, a warning is an error.
    pub fn from_urdf_str(
        path: &str,
        text: &str,
        strict: bool,
    ) -> Result<(Model, Vec<Diagnostic>), LoadError> {
        Model::from_urdf_str_in_scene(path, text, strict, &Scene::default(), "")
    }

    /// As [`Model::from_urdf_str`], with `scene` (read from `scene_path`) applied: locked
    /// joints merged as fixed, subtrees kept or dropped, payloads added. A name the scene
    /// uses that the URDF lacks is an error.
    pub fn from_urdf_str_in_scene(
        path: &str,
        text: &str,
        strict: bool,
        scene: &Scene,
        scene_path: &str,
    ) -> Result<(Model, Vec<Diagnostic>), LoadError> {
        let (mut urdf, tree, mut diags) = urdf::load(path, text)?;
        let rounded = scene.round_angles.map(|tol| urdf::round_angles(&mut urdf, tol));
        let edits = scene::resolve(scene, scene_path, &urdf, &tree, &mut diags);
        let built = build(
            &urdf,
            &tree,
            &edits,
            scene.floating_base,
            scene.mimic == crate::scene::MimicMode::Coupled,
            &mut diags,
        )
        .map(|(mut model, source)| {
            model.singular = check_massless(&model, &source, &urdf, &mut diags);
            model.rounded_angles = rounded;
            model.specialisation = scene::specialise(scene, scene_path, &urdf, &model, &mut diags);
            let file_name = |p: &str| {
                std::path::Path::new(p)
                    .file_name()
                    .map(|f| f.to_string_lossy().into_owned())
                    .unwrap_or_default()
            };
            model.source = file_name(path);
            // Generated files name their scene too: the same robot in another scene is
            // another model, and `write_files` must not let one overwrite the other.
            if !scene.is_empty() && !scene_path.is_empty() {
                model.source = format!("{} in scene {}", model.source, file_name(scene_path));
            }
            model
        });
        let failed = diags
            .iter()
            .any(|d| d.severity == Severity::Error || (strict && d.severity == Severity::Warning));
        match built {
            Some(model) if !failed => Ok((model, diags)),
            _ => {
                if strict {
                    for d in &mut diags {
                        d.severity = Severity::Error;
                    }
                }
                Err(LoadError {
                    path: path.to_string(),
                    source_text: text.to_string(),
                    diagnostics: diags,
                })
            }
        }
    }
}

/// Every movable joint must move some inertia, or M is singular: M_ii = S_iᵀ Ic_i S_i > 0,
/// with Ic_i the composite inertia of its subtree (checked at q = 0 with the reference CRBA).
/// A joint that does not is a warning (example-robot-data's `romeo.urdf` has one): RNEA,
/// its gradient and M are still right. Returns the first such joint's name.
fn check_massless(
    model: &Model,
    source: &[Option<usize>],
    urdf: &Urdf,
    diags: &mut Vec<Diagnostic>,
) -> Option<String> {
    let mut singular = None;
    let n = model.nv();
    let m = crate::reference::crba(model, &model.neutral_q());
    let scale = (0..n).map(|i| m[(i, i)]).fold(0.0, f64::max);
    let mut mass: Vec<f64> = model.joints.iter().map(|j| j.inertia.mass).collect();
    for i in (0..model.njoints()).rev() {
        if let Some(p) = model.joints[i].parent {
            mass[p] += mass[i];
        }
        // A coupled mimic joint's inertia is in its coordinate's M_kk.
        if model.coupling(i).is_some() {
            continue;
        }
        let k = model.coordinate_of(JointIndex(i)).0;
        // Relative to M's largest diagonal entry, so a small robot is not a singular one:
        // below n·ε of it, M_ii is rounding noise at M's scale, cond(M) ≥ max M_jj / M_ii
        // exceeds 1/(n·ε), and no double-precision factorisation of M is meaningful.
        if m[(k, k)] <= n as f64 * f64::EPSILON * scale {
            let Some(uj) = source[i].map(|j| &urdf.joints[j]) else {
                // `--floating-base`'s free-flyer: the whole robot is massless.
                if singular.is_none() {
                    diags.push(
                        Diagnostic::warning(format!("the floating base `{}` moves no inertia", model.joints[i].name), None, "the mass matrix is singular")
                            .with_help("give the robot's links <inertial> elements with positive mass; until then minv, fd and fd_grad are not generated"),
                    );
                    singular = Some(model.joints[i].name.clone());
                }
                continue;
            };
            let child = &uj.child;
            let (message, help) = if mass[i] <= 0.0 {
                (
                    format!("joint `{}` moves only massless links (`{child}` and below)", uj.name),
                    format!("give `{child}` or a link below it an <inertial> with positive mass, or make the joint fixed"),
                )
            } else {
                (
                    format!("joint `{}` moves no inertia about its axis", uj.name),
                    format!("the links from `{child}` down have their mass on the axis and no rotational inertia; give them an <inertia>"),
                )
            };
            let help = format!("{help}; until then rnea, rnea_grad and mass_matrix are generated, and minv, fd and fd_grad (which need M⁻¹) are not");
            diags.push(
                Diagnostic::warning(message, Some(uj.span.clone()), "the mass matrix is singular")
                    .with_help(help),
            );
            singular = Some(uj.name.clone());
        }
    }
    singular
}
