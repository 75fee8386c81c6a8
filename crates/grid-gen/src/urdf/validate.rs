//! Structural checks on the parsed URDF: names resolve, every link has one parent, one
//! root, no cycles.

use std::collections::HashMap;

use super::parse::Urdf;
use crate::diagnostic::Diagnostic;

/// The kinematic tree of a checked URDF, by indices into `Urdf::links` / `Urdf::joints`.
#[derive(Clone, Debug)]
pub struct Tree {
    pub root: usize,
    /// For each link, the joint whose child it is (None for the root).
    pub parent_joint: Vec<Option<usize>>,
    /// For each link, the joints whose parent it is, in document order.
    pub child_joints: Vec<Vec<usize>>,
    /// For each joint, (parent link, child link).
    pub joint_links: Vec<(usize, usize)>,
}

/// Checks the tree structure, collecting every error found.
pub fn check_tree(urdf: &Urdf) -> Result<Tree, Vec<Diagnostic>> {
    let mut diags = Vec::new();
    if urdf.links.is_empty() {
        diags.push(
            Diagnostic::error(
                format!("robot `{}` has no links", urdf.name),
                Some(urdf.span.clone()),
                "no <link> inside",
            )
            .with_help("add at least one <link name=\"...\">"),
        );
        return Err(diags);
    }
    let mut link_index: HashMap<&str, usize> = HashMap::new();
    for (i, link) in urdf.links.iter().enumerate() {
        if link_index.contains_key(link.name.as_str()) {
            diags.push(
                Diagnostic::error(
                    format!("duplicate link name `{}`", link.name),
                    Some(link.span.clone()),
                    "a second link with this name",
                )
                .with_help("give every <link> a unique name"),
            );
        } else {
            link_index.insert(&link.name, i);
        }
    }
    let mut joint_names: HashMap<&str, usize> = HashMap::new();
    for (i, joint) in urdf.joints.iter().enumerate() {
        if joint_names.insert(&joint.name, i).is_some() {
            diags.push(
                Diagnostic::error(
                    format!("duplicate joint name `{}`", joint.name),
                    Some(joint.span.clone()),
                    "a second joint with this name",
                )
                .with_help("give every <joint> a unique name"),
            );
        }
    }
    let n = urdf.links.len();
    let mut parent_joint: Vec<Option<usize>> = vec![None; n];
    let mut child_joints = vec![Vec::new(); n];
    let mut joint_links = Vec::with_capacity(urdf.joints.len());
    for (j, joint) in urdf.joints.iter().enumerate() {
        let parent = link_index.get(joint.parent.as_str()).copied();
        let child = link_index.get(joint.child.as_str()).copied();
        if parent.is_none() {
            diags.push(
                Diagnostic::error(
                    format!("joint `{}` names unknown parent link `{}`", joint.name, joint.parent),
                    Some(joint.parent_span.clone()),
                    format!("no <link name=\"{}\"> in this robot", joint.parent),
                )
                .with_help("correct the name or add the missing <link>"),
            );
        }
        if child.is_none() {
            diags.push(
                Diagnostic::error(
                    format!("joint `{}` names unknown child link `{}`", joint.name, joint.child),
                    Some(joint.child_span.clone()),
                    format!("no <link name=\"{}\"> in this robot", joint.child),
                )
                .with_help("correct the name or add the missing <link>"),
            );
        }
        let (Some(p), Some(c)) = (parent, child) else {
            joint_links.push((usize::MAX, usize::MAX));
            continue;
        };
        if let Some(other) = parent_joint[c] {
            diags.push(
                Diagnostic::error(
                    format!("link `{}` has two parents", joint.child),
                    Some(joint.child_span.clone()),
                    format!("joint `{}` already makes `{}` its child", urdf.joints[other].name, joint.child),
                )
                .with_help("a URDF is a tree: each link may be the child of one joint only (closed loops are not supported)"),
            );
        } else {
            parent_joint[c] = Some(j);
            child_joints[p].push(j);
        }
        joint_links.push((p, c));
    }
    if !diags.is_empty() {
        return Err(diags);
    }
    let roots: Vec<usize> = (0..n).filter(|&l| parent_joint[l].is_none()).collect();
    match roots.len() {
        0 => {
            let j = &urdf.joints[0];
            diags.push(
                Diagnostic::error(
                    "the robot has no root link: every link is some joint's child",
                    Some(j.span.clone()),
                    "part of a cycle",
                )
                .with_help("a URDF is a tree: remove the joint that closes the loop"),
            );
            return Err(diags);
        }
        1 => {}
        _ => {
            let names: Vec<String> =
                roots.iter().map(|&r| format!("`{}`", urdf.links[r].name)).collect();
            diags.push(
                Diagnostic::error(
                    format!("the robot has {} root links: {}", roots.len(), names.join(", ")),
                    Some(urdf.links[roots[1]].span.clone()),
                    "this link is not connected to the first root",
                )
                .with_help(
                    "connect every link to one tree with joints (a URDF has exactly one root link)",
                ),
            );
            return Err(diags);
        }
    }
    let root = roots[0];
    let mut reached = vec![false; n];
    let mut stack = vec![root];
    while let Some(l) = stack.pop() {
        reached[l] = true;
        stack.extend(child_joints[l].iter().map(|&j| joint_links[j].1));
    }
    if let Some(l) = (0..n).find(|&l| !reached[l]) {
        let j = parent_joint[l].expect("non-root links have a parent joint");
        diags.push(
            Diagnostic::error(
                format!("joints form a cycle through link `{}`", urdf.links[l].name),
                Some(urdf.joints[j].span.clone()),
                "this joint is part of the cycle",
            )
            .with_help("a URDF is a tree: remove the joint that closes the loop"),
        );
        return Err(diags);
    }
    Ok(Tree { root, parent_joint, child_joints, joint_links })
}
