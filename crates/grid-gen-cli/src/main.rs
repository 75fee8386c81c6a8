//! The `grid-gen` command line: argument parsing, diagnostic rendering and exit codes.
//! All the work is in the `grid-gen` library.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};
use codespan_reporting::diagnostic::{Diagnostic as Report, Label};
use codespan_reporting::files::SimpleFile;
use codespan_reporting::term::{self, termcolor};
use grid_gen::info::Info;
use grid_gen::{Diagnostic, Model, Severity};

/// Generates robot-specific rigid-body dynamics and their analytical gradients from a URDF.
///
/// `grid-gen ROBOT.urdf -o DIR` writes the generated code into DIR (one `<robot>.rs`
/// module by default); `grid-gen ROBOT.urdf` prints a summary of the model. Both are
/// short for `grid-gen generate ...`. Options shown here apply to every command.
#[derive(Parser)]
#[command(
    name = "grid-gen",
    version,
    subcommand_required = true,
    arg_required_else_help = true,
    override_usage = "grid-gen [OPTIONS] <ROBOT.urdf> [-o DIR]    (same as `grid-gen generate ...`)\n       grid-gen [OPTIONS] <COMMAND>"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    #[command(flatten)]
    load: LoadArgs,
    #[command(flatten)]
    verilog: VerilogArgs,
    #[command(flatten)]
    wgsl: WgslArgs,
}

/// What the generated kernels compute with: shared by `generate` and `info`, so the
/// summary counts the operations of the code that would be written.
#[derive(clap::Args, Clone)]
struct KernelArgs {
    /// Gravity in the root frame, m/s², compiled into the generated code.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_gravity, default_value = "0,0,-9.81", allow_hyphen_values = true)]
    gravity: [f64; 3],
    /// How to build the RNEA gradient (rnea_grad, fd_grad): `idsva` (Singh, Russell &
    /// Wensing 2022), `columns` (Carpentier & Mansard 2018), or `auto`, the one with fewer
    /// operations for this robot (`info` says which).
    #[arg(long, value_name = "FORM", default_value = "auto", value_parser = ["auto", "columns", "idsva"])]
    gradient: String,
}

impl KernelArgs {
    fn gradient(&self) -> grid_gen::ir::Gradient {
        grid_gen::ir::Gradient::parse(&self.gradient).unwrap_or(grid_gen::ir::Gradient::Auto)
    }
}

/// The WGSL kernels' options (`--emit wgsl`, `eval --backend wgsl`, `bench`).
#[derive(clap::Args, Clone)]
struct WgslArgs {
    /// WGSL strategy: thread (one invocation per state), cooperative (one workgroup per
    /// state), or both (emit both entry points; eval runs thread, bench times both).
    #[arg(long, value_name = "S", default_value = "both", value_parser = ["thread", "cooperative", "both"], global = true)]
    wgsl_strategy: String,
    /// WGSL float type: f32 (every adapter) or f64 (adapters with SHADER_F64).
    #[arg(long, value_name = "P", default_value = "f32", value_parser = ["f32", "f64"], global = true)]
    precision: String,
    /// WGSL sin/cos: accurate (in-kernel reduction and polynomial, ~1 ulp) or builtin
    /// (WGSL's, accuracy up to the implementation; f32 only).
    #[arg(long, value_name = "T", default_value = "accurate", value_parser = ["accurate", "builtin"], global = true)]
    wgsl_trig: String,
    /// WGSL cooperative strategy: invocations per state (1 to 256).
    #[arg(long, value_name = "W", default_value_t = 64, global = true)]
    wgsl_workers: u32,
    /// WGSL thread strategy: most operations per dispatch; a larger kernel runs as several
    /// entry points (stages) in order, so no driver compiles more in one pipeline (0: no
    /// split).
    #[arg(long, value_name = "OPS", default_value_t = grid_gen::back::wgsl::DEFAULT_STAGE, global = true)]
    wgsl_stage: usize,
}

impl WgslArgs {
    fn options(&self) -> grid_gen::back::wgsl::WgslOptions {
        use grid_gen::back::wgsl::{Precision, Strategy, Trig, WgslOptions};
        let strategies = match self.wgsl_strategy.as_str() {
            "both" => Strategy::ALL.to_vec(),
            s => vec![Strategy::parse(s).unwrap_or(Strategy::Thread)],
        };
        WgslOptions {
            strategies,
            precision: Precision::parse(&self.precision).unwrap_or(Precision::F32),
            trig: Trig::parse(&self.wgsl_trig).unwrap_or(Trig::Accurate),
            workers: self.wgsl_workers,
            stage: self.wgsl_stage,
            ..WgslOptions::default()
        }
    }
}

/// The fixed-point datapath's options (`--emit verilog`, `eval --backend verilog`).
#[derive(clap::Args, Clone)]
struct VerilogArgs {
    /// Verilog number format: `WIDTH.FRAC` (signed, e.g. 32.16), or `auto` for the
    /// narrowest format whose analysed error meets --max-error.
    #[arg(long, value_name = "WIDTH.FRAC|auto", default_value = "auto", global = true)]
    fixed: String,
    /// With --fixed auto: the largest absolute error allowed on any output entry.
    #[arg(long, value_name = "E", default_value_t = grid_gen::back::verilog::DEFAULT_MAX_ERROR, global = true)]
    max_error: f64,
    /// How multipliers drop fraction bits: truncate (robomorphic's choice) or half-up.
    #[arg(long, value_name = "MODE", default_value = "half-up", value_parser = parse_rounding, global = true)]
    rounding: grid_gen::ir::fixed::Rounding,
    /// Datapath architecture: pipelined (one state per clock) or shared (M multipliers,
    /// A adders, list-scheduled).
    #[arg(long, value_name = "ARCH", default_value = "pipelined", value_parser = ["pipelined", "shared"], global = true)]
    arch: String,
    /// Pipelined: levels of dependence depth between pipeline registers.
    #[arg(long, value_name = "K", default_value_t = grid_gen::back::verilog::DEFAULT_STAGE_DEPTH, global = true)]
    stage_depth: u32,
    /// Shared: number of multipliers.
    #[arg(long, value_name = "M", default_value_t = grid_gen::back::verilog::DEFAULT_MULTIPLIERS, global = true)]
    multipliers: usize,
    /// Shared: number of adders.
    #[arg(long, value_name = "A", default_value_t = grid_gen::back::verilog::DEFAULT_ADDERS, global = true)]
    adders: usize,
    /// Speed bound of every joint for the range analysis (default: the URDF's
    /// `<limit velocity>`, else 10).
    #[arg(long, value_name = "V", global = true)]
    qd_max: Option<f64>,
    /// Acceleration bound of every joint for the range analysis (default 100).
    #[arg(long, value_name = "A", global = true)]
    qdd_max: Option<f64>,
    /// Bound on every entry of fext and lambda for the range analysis (N, N m; default 1e4).
    #[arg(long, value_name = "F", global = true)]
    force_max: Option<f64>,
}

