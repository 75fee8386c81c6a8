//! XML to raw URDF elements, each with the byte range it came from.

use std::ops::Range;

use roxmltree::{Document, Node};

use crate::diagnostic::Diagnostic;

/// An `<origin>`: translation, then roll-pitch-yaw (URDF: R = Rz(yaw) Ry(pitch) Rx(roll)).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose {
    pub xyz: [f64; 3],
    pub rpy: [f64; 3],
}

#[derive(Clone, Debug, PartialEq)]
pub struct Inertial {
    pub span: Range<usize>,
    pub origin: Pose,
    pub mass: f64,
    pub mass_span: Range<usize>,
    /// ixx, ixy, ixz, iyy, iyz, izz about the centre of mass, in the `<origin>` frame.
    pub inertia: [f64; 6],
    pub inertia_span: Range<usize>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Link {
    pub name: String,
    pub span: Range<usize>,
    pub inertial: Option<Inertial>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    Revolute,
    Continuous,
    Prismatic,
    Fixed,
    /// Six degrees of freedom: only between the root link and the base (a floating base).
    Floating,
    /// Three rotational degrees of freedom about the joint origin: not in the
    /// URDF specification (urdfdom rejects it), a grid-gen extension with the conventions
    /// of Pinocchio's `JointModelSpherical` (a quaternion in q, the angular velocity in
    /// the child frame in q̇). `<axis>` and `<limit>` are ignored.
    Spherical,
}

impl JointKind {
    pub fn as_str(self) -> &'static str {
        match self {
            JointKind::Revolute => "revolute",
            JointKind::Continuous => "continuous",
            JointKind::Prismatic => "prismatic",
            JointKind::Fixed => "fixed",
            JointKind::Floating => "floating",
            JointKind::Spherical => "spherical",
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Mimic {
    pub joint: String,
    /// The `<mimic>` element.
    pub span: Range<usize>,
    pub multiplier: f64,
    pub offset: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Joint {
    pub name: String,
    pub span: Range<usize>,
    pub kind: JointKind,
    pub parent: String,
    pub parent_span: Range<usize>,
    pub child: String,
    pub child_span: Range<usize>,
    pub origin: Pose,
    /// As written (URDF default (1, 0, 0)); normalised by the model.
    pub axis: [f64; 3],
    pub axis_span: Range<usize>,
    pub limit: Option<(f64, f64)>,
    /// `<limit velocity>` when positive (URDF writes 0 for "not given" in practice).
    pub velocity: Option<f64>,
    pub damping: f64,
    pub friction: f64,
    pub mimic: Option<Mimic>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Urdf {
    pub name: String,
    pub span: Range<usize>,
    pub links: Vec<Link>,
    pub joints: Vec<Joint>,
}

/// Byte offset of a 1-based row/column reported by roxmltree (column counts characters).
fn offset_of(text: &str, row: u32, col: u32) -> usize {
    let mut offset = 0;
    for (i, line) in text.split_inclusive('\n').enumerate() {
        if i + 1 == row as usize {
            return offset
                + line
                    .char_indices()
                    .nth(col.saturating_sub(1) as usize)
                    .map_or(line.len(), |(b, _)| b);
        }
        offset += line.len();
    }
    text.len()
}

/// The start tag of an element: diagnostics show it rather than the whole subtree.
fn tag_span(node: Node) -> Range<usize> {
    let r = node.range();
    let end = node.first_child().map_or(r.end, |c| c.range().start);
    r.start..end.max(r.start)
}

struct Parser {
    diags: Vec<Diagnostic>,
}

impl Parser {
    fn attr_span(node: Node, name: &str) -> Range<usize> {
        node.attribute_node(name).map_or_else(|| tag_span(node), |a| a.range())
    }

    fn required<'n>(&mut self, node: Node<'n, 'n>, name: &str) -> Option<&'n str> {
        let v = node.attribute(name);
        if v.is_none() {
            let tag = node.tag_name().name();
            self.diags.push(
                Diagnostic::error(
                    format!("<{tag}> has no `{name}` attribute"),
                    Some(tag_span(node)),
                    format!("`{name}` is required here"),
                )
                .with_help(format!("add {name}=\"...\" to this <{tag}>")),
            );
        }
        v
    }

    /// Parses `count` whitespace-separated finite numbers from an attribute.
    fn numbers<const N: usize>(
        &mut self,
        node: Node,
        name: &str,
        default: Option<[f64; N]>,
    ) -> Option<[f64; N]> {
        let tag = node.tag_name().name();
        let Some(raw) = node.attribute(name) else {
            if default.is_none() {
                self.required(node, name);
            }
            return default;
        };
        let span = Self::attr_span(node, name);
        let parts: Vec<&str> = raw.split_whitespace().collect();
        if parts.len() != N {
            let what = if N == 1 { "one number".to_string() } else { format!("{N} numbers") };
            self.diags.push(
                Diagnostic::error(
                    format!("<{tag}> attribute `{name}` needs {what}, found {}", parts.len()),
                    Some(span),
                    format!("`{raw}`"),
                )
                .with_help(format!("write {what} separated by spaces")),
            );
            return None;
        }
        let mut out = [0.0; N];
        for (slot, part) in out.iter_mut().zip(&parts) {
            match part.parse::<f64>() {
                Ok(v) if v.is_finite() => *slot = v,
                Ok(_) => {
                    self.diags.push(
                        Diagnostic::error(
                            format!("<{tag}> attribute `{name}` is not finite"),
                            Some(span),
                            format!("`{part}` is not a finite number"),
                        )
                        .with_help("every number in a URDF must be finite"),
                    );
                    return None;
                }
                Err(_) => {
                    self.diags.push(
                        Diagnostic::error(
                            format!("<{tag}> attribute `{name}` is not a number"),
                            Some(span),
                            format!("`{part}` is not a number"),
                        )
                        .with_help("write a decimal number such as 0.25 or 1e-3"),
                    );
                    return None;
                }
            }
        }
        Some(out)
    }

    fn pose(&mut self, parent: Node) -> Pose {
        let Some(origin) = child(parent, "origin") else { return Pose::default() };
        let xyz = self.numbers::<3>(origin, "xyz", Some([0.0; 3])).unwrap_or_default();
        let rpy = self.numbers::<3>(origin, "rpy", Some([0.0; 3])).unwrap_or_default();
        Pose { xyz, rpy }
    }

    fn link(&mut self, node: Node) -> Option<Link> {
        let name = self.required(node, "name")?.to_string();
        let inertial = child(node, "inertial").and_then(|n| self.inertial(n));
        Some(Link { name, span: tag_span(node), inertial })
    }

    fn inertial(&mut self, node: Node) -> Option<Inertial> {
        let origin = self.pose(node);
        let mass_node = self.required_child(node, "mass")?;
        let [mass] = self.numbers::<1>(mass_node, "value", None)?;
        let inertia_node = self.required_child(node, "inertia")?;
        let mut inertia = [0.0; 6];
        let mut ok = true;
        for (slot, name) in inertia.iter_mut().zip(["ixx", "ixy", "ixz", "iyy", "iyz", "izz"]) {
            match self.numbers::<1>(inertia_node, name, None) {
                Some([v]) => *slot = v,
                None => ok = false,
            }
        }
        ok.then(|| Inertial {
            span: tag_span(node),
            origin,
            mass,
            mass_span: tag_span(mass_node),
            inertia,
            inertia_span: tag_span(inertia_node),
        })
    }

    fn required_child<'n>(&mut self, node: Node<'n, 'n>, name: &str) -> Option<Node<'n, 'n>> {
        let c = child(node, name);
        if c.is_none() {
            let tag = node.tag_name().name();
            self.diags.push(
                Diagnostic::error(
                    format!("<{tag}> has no <{name}>"),
                    Some(tag_span(node)),
                    format!("<{name}> is required inside <{tag}>"),
                )
                .with_help(format!("add a <{name}> element")),
            );
        }
        c
    }

    fn joint(&mut self, node: Node) -> Option<Joint> {
        let name = self.required(node, "name")?.to_string();
        let ty = self.required(node, "type")?;
        let span = tag_span(node);
        let kind = match ty {
            "revolute" => JointKind::Revolute,
            "continuous" => JointKind::Continuous,
            "prismatic" => JointKind::Prismatic,
            "fixed" => JointKind::Fixed,
            "floating" => JointKind::Floating,
            "spherical" => JointKind::Spherical,
            "planar" => {
                self.diags.push(
                    Diagnostic::error(
                        format!("joint `{name}` has type `{ty}`, which is not supported"),
                        Some(Self::attr_span(node, "type")),
                        "unsupported joint type",
                    )
                    .with_help("supported joint types are revolute, continuous, prismatic, fixed, floating (at the root) and spherical"),
                );
                return None;
            }
            other => {
                self.diags.push(
                    Diagnostic::error(format!("joint `{name}` has unknown type `{other}`"), Some(Self::attr_span(node, "type")), "not a URDF joint type")
                        .with_help("supported joint types are revolute, continuous, prismatic, fixed, floating (at the root) and spherical"),
                );
                return None;
            }
        };
        let parent_node = self.required_child(node, "parent");
        let child_node = self.required_child(node, "child");
        let (parent_node, child_node) = (parent_node?, child_node?);
        let parent = self.required(parent_node, "link")?.to_string();
        let child_name = self.required(child_node, "link")?.to_string();
        let origin = self.pose(node);
        let axis_node = child(node, "axis");
        let axis = match axis_node {
            Some(a) => self.numbers::<3>(a, "xyz", Some([1.0, 0.0, 0.0]))?,
            None => [1.0, 0.0, 0.0],
        };
        let axis_span = axis_node.map_or(span.clone(), |a| Self::attr_span(a, "xyz"));
        let (limit, velocity) = match child(node, "limit") {
            Some(l) => {
                let lo = self.numbers::<1>(l, "lower", Some([0.0]))?[0];
                let hi = self.numbers::<1>(l, "upper", Some([0.0]))?[0];
                let v = self.numbers::<1>(l, "velocity", Some([0.0]))?[0];
                (Some((lo, hi)), (v > 0.0).then_some(v))
            }
            None => (None, None),
        };
        let (damping, friction) = match child(node, "dynamics") {
            Some(d) => (
                self.numbers::<1>(d, "damping", Some([0.0]))?[0],
                self.numbers::<1>(d, "friction", Some([0.0]))?[0],
            ),
            None => (0.0, 0.0),
        };
        let mimic = match child(node, "mimic") {
            Some(m) => Some(Mimic {
                joint: self.required(m, "joint")?.to_string(),
                span: tag_span(m),
                multiplier: self.numbers::<1>(m, "multiplier", Some([1.0]))?[0],
                offset: self.numbers::<1>(m, "offset", Some([0.0]))?[0],
            }),
            None => None,
        };
        Some(Joint {
            name,
            span,
            kind,
            parent,
            parent_span: tag_span(parent_node),
            child: child_name,
            child_span: tag_span(child_node),
            origin,
            axis,
            axis_span,
            limit,
            velocity,
            damping,
            friction,
            mimic,
        })
    }
}

fn child<'a>(node: Node<'a, 'a>, name: &str) -> Option<Node<'a, 'a>> {
    node.children().find(|c| c.is_element() && c.tag_name().name() == name)
}

/// Parses the XML. Returns the robot (when its outline could be read) and every finding.
pub(crate) fn parse(text: &str) -> (Option<Urdf>, Vec<Diagnostic>) {
    let doc = match Document::parse(text) {
        Ok(doc) => doc,
        Err(e) => {
            let pos = e.pos();
            let at = offset_of(text, pos.row, pos.col);
            let span = at..(at + 1).min(text.len()).max(at);
            return (
                None,
                vec![Diagnostic::error(
                    format!("malformed XML: {e}"),
                    Some(span),
                    "the XML parser stopped here",
                )
                .with_help("fix the XML syntax; a URDF is one <robot> element")],
            );
        }
    };
    let root = doc.root_element();
    let mut p = Parser { diags: Vec::new() };
    if root.tag_name().name() != "robot" {
        p.diags.push(
            Diagnostic::error(
                format!("the root element is <{}>, not <robot>", root.tag_name().name()),
                Some(tag_span(root)),
                "expected <robot>",
            )
            .with_help("a URDF file holds one <robot name=\"...\"> element"),
        );
        return (None, p.diags);
    }
    let name = p.required(root, "name").unwrap_or("robot").to_string();
    let mut links = Vec::new();
    let mut joints = Vec::new();
    for node in root.children().filter(|c| c.is_element()) {
        match node.tag_name().name() {
            "link" => links.extend(p.link(node)),
            "joint" => joints.extend(p.joint(node)),
            _ => {}
        }
    }
    (Some(Urdf { name, span: tag_span(root), links, joints }), p.diags)
}
