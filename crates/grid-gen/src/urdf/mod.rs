//! The URDF front end: parse the XML into located raw elements, then check the tree.
//!
//! We read the XML with roxmltree rather than urdf-rs: urdf-rs keeps no source positions
//! and fills missing or malformed values with defaults, and every finding here must point
//! at the element it is about.

mod parse;
mod validate;

pub use parse::{Inertial, Joint, JointKind, Link, Mimic, Pose, Urdf};
pub use validate::{check_tree, Tree};

use crate::diagnostic::{Diagnostic, LoadError, Severity};

/// Parses and checks a URDF; on success returns it with the tree it describes and any
/// warnings. Never panics, whatever the input.
pub fn load(path: &str, text: &str) -> Result<(Urdf, Tree, Vec<Diagnostic>), LoadError> {
    let fail = |diagnostics: Vec<Diagnostic>| LoadError { path: path.to_string(), source_text: text.to_string(), diagnostics };
    let (urdf, mut diags) = parse::parse(text);
    let Some(urdf) = urdf else { return Err(fail(diags)) };
    if diags.iter().any(|d| d.severity == Severity::Error) {
        return Err(fail(diags));
    }
    match check_tree(&urdf) {
        Ok(tree) => Ok((urdf, tree, diags)),
        Err(more) => {
            diags.extend(more);
            Err(fail(diags))
        }
    }
}