fn parse_rounding(s: &str) -> Result<grid_gen::ir::fixed::Rounding, String> {
    grid_gen::ir::fixed::Rounding::parse(s)
        .ok_or_else(|| format!("unknown rounding `{s}`; available: truncate, half-up"))
}

impl VerilogArgs {
    fn options(&self) -> Result<grid_gen::back::verilog::VerilogOptions, String> {
        use grid_gen::back::verilog::{Arch, FormatChoice, VerilogOptions};
        let format = if self.fixed == "auto" {
            FormatChoice::Auto { max_error: self.max_error }
        } else {
            match grid_gen::ir::fixed::Format::parse(&self.fixed, self.rounding) {
                Some(Ok(f)) => FormatChoice::Fixed { width: f.width, frac: f.frac },
                Some(Err(e)) => return Err(format!("--fixed: {e}")),
                None => {
                    return Err(format!(
                        "--fixed: expected WIDTH.FRAC such as 32.16, or auto; found `{}`",
                        self.fixed
                    ))
                }
            }
        };
        for (name, v) in [
            ("--qd-max", self.qd_max),
            ("--qdd-max", self.qdd_max),
            ("--force-max", self.force_max),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("{name} must be a positive finite number, got {v}"));
                }
            }
        }
        let arch = match self.arch.as_str() {
            "shared" => Arch::Shared { multipliers: self.multipliers, adders: self.adders },
            _ => Arch::Pipelined { stage_depth: self.stage_depth },
        };
        Ok(VerilogOptions {
            format,
            rounding: self.rounding,
            arch,
            qd_max: self.qd_max,
            qdd_max: self.qdd_max,
            force_max: self.force_max,
            ..VerilogOptions::default()
        })
    }
}

fn parse_target(s: &str) -> Result<grid_gen::generate::Target, String> {
    grid_gen::generate::Target::parse(s).ok_or_else(|| {
        format!(
            "unknown backend `{s}`; available: {}",
            grid_gen::generate::Target::ALL.map(|t| t.name()).join(", ")
        )
    })
}

#[derive(clap::Args)]
struct LoadArgs {
    /// Treat warnings (such as physically implausible inertias) as errors.
    #[arg(long, global = true)]
    strict: bool,
    /// A scene file (TOML): joints to lock, links to keep or drop, payloads, gravity, the
    /// kernels to generate; applied to the model for every command (the book, Scenes).
    #[arg(long, value_name = "SCENE.toml", global = true)]
    scene: Option<PathBuf>,
    /// Put a free-flyer between the world and the root link (Pinocchio's conventions:
    /// q = [x, y, z, qx, qy, qz, qw, joints...], velocities and gradients in the base frame).
    #[arg(long, global = true)]
    floating_base: bool,
    /// How <mimic> joints are modelled: `independent` (the default, as urdfdom and
    /// Pinocchio's default) or `coupled` (q_m = multiplier * q + offset, no coordinate of
    /// their own; Pinocchio's mimic=True).
    #[arg(long, value_name = "MODE", global = true, value_parser = parse_mimic)]
    mimic: Option<grid_gen::MimicMode>,
    /// Frames (URDF link names, comma-separated) whose placement, Jacobian, velocity and
    /// classical acceleration the frame kernels compute and `eval` reports; replaces the
    /// scene's `[frames] names`.
    #[arg(long, value_name = "LINK,...", value_delimiter = ',', global = true)]
    frames: Vec<String>,
    /// The frame kernels' reference frame (Pinocchio's ReferenceFrame): local, world or
    /// local_world_aligned (the default).
    #[arg(long, value_name = "RF", global = true, value_parser = parse_reference_frame)]
    reference_frame: Option<grid_gen::model::ReferenceFrame>,
    /// Generate the step kernels (`step`, `step_grad`) and have `eval` report each state's
    /// next state and [A | B]: semi_implicit_euler (Crocoddyl's default), explicit_euler or
    /// rk4; replaces the scene's `[step] scheme`. Needs a time step (--dt).
    #[arg(long, value_name = "SCHEME", global = true, value_parser = parse_scheme)]
    step: Option<grid_gen::model::Scheme>,
    /// The step's time step in seconds (folded into the kernels); replaces `[step] dt`.
    #[arg(long, value_name = "SECONDS", global = true)]
    dt: Option<f64>,
    /// `fd_grad` also returns `dqdd_dtau` = M^-1 (the scene's `[fd_grad] minv = true`).
    #[arg(long, global = true)]
    fd_grad_minv: bool,
    /// Bodies that take an external force `fext` in rnea, rnea_grad, fd and fd_grad (and,
    /// held constant, in the contact and step kernels), by the name of the joint that moves them (Pinocchio's names: `root_joint` for a floating
    /// base), comma-separated, or `*` for every body; replaces `[external_forces] joints`.
    #[arg(long, value_name = "JOINT,...", value_delimiter = ',', global = true)]
    fext: Vec<String>,
    /// rnea_grad and fd_grad do not return d/dfext (the scene's `[external_forces]
    /// derivatives = false`): the forces cost only their own work.
    #[arg(long, global = true)]
    no_fext_derivatives: bool,
    /// Contacts whose forces lambda those kernels take, in world axes at the frame's
    /// origin: FRAME:point (3-D force) or FRAME:wrench (6-D), comma-separated; the contact
    /// and step kernels hold them rigid and solve for lambda. Replaces the scene's `[[contact]]`.
    #[arg(long, value_name = "FRAME:TYPE,...", value_delimiter = ',', global = true, value_parser = parse_contact)]
    contact: Vec<grid_gen::ContactEntry>,
}

