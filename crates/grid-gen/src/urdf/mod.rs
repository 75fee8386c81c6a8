//! The URDF front end: parse the XML into located raw elements, then check the tree.
//!
//! We read the XML with roxmltree rather than urdf-rs: urdf-rs keeps no source positions
//! and fills missing or malformed values with defaults, and every finding here must point
//! at the element it is about.

mod parse;
mod round;
mod validate;

pub use parse::{Inertial, Joint, JointKind, Link, Mimic, Pose, Urdf};
pub use round::{round_angles, RoundedAngles, MAX_ROUND_ANGLES};
pub use validate::{check_tree, Tree};

use crate::diagnostic::{Diagnostic, LoadError, Severity};

/// Parses and checks a URDF; on success returns it with the tree it describes and any
/// warnings. Never panics, whatever the input.
pub fn load(path: &str, text: &str) -> Result<(Urdf, Tree, Vec<Diagnostic>), LoadError> {
    let fail = |mut diagnostics: Vec<Diagnostic>| {
        // A xacro file is not URDF until xacro expands its macros; say so, whatever broke.
        if path.ends_with(".xacro") || text.contains("xmlns:xacro") {
            diagnostics.push(
                Diagnostic::error(format!("{path} is a xacro file (macros, not URDF)"), None, "xacro is not expanded here")
                    .with_help("expand it first: `xacro robot.urdf.xacro > robot.urdf` (ROS's xacro, or `pip install xacro`)"),
            );
        }
        LoadError { path: path.to_string(), source_text: text.to_string(), diagnostics }
    };
    let (urdf, mut diags) = parse::parse(text);
    let Some(urdf) = urdf else { return Err(fail(diags)) };
    if diags.iter().any(|d| d.severity == Severity::Error) {
        return Err(fail(diags));
    }
    match check_tree(&urdf) {
        Ok(tree) => {
            unknown_mimic_targets(&urdf, &mut diags);
            Ok((urdf, tree, diags))
        }
        Err(more) => {
            diags.extend(more);
            Err(fail(diags))
        }
    }
}

/// A `<mimic>` naming no joint of the robot is a warning, not an error: urdfdom and
/// Pinocchio accept such files (example-robot-data's `alex_psyonic_hands.urdf` is one),
/// and grid-gen models mimic joints as independent joints, so nothing depends on the
/// target.
fn unknown_mimic_targets(urdf: &Urdf, diags: &mut Vec<Diagnostic>) {
    let names: std::collections::HashSet<&str> =
        urdf.joints.iter().map(|j| j.name.as_str()).collect();
    for joint in &urdf.joints {
        let Some(m) = &joint.mimic else { continue };
        if !names.contains(m.joint.as_str()) {
            diags.push(
                Diagnostic::warning(
                    format!("joint `{}` mimics unknown joint `{}`", joint.name, m.joint),
                    Some(m.span.clone()),
                    "the <mimic> names no joint of this robot",
                )
                .with_help(format!(
                    "`{}` is modelled as an independent joint, as urdfdom and Pinocchio do; correct the name in <mimic joint=\"...\"> if it is a typo",
                    joint.name
                )),
            );
        }
    }
}
