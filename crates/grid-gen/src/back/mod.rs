//! Backends: each reads an [`ir::Module`](crate::ir::Module) (and the shared namer) and
//! returns its own files, headers included. Adding a target is one folder here and one
//! variant of [`Target`].

pub mod c;
pub mod names;
pub mod rust;
pub mod verilog;
pub mod wgsl;

/// Starts the header line that names the URDF file a generated file came from;
/// the generator's `write_files` reads it back so that two robots sharing a name never
/// silently overwrite each other's files in one folder.
pub const SOURCE_PREFIX: &str = "// source: ";

/// The header line naming `source` (the URDF's file name, escaped like every name in a
/// comment), or nothing when the model has no file.
pub fn source_line(source: &str) -> String {
    if source.is_empty() {
        String::new()
    } else {
        format!("{SOURCE_PREFIX}{}\n", names::comment_text(source))
    }
}

/// The attribute that compiles an item only with the Cargo feature `feature` (a kernel's
/// name, or `common`: [`rust::RustOptions::kernel_features`]), with its line break.
pub fn feature_gate(feature: &str) -> String {
    format!("#[cfg(feature = \"{feature}\")]\n")
}

/// Header comment lines saying what the scene fixes (empty when nothing): a user reading
/// the file must see that `qd` is ignored or that some gradient entries are written 0.
pub fn specialisation_lines(robot: &crate::ir::Robot) -> String {
    let spec = &robot.specialisation;
    let mut out = String::new();
    if let Some(r) = &robot.rounded_angles {
        out.push_str(&format!(
            "// Right angles: the scene's {r};\n\
             // so this robot differs from the URDF as written, and the outputs from its, by about that.\n"
        ));
    }
    if robot.floating {
        out.push_str(&format!(
            "// Floating base (Pinocchio's free-flyer): q = [x, y, z, qx, qy, qz, qw, joints 6..] ({} entries; the quaternion is\n\
             // normalised); joints 0-5 are the base's linear and angular velocity in its own frame; gradients are\n\
             // with respect to the tangent space at q, the base first.\n",
            robot.nq()
        ));
    }
    if !robot.spherical.is_empty() {
        let joints: Vec<String> = robot
            .spherical
            .iter()
            .map(|s| {
                let at = s.q_start;
                format!("{} at q[{at}..{}]", names::comment_text(&s.name), at + 4)
            })
            .collect();
        out.push_str(&format!(
            "// Spherical joints (Pinocchio's JointModelSpherical), each a quaternion [qx, qy, qz, qw] in q (normalised): {}.\n\
             // Each has three coordinates <name>_wx, _wy, _wz, its angular velocity in its own frame; gradients are with\n\
             // respect to the tangent space at q. q has {} entries.\n",
            joints.join(", "),
            robot.nq()
        ));
    }
    if !robot.frames.is_empty() {
        let frames: Vec<String> = robot.frames.iter().map(|n| names::comment_text(n)).collect();
        out.push_str(&format!(
            "// Frames (URDF links), in the order of every frame output ([.; NF]): {}. Jacobians (6 x nv, rows\n\
             // [linear; angular]), velocities ([linear; angular]) and classical accelerations in {} (Pinocchio's\n\
             // ReferenceFrame); rotations row-major, the frame's axes in world coordinates.\n",
            frames.join(", "),
            robot.reference.name().to_uppercase()
        ));
    }
    if !robot.coupled.is_empty() {
        let coupled: Vec<String> = robot
            .coupled
            .iter()
            .map(|c| {
                format!(
                    "{} = {:?} * {} + {:?}",
                    names::comment_text(&c.joint),
                    c.multiplier,
                    names::comment_text(&c.follows),
                    c.offset
                )
            })
            .collect();
        out.push_str(&format!(
            "// Coupled mimic joints (no coordinate of their own; q, qd, qdd, tau and the matrices leave them out): {}.\n\
             // minv, fd and fd_grad project the tree's M^-1 and articulated-body qdd onto the mimic constraints.\n",
            coupled.join(", ")
        ));
    }
    if spec.static_velocity {
        out.push_str("// Static scene: qd = 0 is assumed, the velocity terms are compiled out and every `qd` argument is ignored.\n");
    }
    let names = |set: &Option<Vec<usize>>| match set {
        None => "all".to_string(),
        Some(v) => v
            .iter()
            .map(|&j| names::comment_text(&robot.joint_names[j]))
            .collect::<Vec<_>>()
            .join(", "),
    };
    if spec.selects() {
        out.push_str(&format!(
            "// Gradient entries computed (the scene's [gradient]): rows {}; columns {}. Every other entry of dc_dq, dc_dqd, dqdd_dq and dqdd_dqd is written 0.\n",
            names(&spec.rows),
            names(&spec.columns)
        ));
    }
    out
}

/// The source named in a generated file's header, if it has one.
pub fn source_of(contents: &str) -> Option<&str> {
    contents.lines().take(16).find_map(|l| l.strip_prefix(SOURCE_PREFIX))
}

/// One output file: a name (no folders) and its contents.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GeneratedFile {
    pub name: String,
    pub contents: String,
}

/// The targets grid-gen can emit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Target {
    Rust,
    Wgsl,
    Verilog,
    /// The batch entry points and C ABI (`<robot>_c.rs`) and their header (`<robot>.h`).
    C,
}

impl Target {
    pub const ALL: [Target; 4] = [Target::Rust, Target::Wgsl, Target::Verilog, Target::C];

    /// The name used by `--backend`.
    pub fn name(self) -> &'static str {
        match self {
            Target::Rust => "rust",
            Target::Wgsl => "wgsl",
            Target::Verilog => "verilog",
            Target::C => "c",
        }
    }

    pub fn parse(s: &str) -> Option<Target> {
        Target::ALL.into_iter().find(|t| t.name() == s)
    }

    /// The file a target writes for the file stem `stem` (Verilog writes one per module:
    /// `<robot>_<kernel>.v` and its testbench `<robot>_<kernel>_tb.v`).
    pub fn file_name(self, stem: &str) -> String {
        match self {
            Target::Rust => format!("{stem}.rs"),
            Target::Wgsl => format!("{stem}.wgsl"),
            Target::Verilog => format!("{stem}.v"),
            Target::C => format!("{stem}_c.rs"),
        }
    }
}

/// Why a backend could not print a module: each backend's own error.
#[derive(Debug, thiserror::Error)]
pub enum BackError {
    #[error(transparent)]
    Rust(#[from] rust::RustError),
    #[error(transparent)]
    Wgsl(#[from] wgsl::WgslError),
    #[error(transparent)]
    Verilog(#[from] verilog::VerilogError),
    #[error(transparent)]
    C(#[from] c::CError),
}