fn parse_contact(s: &str) -> Result<grid_gen::ContactEntry, String> {
    let (frame, kind) = s
        .rsplit_once(':')
        .ok_or_else(|| format!("`{s}`: write a contact as FRAME:point or FRAME:wrench"))?;
    let kind = grid_gen::model::ContactKind::parse(kind)
        .ok_or_else(|| format!("`{s}`: unknown contact type `{kind}`; available: point, wrench"))?;
    Ok(grid_gen::ContactEntry { frame: frame.to_string(), kind })
}

fn parse_scheme(s: &str) -> Result<grid_gen::model::Scheme, String> {
    grid_gen::model::Scheme::parse(s).ok_or_else(|| {
        format!("unknown step scheme `{s}`; available: semi_implicit_euler, explicit_euler, rk4")
    })
}

fn parse_reference_frame(s: &str) -> Result<grid_gen::model::ReferenceFrame, String> {
    grid_gen::model::ReferenceFrame::parse(s).ok_or_else(|| {
        format!("unknown reference frame `{s}`; available: local, world, local_world_aligned")
    })
}

fn parse_mimic(s: &str) -> Result<grid_gen::MimicMode, String> {
    grid_gen::MimicMode::parse(s)
        .ok_or_else(|| format!("unknown mimic mode `{s}`; available: independent, coupled"))
}

#[derive(Subcommand)]
enum Command {
    /// Write the generated code into -o DIR, or print the model's summary without -o (the
    /// default command: `grid-gen ROBOT.urdf ...` runs it).
    Generate {
        /// The robot description.
        #[arg(value_name = "ROBOT.urdf")]
        urdf: PathBuf,
        /// Folder to write the generated files into (created if needed).
        #[arg(short = 'o', long = "out", value_name = "DIR")]
        out: Option<PathBuf>,
        /// Backends to emit, comma-separated (available: rust, wgsl, verilog, c; c writes the
        /// batch entry points and C ABI `<robot>_c.rs` and the header `<robot>.h`).
        #[arg(long, value_name = "LIST", value_delimiter = ',', default_value = "rust", value_parser = parse_target)]
        emit: Vec<grid_gen::generate::Target>,
        /// Write nothing; exit 1 if any file would change (for CI freshness checks).
        #[arg(long, requires = "out")]
        check: bool,
        /// Also emit the Rust module's `avx512` copy, run first on CPUs with AVX-512 F and VL
        /// (half again the module's size and compile time; results bit-identical to the
        /// `fma` copy; the book, Speed).
        #[arg(long)]
        avx512: bool,
        #[command(flatten)]
        kernel: KernelArgs,
    },
    /// Print the model: joint order, types, parents, tree levels, gradient sparsity,
    /// operations per kernel, Verilog netlist sizes.
    Info {
        /// The robot description.
        #[arg(value_name = "ROBOT.urdf")]
        urdf: PathBuf,
        /// Print stable JSON instead of text (fields documented in the book's command-line
        /// reference).
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        kernel: KernelArgs,
    },
    /// Evaluate the reference dynamics on states from a JSON file and print JSON.
    ///
    /// Input: {"states": [{"q": [...], "qd": [...], "qdd": [...], "tau": [...]}]} in model
    /// order (qdd and tau optional). Output: per state rnea, drnea_dq, drnea_dqd (with qdd),
    /// M, Minv, fd, dfd_dq, dfd_dqd (with tau); matrices row-major, [i][j] = ∂out_i/∂in_j;
    /// with --frames, frames.LINK: translation, rotation, jacobian, velocity and (with qdd)
    /// classical_acceleration, in Pinocchio's reference frames (the book, Frames).
    Eval {
        /// The robot description.
        #[arg(value_name = "ROBOT.urdf")]
        urdf: PathBuf,
        /// The states to evaluate.
        #[arg(long, value_name = "STATES.json")]
        states: PathBuf,
        /// Gravity in the root frame, m/s².
        #[arg(long, value_name = "X,Y,Z", value_parser = parse_gravity, default_value = "0,0,-9.81", allow_hyphen_values = true)]
        gravity: [f64; 3],
        /// `reference` (f64, every key); `wgsl`: run the WGSL kernels on the first
        /// adapter (or the one WGPU_ADAPTER_NAME names), same keys, with the WGSL options;
        /// or `verilog`: simulate the rnea_grad and mass_matrix netlists under Icarus
        /// Verilog (keys drnea_dq, drnea_dqd, M, plus each netlist's overflow flag), with
        /// the Verilog options.
        #[arg(long, value_name = "BACKEND", default_value = "reference", value_parser = ["reference", "wgsl", "verilog"])]
        backend: String,
    },
    /// Measure each kernel's error per number format against the double-double value
    /// of its graph, with cond(M) over the states.
    ///
    /// Formats: f64 and f32 (what the generated Rust computes), fixed (the Verilog
    /// datapath's bit-exact model in the --fixed/--rounding/--max-error format; also
    /// fixed:WIDTH.FRAC and fixed:auto), wgsl (the WGSL kernels on the first adapter, with
    /// the WGSL options). Error per state: max|Δ| / max|true| over each output, the worst
    /// output; the table gives the median and largest over the states.
    Accuracy {
        /// The robot description.
        #[arg(value_name = "ROBOT.urdf")]
        urdf: PathBuf,
        /// States to measure on (the format of `eval`); without it, --random states.
        #[arg(long, value_name = "STATES.json", conflicts_with_all = ["random", "seed"])]
        states: Option<PathBuf>,
        /// Number of seeded random states: q within the joint limits, q̇ and q̈ within the
        /// fixed-point bounds (--qd-max, --qdd-max), τ = RNEA at another such q̈.
        #[arg(long, value_name = "N", default_value_t = 100)]
        random: usize,
        /// Seed of the random states.
        #[arg(long, value_name = "S", default_value_t = 1)]
        seed: u64,
        /// Number formats, comma-separated: f64, f32, fixed, fixed:WIDTH.FRAC, fixed:auto, wgsl.
        #[arg(long, value_name = "LIST", value_delimiter = ',', default_value = "f64,f32,fixed")]
        formats: Vec<String>,
        /// Kernels to measure (default: every kernel the robot has).
        #[arg(long, value_name = "K,...", value_delimiter = ',')]
        kernels: Vec<String>,
        /// Print JSON instead of the table.
        #[arg(long)]
        json: bool,
        /// Also write the error-against-cost figure as SVG (cost: time per call with
        /// --time, else operations per call).
        #[arg(long, value_name = "FILE.svg")]
        plot: Option<PathBuf>,
        /// Also time the f64 and f32 kernels (the portable copy, whose numbers are the ones
        /// measured): compiles them with rustc, as `bench --backend rust`.
        #[arg(long)]
        time: bool,
        #[command(flatten)]
        kernel: KernelArgs,
    },
    /// Time the generated kernels: WGSL on batches of states (GPU or lavapipe), or with
    /// --backend rust the Rust kernels per call on this CPU.
    ///
    /// WGSL prints, per kernel, strategy and batch size N: microseconds per batch for the
    /// dispatch alone (inputs on the device) and for the round trip (upload, dispatch,
    /// read back), and states per second (medians of repeated runs).
    Bench {
        /// The robot description.
        #[arg(value_name = "ROBOT.urdf")]
        urdf: PathBuf,
        /// `wgsl`, or `rust`: the generated Rust kernels compiled with `rustc -C
        /// opt-level=3` and timed per call, f64 and f32, portable and dispatching copies
        /// (--batch and --seconds do not apply).
        #[arg(long, value_name = "BACKEND", default_value = "wgsl", value_parser = ["wgsl", "rust"])]
        backend: String,
        /// Batch sizes.
        #[arg(
            long,
            value_name = "N,...",
            value_delimiter = ',',
            default_value = "1,16,128,1024,16384"
        )]
        batch: Vec<usize>,
        /// Kernels to time.
        #[arg(
            long,
            value_name = "K,...",
            value_delimiter = ',',
            default_value = "rnea_grad,fd_grad"
        )]
        kernels: Vec<String>,
        /// Time spent repeating each measurement (at least 5 runs each).
        #[arg(long, value_name = "S", default_value_t = 0.5)]
        seconds: f64,
    },
}

fn parse_gravity(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers such as 0,0,-9.81, found `{s}`"
        ));
    }
    let mut g = [0.0; 3];
    for (slot, p) in g.iter_mut().zip(parts) {
        *slot = p
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("`{p}` is not a finite number"))?;
    }
    Ok(g)
}

/// Renders diagnostics with source excerpts; colour only on a terminal.
fn render(path: &str, source: &str, diagnostics: &[Diagnostic]) {
    let file = SimpleFile::new(path, source);
    let choice = if std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none() {
        termcolor::ColorChoice::Auto
    } else {
        termcolor::ColorChoice::Never
    };
    let writer = termcolor::StandardStream::stderr(choice);
    let config = term::Config::default();
    for d in diagnostics {
        let mut report = match d.severity {
            Severity::Error => Report::error(),
            Severity::Warning => Report::warning(),
        }
        .with_message(&d.message);
        if let Some(span) = &d.span {
            report =
                report.with_labels(vec![Label::primary((), span.clone()).with_message(&d.label)]);
        } else if !d.label.is_empty() {
            report = report.with_notes(vec![d.label.clone()]);
        }
        if let Some(help) = &d.help {
            report.notes.push(format!("help: {help}"));
        }
        // A failed write to stderr leaves nothing better to do.
        let _ = term::emit(&mut writer.lock(), &config, &file, &report);
    }
}

fn fail(message: impl std::fmt::Display) -> ExitCode {
    eprintln!("error: {message}");
    ExitCode::from(1)
}

/// Reads and loads a URDF in the scene of `--scene` (if any), rendering every
/// diagnostic; the exit code after an error.
fn load(path: &Path, args: &LoadArgs) -> Result<(Model, grid_gen::Scene), ExitCode> {
    let scene = match &args.scene {
        None => grid_gen::Scene::default(),
        Some(p) => {
            let parsed = std::fs::read_to_string(p)
                .map_err(|e| format!("cannot read scene {}: {e}", p.display()));
            match parsed.and_then(|t| {
                grid_gen::Scene::parse(&p.display().to_string(), &t).map_err(|e| e.to_string())
            }) {
                Ok(s) => s,
                Err(e) => return Err(fail(e)),
            }
        }
    };
    let mut scene = scene;
    scene.floating_base |= args.floating_base;
    if let Some(mode) = args.mimic {
        scene.mimic = mode;
    }
    if !args.frames.is_empty() {
        scene.frames.names = args.frames.clone();
    }
    if let Some(rf) = args.reference_frame {
        scene.frames.reference = Some(rf);
    }
    scene.fd_grad.minv |= args.fd_grad_minv;
    if !args.fext.is_empty() {
        scene.external_forces.joints = args.fext.clone();
    }
    if args.no_fext_derivatives {
        scene.external_forces.derivatives = Some(false);
    }
    if !args.contact.is_empty() {
        scene.contact = args.contact.clone();
    }
    if args.step.is_some() || args.dt.is_some() {
        let s = scene.step.get_or_insert_with(Default::default);
        s.scheme = args.step.or(s.scheme);
        s.dt = args.dt.or(s.dt);
    }
    let scene_path = args.scene.as_ref().map(|p| p.display().to_string()).unwrap_or_default();
    let strict = args.strict;
    let shown = path.display().to_string();
    let text = match std::fs::read(path) {
        Ok(bytes) => match String::from_utf8(bytes) {
            Ok(t) => t,
            Err(_) => return Err(fail(format!("{shown}: the file is not UTF-8 text"))),
        },
        Err(e) => return Err(fail(format!("cannot read {shown}: {e}"))),
    };
    match Model::from_urdf_str_in_scene(&shown, &text, strict, &scene, &scene_path) {
        Ok((model, warnings)) => {
            render(&shown, &text, &warnings);
            Ok((model, scene))
        }
        Err(e) => {
            render(&shown, &text, &e.diagnostics);
            Err(ExitCode::from(1))
        }
    }
}

/// What a scene changed about the robot, for the text summaries (empty without a scene).
fn scene_lines(scene: &grid_gen::Scene) -> String {
    let mut s = String::new();
    if !scene.lock.is_empty() {
        let locked: Vec<String> = scene.lock.iter().map(|(j, v)| format!("{j} = {v}")).collect();
        s.push_str(&format!("scene: locked (fixed at these positions): {}\n", locked.join(", ")));
    }
    if !scene.keep.is_empty() {
        s.push_str(&format!(
            "scene: kept only the subtrees of {} (and the paths to them)\n",
            scene.keep.join(", ")
        ));
    }
    if !scene.drop.is_empty() {
        s.push_str(&format!("scene: dropped {} with everything below\n", scene.drop.join(", ")));
    }
    for p in &scene.payload {
        s.push_str(&format!(
            "scene: payload of {} kg on {}, com {:?} (link frame), inertia {:?} about the com\n",
            p.mass, p.link, p.com, p.inertia
        ));
    }
    s
}

fn print(text: &str) -> ExitCode {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        Ok(()) => ExitCode::SUCCESS,
        // A closed pipe (`| head`) is not a failure of ours.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(e) => fail(format!("cannot write output: {e}")),
    }
}

/// Generates `model`'s files with `options` and writes them into `dir` (or, with `check`,
/// reports which would change).
fn write_generated(
    model: &Model,
    dir: &Path,
    options: &grid_gen::generate::Options,
    check: bool,
) -> ExitCode {
    use grid_gen::generate::{self as g, FileStatus};
    let files = match g::generate(model, options) {
        Ok(f) => f,
        Err(e) => return fail(e),
    };
    let statuses = match g::write_files(dir, &files, check) {
        Ok(s) => s,
        Err(e) => return fail(format!("cannot write into {}: {e}", dir.display())),
    };
    let mut report = String::new();
    let mut stale = false;
    for (path, status) in statuses {
        let what = match status {
            FileStatus::Unchanged => "unchanged",
            FileStatus::Written => "wrote",
            FileStatus::Stale => {
                stale = true;
                "would change"
            }
        };
        report.push_str(&format!("{what} {}\n", path.display()));
    }
    let code = print(&report);
    if stale {
        eprintln!("error: generated files are out of date; rerun without --check");
        return ExitCode::from(1);
    }
    code
}

fn run(cli: Cli) -> ExitCode {
    match cli.command {
        Command::Generate { urdf, out, emit, check, avx512, kernel } => {
            let (model, scene) = match load(&urdf, &cli.load) {
                Ok(loaded) => loaded,
                Err(code) => return code,
            };
            let gravity = scene.gravity.unwrap_or(kernel.gravity);
            match out {
                None => print(
                    &(Info::with_options(&model, gravity, kernel.gradient()).to_text()
                        + &scene_lines(&scene)
                        + "(pass -o DIR to generate code)\n"),
                ),
                Some(dir) => {
                    let verilog = match cli.verilog.options() {
                        Ok(v) => v,
                        Err(e) => return fail(e),
                    };
                    let mut lower = grid_gen::ir::LowerOptions {
                        gradient: kernel.gradient(),
                        ..Default::default()
                    };
                    if let Some(k) = scene.kernels().unwrap_or_default() {
                        lower.kernels = k;
                    }
                    let options = grid_gen::generate::Options {
                        gravity,
                        targets: emit,
                        lower,
                        verilog,
                        wgsl: cli.wgsl.options(),
                        rust: grid_gen::back::rust::RustOptions { avx512, ..Default::default() },
                        ..Default::default()
                    };
                    write_generated(&model, &dir, &options, check)
                }
            }
        }
        Command::Info { urdf, json, kernel } => match load(&urdf, &cli.load) {
            Ok((model, scene)) => {
                let info = Info::with_options(
                    &model,
                    scene.gravity.unwrap_or(kernel.gravity),
                    kernel.gradient(),
                );
                if json {
                    print(&(serde_json::to_string_pretty(&info).expect("info serialises") + "\n"))
                } else {
                    print(&(info.to_text() + &scene_lines(&scene)))
                }
            }
            Err(code) => code,
        },
        Command::Bench { urdf, backend, batch, kernels, seconds } => match load(&urdf, &cli.load) {
            Ok((model, scene)) if backend == "rust" => bench_rust(&model, &scene, &kernels),
            Ok((model, _)) => bench(&model, &cli.wgsl, &batch, &kernels, seconds),
            Err(code) => code,
        },
        Command::Accuracy {
            urdf,
            states,
            random,
            seed,
            formats,
            kernels,
            json,
            plot,
            time,
            kernel,
        } => match load(&urdf, &cli.load) {
            Ok((model, scene)) => accuracy(
                &model,
                &scene,
                &cli.verilog,
                &cli.wgsl,
                AccuracyArgs { states, random, seed, formats, kernels, json, plot, time, kernel },
            ),
            Err(code) => code,
        },
        Command::Eval { urdf, states, gravity, backend } => {
            let (model, scene) = match load(&urdf, &cli.load) {
                Ok(loaded) => loaded,
                Err(code) => return code,
            };
            let gravity = scene.gravity.unwrap_or(gravity);
            let text = match std::fs::read_to_string(&states) {
                Ok(t) => t,
                Err(e) => return fail(format!("cannot read {}: {e}", states.display())),
            };
            let file = match grid_gen::eval::parse_states(&text) {
                Ok(f) => f,
                Err(e) => return fail(format!("{}: {e}", states.display())),
            };
            #[cfg(not(feature = "wgpu"))]
            if backend == "wgsl" {
                return fail(NO_WGPU);
            }
            #[cfg(feature = "wgpu")]
            if backend == "wgsl" {
                let gpu = match grid_gen_wgpu::Gpu::new() {
                    Ok(g) => g,
                    Err(e) => return fail(e),
                };
                let options = cli.wgsl.options();
                let strategy = if cli.wgsl.wgsl_strategy == "cooperative" {
                    grid_gen::back::wgsl::Strategy::Cooperative
                } else {
                    grid_gen::back::wgsl::Strategy::Thread
                };
                // Which adapter and number type the JSON comes from (stdout stays JSON).
                eprintln!(
                    "eval: WGSL on `{}`, {}, {} strategy",
                    gpu.adapter(),
                    options.precision.name(),
                    strategy.name()
                );
                return match grid_gen_wgpu::evaluate(
                    &gpu, &model, &file, gravity, &options, strategy,
                ) {
                    Ok(out) => {
                        print(&(serde_json::to_string(&out).expect("results serialise") + "\n"))
                    }
                    Err(e) => fail(format!("{}: {e}", states.display())),
                };
            }
            if backend == "verilog" {
                let options = match cli.verilog.options() {
                    Ok(v) => v,
                    Err(e) => return fail(e),
                };
                return match grid_gen::eval::evaluate_verilog(&model, &file, gravity, &options) {
                    Ok(out) => {
                        print(&(serde_json::to_string(&out).expect("results serialise") + "\n"))
                    }
                    Err(e) => fail(format!("{}: {e}", states.display())),
                };
            }
            match grid_gen::eval::evaluate(&model, &file, gravity) {
                Ok(out) => print(&(serde_json::to_string(&out).expect("results serialise") + "\n")),
                Err(e) => fail(format!("{}: {e}", states.display())),
            }
        }
    }
}

struct AccuracyArgs {
    states: Option<PathBuf>,
    random: usize,
    seed: u64,
    formats: Vec<String>,
    kernels: Vec<String>,
    json: bool,
    plot: Option<PathBuf>,
    time: bool,
    kernel: KernelArgs,
}

fn accuracy(
    model: &Model,
    scene: &grid_gen::Scene,
    verilog: &VerilogArgs,
    wgsl: &WgslArgs,
    args: AccuracyArgs,
) -> ExitCode {
    use grid_gen::accuracy::{self, NumberFormat};
    let gravity = scene.gravity.unwrap_or(args.kernel.gravity);
    let (file, source) = match &args.states {
        Some(path) => {
            let parsed = std::fs::read_to_string(path)
                .map_err(|e| e.to_string())
                .and_then(|t| grid_gen::eval::parse_states(&t).map_err(|e| e.to_string()));
            match parsed {
                Ok(f) => (f, path.display().to_string()),
                Err(e) => return fail(format!("{}: {e}", path.display())),
            }
        }
        None => (
            accuracy::random_states(
                model,
                gravity,
                args.random,
                args.seed,
                verilog.qd_max,
                verilog.qdd_max,
            ),
            format!("random, seed {}", args.seed),
        ),
    };
    let kernels = if args.kernels.is_empty() {
        let all = accuracy::default_kernels(model);
        match scene.kernels() {
            Ok(Some(wanted)) => all.into_iter().filter(|k| wanted.contains(k)).collect(),
            _ => all,
        }
    } else {
        match parse_kernels(&args.kernels) {
            Ok(k) => k,
            Err(code) => return code,
        }
    };
    let mut formats = Vec::new();
    let mut want_wgsl = false;
    for f in &args.formats {
        let parsed = match f.as_str() {
            "wgsl" => {
                want_wgsl = true;
                continue;
            }
            "fixed" => NumberFormat::parse(
                &format!("fixed:{}", verilog.fixed),
                verilog.rounding,
                verilog.max_error,
            ),
            other => NumberFormat::parse(other, verilog.rounding, verilog.max_error),
        };
        match parsed {
            Ok(p) => formats.push(p),
            // One list of what exists, here (the library's message names only the problem).
            Err(e) => {
                return fail(format!(
                    "--formats: {e}; available: f64, f32, mixed, mixed:TARGET (e.g. mixed:1e-10), fixed (the Verilog options' format), \
                     fixed:WIDTH.FRAC (e.g. fixed:32.16), fixed:auto, wgsl"
                ))
            }
        }
    }
    #[cfg(not(feature = "wgpu"))]
    if want_wgsl {
        let _ = wgsl;
        return fail(NO_WGPU);
    }
    #[cfg(feature = "wgpu")]
    let gpu = if want_wgsl {
        match grid_gen_wgpu::Gpu::new() {
            Ok(g) => Some(g),
            Err(e) => return fail(e),
        }
    } else {
        None
    };
    #[allow(unused_mut)]
    let mut backends = Vec::new();
    #[cfg(feature = "wgpu")]
    if let Some(gpu) = &gpu {
        use grid_gen::back::wgsl::Strategy;
        let options = wgsl.options();
        let strategy = if wgsl.wgsl_strategy == "cooperative" {
            Strategy::Cooperative
        } else {
            Strategy::Thread
        };
        let lower = grid_gen::ir::LowerOptions {
            kernels: kernels.clone(),
            gradient: args.kernel.gradient(),
            ..Default::default()
        };
        let source =
            grid_gen::ir::lower(model, gravity, &lower).map_err(|e| e.to_string()).and_then(|m| {
                grid_gen::back::wgsl::emit(
                    &m,
                    &grid_gen::back::wgsl::WgslOptions {
                        strategies: vec![strategy],
                        ..options.clone()
                    },
                )
                .map_err(|e| e.to_string())
            });
        let shader = match source.and_then(|s| gpu.load(&s.contents).map_err(|e| e.to_string())) {
            Ok(s) => s,
            Err(e) => return fail(format!("wgsl: {e}")),
        };
        let adapter = gpu.adapter();
        let short = adapter.split(" (").next().unwrap_or(&adapter);
        let label = format!("wgsl {} {} on {short}", wgsl.precision, strategy.name());
        backends.push(accuracy::Backend {
            label,
            run: Box::new(move |kind, q, qd, u| {
                let kernel =
                    gpu.kernel(&shader, &strategy.entry(kind.name())).map_err(|e| e.to_string())?;
                gpu.run(&kernel, q, qd, u).map_err(|e| e.to_string())
            }),
        });
    }
    let options = accuracy::Options {
        kernels,
        formats,
        gravity,
        gradient: args.kernel.gradient(),
        qd_max: verilog.qd_max,
        qdd_max: verilog.qdd_max,
    };
    let mut report = match accuracy::measure(model, &file, &source, &options, &mut backends) {
        Ok(r) => r,
        Err(e) => return fail(e),
    };
    if args.time {
        eprintln!("compiling the kernels with rustc to time them...");
        let mixed: Vec<grid_gen::timing::MixedKernel> = report
            .mixed
            .iter()
            .map(|m| grid_gen::timing::MixedKernel {
                label: m.label.clone(),
                function: &m.function,
                wide: &m.wide,
            })
            .collect();
        match time_kernels(model, gravity, args.kernel.gradient(), &options.kernels, &mixed) {
            Ok(times) => report.add_times(&times),
            Err(e) => return fail(e),
        }
    }
    if let Some(path) = &args.plot {
        // As `-o` does, the plot's folder is created.
        let written = match path.parent().filter(|p| !p.as_os_str().is_empty()) {
            Some(dir) => std::fs::create_dir_all(dir)
                .and_then(|_| std::fs::write(path, accuracy::svg(&report))),
            None => std::fs::write(path, accuracy::svg(&report)),
        };
        if let Err(e) = written {
            return fail(format!("cannot write {}: {e}", path.display()));
        }
    }
    if args.json {
        print(&(serde_json::to_string_pretty(&report).expect("report serialises") + "\n"))
    } else {
        print(&report.to_text())
    }
}

/// The kernels a `--kernels` list names, or the exit code after naming the unknown one.
fn parse_kernels(names: &[String]) -> Result<Vec<grid_gen::ir::KernelKind>, ExitCode> {
    use grid_gen::ir::KernelKind;
    names
        .iter()
        .map(|k| {
            KernelKind::parse(k).ok_or_else(|| {
                fail(format!(
                    "--kernels: unknown kernel `{k}`; available: {}",
                    KernelKind::ALL.map(|x| x.name()).join(", ")
                ))
            })
        })
        .collect()
}

/// Times the generated Rust kernels in a scratch folder under the system's temp folder.
fn time_kernels(
    model: &Model,
    gravity: [f64; 3],
    gradient: grid_gen::ir::Gradient,
    kernels: &[grid_gen::ir::KernelKind],
    mixed: &[grid_gen::timing::MixedKernel],
) -> Result<Vec<grid_gen::timing::KernelTime>, grid_gen::timing::TimingError> {
    let work = std::env::temp_dir().join(format!("grid-gen-time-{}", std::process::id()));
    let result = grid_gen::timing::time_rust_kernels_with_mixed(
        model,
        gravity,
        gradient,
        kernels,
        mixed,
        &grid_gen::timing::rustc(),
        &work,
    );
    // The folder holds only what this call wrote; failing to remove it changes nothing.
    let _ = std::fs::remove_dir_all(&work);
    result
}

fn bench_rust(model: &Model, scene: &grid_gen::Scene, kernels: &[String]) -> ExitCode {
    let kinds = match parse_kernels(kernels) {
        Ok(k) => k,
        Err(code) => return code,
    };
    eprintln!("compiling the kernels with rustc -C opt-level=3...");
    let gravity = scene.gravity.unwrap_or(grid_gen::model::DEFAULT_GRAVITY);
    let times = match time_kernels(model, gravity, grid_gen::ir::Gradient::Auto, &kinds, &[]) {
        Ok(t) => t,
        Err(e) => return fail(e),
    };
    let mut out = format!(
        "{:<12} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14}   (ns per call, one state, median of 15; dispatch runs the {} copy here)\n",
        "kernel",
        "f64 portable",
        "f64 fma",
        "f64 dispatch",
        "f32 portable",
        "f32 fma",
        "f32 dispatch",
        dispatched_copy()
    );
    for kind in kinds {
        let cell = |scalar: &str, copy: &str| {
            times
                .iter()
                .find(|t| t.kernel == kind && t.scalar == scalar && t.copy == copy)
                .map_or("-".to_string(), |t| format!("{:.0}", t.ns_per_call))
        };
        out += &format!(
            "{:<12} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14}\n",
            kind.name(),
            cell("f64", "portable"),
            cell("f64", "fma"),
            cell("f64", "dispatch"),
            cell("f32", "portable"),
            cell("f32", "fma"),
            cell("f32", "dispatch")
        );
    }
    print(&out)
}

/// The machine-code copy the generated dispatchers pick on this CPU (the same test as
/// their `has_avx512` and `has_fma`).
fn dispatched_copy() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        let fma = std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma");
        if fma
            && std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512vl")
        {
            return "avx512";
        }
        if fma {
            return "fma";
        }
    }
    "portable"
}

/// Without the `wgpu` feature: the WGSL kernels cannot run here.
#[cfg(not(feature = "wgpu"))]
fn bench(_: &Model, _: &WgslArgs, _: &[usize], _: &[String], _: f64) -> ExitCode {
    fail(NO_WGPU)
}

#[cfg(feature = "wgpu")]
fn bench(
    model: &Model,
    wgsl: &WgslArgs,
    batch: &[usize],
    kernels: &[String],
    seconds: f64,
) -> ExitCode {
    use std::fmt::Write as _;
    let lower = match parse_kernels(kernels) {
        Ok(kernels) => grid_gen::ir::LowerOptions { kernels, ..Default::default() },
        Err(code) => return code,
    };
    if !(seconds.is_finite() && seconds > 0.0) {
        return fail("--seconds must be a positive number");
    }
    let gpu = match grid_gen_wgpu::Gpu::new() {
        Ok(g) => g,
        Err(e) => return fail(e),
    };
    let options = wgsl.options();
    let module = match grid_gen::ir::lower(model, grid_gen::model::DEFAULT_GRAVITY, &lower) {
        Ok(m) => m,
        Err(e) => return fail(e),
    };
    let source = match grid_gen::back::wgsl::emit(&module, &options) {
        Ok(f) => f.contents,
        Err(e) => return fail(e),
    };
    let t = std::time::Instant::now();
    let shader = match gpu.load(&source) {
        Ok(s) => s,
        Err(e) => return fail(e),
    };
    let mut report = format!(
        "adapter: {}\nrobot: {} ({} joints), {}, trig {}; shader module {:.2?}\n",
        gpu.adapter(),
        module.robot.name,
        module.robot.nv(),
        options.precision.name(),
        options.trig.name(),
        t.elapsed()
    );
    let _ = writeln!(
        report,
        "{:<12} {:<12} {:>7} {:>4} {:>14} {:>12} {:>14} {:>16} {:>14}",
        "kernel",
        "strategy",
        "N",
        "disp",
        "us/batch",
        "us/state",
        "states/s",
        "round-trip us",
        "device us"
    );
    // q has nq entries per state (a floating base's or spherical joint's quaternion, which
    // the kernels scale by 1/|q|²), velocities and torques nv.
    let (nq, nv) = (module.robot.nq(), module.robot.nv());
    let mut rng = 0x9E37_79B9_7F4A_7C15u64;
    let mut uniform = move |lo: f64, hi: f64| {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        lo + (hi - lo) * ((rng >> 11) as f64 / (1u64 << 53) as f64)
    };
    let largest = batch.iter().copied().max().unwrap_or(0);
    let q: Vec<f64> = (0..largest * nq).map(|_| uniform(-3.1, 3.1)).collect();
    let qd: Vec<f64> = (0..largest * nv).map(|_| uniform(-3.0, 3.0)).collect();
    let u: Vec<f64> = (0..largest * nv).map(|_| uniform(-3.0, 3.0)).collect();
    let budget = std::time::Duration::from_secs_f64(seconds);
    for f in &module.functions {
        for &strategy in &options.strategies {
            let kernel = match gpu.kernel(&shader, &strategy.entry(f.kind.name())) {
                Ok(k) => k,
                Err(e) => return fail(e),
            };
            let _ = writeln!(
                report,
                "{} {}: pipeline built in {:.2?}",
                kernel.entry.entry,
                strategy.name(),
                kernel.build_time
            );
            for &n in batch {
                let m = n * nv;
                match grid_gen_wgpu::bench::time(
                    &gpu,
                    &kernel,
                    &q[..n * nq],
                    &qd[..m],
                    &u[..m],
                    budget,
                ) {
                    Ok(t) => {
                        let us = t.dispatch.as_secs_f64() * 1e6;
                        let _ = writeln!(
                            report,
                            "{:<12} {:<12} {:>7} {:>4} {:>14.1} {:>12.4} {:>14.3e} {:>16.1} {:>14}",
                            f.kind.name(),
                            strategy.name(),
                            n,
                            t.dispatches,
                            us,
                            us / n.max(1) as f64,
                            n as f64 / t.dispatch.as_secs_f64(),
                            t.round_trip.as_secs_f64() * 1e6,
                            t.device.map_or("-".to_string(), |d| format!(
                                "{:.1}",
                                d.as_secs_f64() * 1e6
                            ))
                        );
                    }
                    Err(e) => return fail(e),
                }
            }
        }
    }
    print(&report)
}

/// What a command that runs WGSL kernels says in a build without the `wgpu` feature.
#[cfg(not(feature = "wgpu"))]
const NO_WGPU: &str = "this grid-gen was built without the `wgpu` feature, so it cannot run WGSL kernels \
     (generating them works); reinstall with default features: cargo install --path crates/grid-gen-cli";

/// `grid-gen ROBOT.urdf ...` is short for `grid-gen generate ROBOT.urdf ...`: inserts
/// `generate` when the first positional argument is not a command. A first argument that
/// is no file and looks like a mistyped command is reported as such (clap alone would
/// read it as the URDF and complain about the real one).
fn with_default_command(args: Vec<std::ffi::OsString>) -> Result<Vec<std::ffi::OsString>, String> {
    let cli = Cli::command();
    let mut commands: Vec<String> =
        cli.get_subcommands().map(|c| c.get_name().to_string()).collect();
    commands.push("help".into());
    // Options that take a value, in any command, so their values are not taken for the URDF.
    let mut valued = Vec::new();
    for c in std::iter::once(&cli).chain(cli.get_subcommands()) {
        for a in c.get_arguments().filter(|a| a.get_action().takes_values() && !a.is_positional()) {
            valued.extend(a.get_long().map(|l| format!("--{l}")));
            valued.extend(a.get_short().map(|s| format!("-{s}")));
        }
    }
    let mut i = 1;
    let first = loop {
        let Some(arg) = args.get(i).map(|a| a.to_string_lossy()) else { return Ok(args) };
        if arg == "--" {
            break i + 1;
        } else if arg.starts_with('-') && arg.len() > 1 {
            i += if valued.iter().any(|v| *v == arg) { 2 } else { 1 };
        } else {
            break i;
        }
    };
    let Some(word) = args.get(first).map(|a| a.to_string_lossy().into_owned()) else {
        return Ok(args);
    };
    if commands.contains(&word) {
        return Ok(args);
    }
    if !Path::new(&word).exists() {
        if let Some(near) = commands.iter().find(|c| strsim::jaro(c, &word) > 0.8) {
            return Err(format!(
                "error: unrecognized command '{word}' (and no such file)\n\n  tip: a similar command exists: '{near}'\n\nUsage: {}\n\nFor more information, try '--help'.",
                cli.clone().render_usage().to_string().trim_start_matches("Usage: ")
            ));
        }
    }
    let mut out = args;
    out.insert(1, "generate".into());
    Ok(out)
}

fn main() -> ExitCode {
    // Mesa's Vulkan loader prints `XDG_RUNTIME_DIR is invalid or not set` on every adapter
    // query without it (DESIGN.md); nothing of ours reads it.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir());
    }
    let args = match with_default_command(std::env::args_os().collect()) {
        Ok(a) => a,
        Err(message) => {
            eprintln!("{message}");
            return ExitCode::from(2);
        }
    };
    match Cli::try_parse_from(args) {
        Ok(cli) => run(cli),
        Err(e) => {
            let _ = e.print();
            // clap: 0 for --help/--version, 2 for usage errors.
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
