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
    model: ModelArgs,
}

/// The WGSL kernels' options, for the commands that write or run them.
#[derive(clap::Args, Clone)]
#[command(next_help_heading = "WGSL options")]
struct WgslArgs {
    /// WGSL strategy: thread (one invocation per state), cooperative (one workgroup per
    /// state), or both (`generate` writes both entry points and `bench` times both, their
    /// default; `eval` and `accuracy` run one, thread by default).
    #[arg(long, value_name = "S")]
    wgsl_strategy: Option<StrategyChoice>,
    /// WGSL float type: f32 (every adapter) or f64 (adapters with SHADER_F64).
    #[arg(long, value_name = "P", default_value = "f32")]
    precision: grid_gen::back::wgsl::Precision,
    /// WGSL sin/cos: accurate (in-kernel reduction and polynomial, ~1 ulp) or builtin
    /// (WGSL's, accuracy up to the implementation; f32 only).
    #[arg(long, value_name = "T", default_value = "accurate")]
    wgsl_trig: grid_gen::back::wgsl::Trig,
    /// WGSL cooperative strategy: invocations per state (1 to 256).
    #[arg(long, value_name = "W", default_value_t = 64)]
    wgsl_workers: u32,
    /// WGSL thread strategy: most operations per dispatch; a larger kernel runs as several
    /// entry points (stages) in order, so no driver compiles more in one pipeline (0: no
    /// split).
    #[arg(long, value_name = "OPS", default_value_t = grid_gen::back::wgsl::DEFAULT_STAGE)]
    wgsl_stage: usize,
}

/// `--wgsl-strategy`: one of the library's strategies, or both.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum StrategyChoice {
    Thread,
    Cooperative,
    Both,
}

impl WgslArgs {
    /// Whether every WGSL flag has its default value (`bench --backend rust` takes none).
    fn is_default(&self) -> bool {
        use grid_gen::back::wgsl::{Precision, Trig, DEFAULT_STAGE};
        self.wgsl_strategy.is_none()
            && self.precision == Precision::F32
            && self.wgsl_trig == Trig::Accurate
            && self.wgsl_workers == 64
            && self.wgsl_stage == DEFAULT_STAGE
    }

    /// The options for the commands that write or time every strategy asked for (both by
    /// default).
    fn options(&self) -> grid_gen::back::wgsl::WgslOptions {
        use grid_gen::back::wgsl::{Strategy, WgslOptions};
        let strategies = match self.wgsl_strategy.unwrap_or(StrategyChoice::Both) {
            StrategyChoice::Both => Strategy::ALL.to_vec(),
            StrategyChoice::Thread => vec![Strategy::Thread],
            StrategyChoice::Cooperative => vec![Strategy::Cooperative],
        };
        WgslOptions {
            strategies,
            precision: self.precision,
            trig: self.wgsl_trig,
            workers: self.wgsl_workers,
            stage: self.wgsl_stage,
            ..WgslOptions::default()
        }
    }

    /// The one strategy `eval` and `accuracy` run (thread by default); `both` is an error
    /// there rather than a silent choice.
    fn strategy(&self, command: &str) -> Result<grid_gen::back::wgsl::Strategy, String> {
        use grid_gen::back::wgsl::Strategy;
        match self.wgsl_strategy {
            None | Some(StrategyChoice::Thread) => Ok(Strategy::Thread),
            Some(StrategyChoice::Cooperative) => Ok(Strategy::Cooperative),
            Some(StrategyChoice::Both) => Err(format!(
                "`{command}` runs one WGSL strategy: pass --wgsl-strategy thread or cooperative"
            )),
        }
    }
}

/// The fixed-point datapath's options, for the commands that write, simulate or model it.
#[derive(clap::Args, Clone)]
#[command(next_help_heading = "Verilog options")]
struct VerilogArgs {
    /// Verilog number format: `WIDTH.FRAC` (signed, e.g. 32.16), or `auto` for the
    /// narrowest format whose analysed error meets --max-error.
    #[arg(long, value_name = "WIDTH.FRAC|auto", default_value = "auto")]
    fixed: String,
    /// With --fixed auto: the largest absolute error allowed on any output entry.
    #[arg(long, value_name = "E", default_value_t = grid_gen::back::verilog::DEFAULT_MAX_ERROR)]
    max_error: f64,
    /// How multipliers drop fraction bits: truncate (robomorphic's choice) or half-up.
    #[arg(long, value_name = "MODE", default_value = "half-up")]
    rounding: grid_gen::datapath::Rounding,
    /// Datapath architecture: pipelined (one state per clock) or shared (M multipliers,
    /// A adders, list-scheduled).
    #[arg(long, value_name = "ARCH", default_value = "pipelined")]
    arch: ArchChoice,
    /// Pipelined: levels of dependence depth between pipeline registers.
    #[arg(long, value_name = "K", default_value_t = grid_gen::back::verilog::DEFAULT_STAGE_DEPTH)]
    stage_depth: u32,
    /// Shared: number of multipliers.
    #[arg(long, value_name = "M", default_value_t = grid_gen::back::verilog::DEFAULT_MULTIPLIERS)]
    multipliers: usize,
    /// Shared: number of adders.
    #[arg(long, value_name = "A", default_value_t = grid_gen::back::verilog::DEFAULT_ADDERS)]
    adders: usize,
    /// Speed bound of every joint for the range analysis (default: the URDF's
    /// `<limit velocity>`, else 10).
    #[arg(long, value_name = "V")]
    qd_max: Option<f64>,
    /// Acceleration bound of every joint for the range analysis (default 100).
    #[arg(long, value_name = "A")]
    qdd_max: Option<f64>,
    /// Bound on every entry of fext and lambda for the range analysis (N, N m; default 1e4).
    #[arg(long, value_name = "F")]
    force_max: Option<f64>,
    /// Also build fd_grad's netlist. `host`: robomorphic computing's partition, the host
    /// computes q̈ and M⁻¹, the netlist ∂q̈/∂q and ∂q̈/∂q̇ = −M⁻¹ ∂c/∂u
    /// (`<robot>_fd_grad_host`). `chip`: the netlist takes τ and computes M, its
    /// factorisation (with a divider), q̈ and both derivatives (`<robot>_fd_grad_chip`;
    /// its ranges are proven, its error measured). `auto` (the flag without a value): chip
    /// where its bounds cover the robot, else host.
    #[arg(long, value_name = "PARTITION", num_args = 0..=1, default_missing_value = "auto")]
    fd_grad_netlist: Option<grid_gen::back::verilog::FdGradPartition>,
    /// With --fd-grad-netlist host: bound on every diagonal entry of M⁻¹, which the host
    /// checks (default: twice the largest over 256 seeded configurations).
    #[arg(long, value_name = "B")]
    minv_max: Option<f64>,
    /// With --fd-grad-netlist chip: bound on every actuated joint's |τ| (N m or N;
    /// default 1000; a floating base takes none).
    #[arg(long, value_name = "T")]
    tau_max: Option<f64>,
}

/// `--fixed`: `WIDTH.FRAC`, or `auto` (the narrowest format within `max_error`).
fn format_choice(
    fixed: &str,
    max_error: f64,
    rounding: grid_gen::datapath::Rounding,
) -> Result<grid_gen::back::verilog::FormatChoice, String> {
    use grid_gen::back::verilog::FormatChoice;
    if fixed == "auto" {
        return Ok(FormatChoice::Auto { max_error });
    }
    match grid_gen::datapath::Format::parse(fixed, rounding) {
        Some(Ok(f)) => Ok(FormatChoice::Fixed { width: f.width, frac: f.frac }),
        Some(Err(e)) => Err(format!("--fixed: {e}")),
        None => {
            Err(format!("--fixed: expected WIDTH.FRAC such as 32.16, or auto; found `{fixed}`"))
        }
    }
}

/// `--arch`: the Verilog architectures, whose sizes are their own flags.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum ArchChoice {
    Pipelined,
    Shared,
}

impl VerilogArgs {
    fn options(&self) -> Result<grid_gen::back::verilog::VerilogOptions, String> {
        use grid_gen::back::verilog::{Arch, VerilogOptions};
        let format = format_choice(&self.fixed, self.max_error, self.rounding)?;
        for (name, v) in [
            ("--qd-max", self.qd_max),
            ("--qdd-max", self.qdd_max),
            ("--force-max", self.force_max),
            ("--minv-max", self.minv_max),
            ("--tau-max", self.tau_max),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("{name} must be a positive finite number, got {v}"));
                }
            }
        }
        let arch = match self.arch {
            ArchChoice::Shared => {
                Arch::Shared { multipliers: self.multipliers, adders: self.adders }
            }
            ArchChoice::Pipelined => Arch::Pipelined { stage_depth: self.stage_depth },
        };
        Ok(VerilogOptions {
            format,
            rounding: self.rounding,
            arch,
            qd_max: self.qd_max,
            qdd_max: self.qdd_max,
            force_max: self.force_max,
            fd_grad: self.fd_grad_netlist,
            minv_max: self.minv_max,
            tau_max: self.tau_max,
            ..VerilogOptions::default()
        })
    }
}

/// The robot, its scene and what its kernels compute: every command loads the model
/// through these, into the library's one [`grid_gen::Config`].
#[derive(clap::Args)]
struct ModelArgs {
    /// Treat warnings (such as physically implausible inertias) as errors.
    #[arg(long, global = true)]
    strict: bool,
    /// A scene file (TOML): joints to lock, links to keep or drop, payloads, gravity, the
    /// kernels to generate; applied to the model for every command (the book, Scenes).
    /// Each flag below replaces the scene's value.
    #[arg(long, value_name = "SCENE.toml", global = true)]
    scene: Option<PathBuf>,
    /// Gravity in the root frame, m/s², compiled into the generated code (default
    /// 0,0,-9.81, or the scene's `gravity`).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_gravity, allow_hyphen_values = true, global = true)]
    gravity: Option<[f64; 3]>,
    /// How to build the RNEA gradient (rnea_grad, fd_grad): `idsva` (Singh, Russell &
    /// Wensing 2022) in body frames, `world` (the same with every pair in one frame per tree),
    /// `columns` (Carpentier & Mansard 2018), or `auto`, the one with fewer operations for
    /// this robot (`info` says which).
    #[arg(
        long,
        value_name = "FORM",
        default_value = "auto",
        global = true,
        hide_possible_values = true
    )]
    gradient: grid_gen::ir::Gradient,
    /// How fd_grad applies M^-1 and minv forms it: `minv` (Pinocchio's), `ltdl` (M's sparse
    /// factorisation), `crba` (fd_grad's q̈ from it too), or `auto`, the one with fewer
    /// operations (`info` says which; the book, Speed).
    #[arg(
        long,
        value_name = "SOLVE",
        default_value = "auto",
        global = true,
        hide_possible_values = true
    )]
    solve: grid_gen::ir::Solve,
    /// Which kernels call other kernels of their module instead of holding their work:
    /// `auto` (where it costs no speed: a step kernel calls its contact kernel; and what
    /// `rnea_grad` does where the module's `contact_fd_grad` has at least 150,000
    /// operations, a humanoid on its feet), `rnea_grad` (also `fd_grad` and
    /// `contact_fd_grad` call `rnea_grad` at their own q̈ where they factorise M and read
    /// the transforms it computes first: a humanoid's library loads in 0.57x to 0.81x the
    /// time, `fd_grad` 0.97x to 1.06x the time, the contact gradients 1.00x to 1.02x) or
    /// `all` (they call `fd` or
    /// `contact_fd` for q̈ too: 0.7x the time, `fd_grad` 1.13x and `step_grad` 1.2x slower;
    /// the book, Compile time).
    #[arg(long, value_name = "WHICH", default_value = "auto", global = true)]
    calls: grid_gen::ir::Calls,
    /// Put a free-flyer between the world and the root link (Pinocchio's conventions:
    /// q = [x, y, z, qx, qy, qz, qw, joints...], velocities and gradients in the base frame).
    #[arg(long, global = true)]
    floating_base: bool,
    /// How <mimic> joints are modelled: `independent` (the default, as urdfdom and
    /// Pinocchio's default) or `coupled` (q_m = multiplier * q + offset, no coordinate of
    /// their own; Pinocchio's mimic=True).
    #[arg(long, value_name = "MODE", global = true, hide_possible_values = true)]
    mimic: Option<grid_gen::MimicMode>,
    /// Frames (URDF link names, comma-separated) whose placement, Jacobian, velocity and
    /// classical acceleration the frame kernels compute and `eval` reports; replaces the
    /// scene's `[frames] names`.
    #[arg(long, value_name = "LINK,...", value_delimiter = ',', global = true)]
    frames: Vec<String>,
    /// The frame kernels' reference frame (Pinocchio's ReferenceFrame; default
    /// local_world_aligned).
    #[arg(long, value_name = "RF", global = true, hide_possible_values = true)]
    reference_frame: Option<grid_gen::model::ReferenceFrame>,
    /// Generate the step kernels (`step`, `step_grad`) and have `eval` report each state's
    /// next state and [A | B] (semi_implicit_euler is Crocoddyl's default); replaces the
    /// scene's `[step] scheme`. With --dt the time step is folded into the kernels; without
    /// it (and no `[step] dt`) the step kernels take `dt` at run time, and `eval` reads each
    /// state's `dt`.
    #[arg(long, value_name = "SCHEME", global = true, hide_possible_values = true)]
    step: Option<grid_gen::model::Scheme>,
    /// The step's time step in seconds, folded into the kernels; replaces `[step] dt`. Left
    /// out, the step kernels take it at run time.
    #[arg(long, value_name = "SECONDS", global = true)]
    dt: Option<f64>,
    /// The actuated joints, comma-separated: the step's τ and B's columns (default every
    /// joint but a floating base); replaces `[actuation] joints`.
    #[arg(long, value_name = "JOINT,...", value_delimiter = ',', global = true)]
    actuated: Vec<String>,
    /// `fd_grad` also returns `dqdd_dtau` = M^-1 (the scene's `[fd_grad] minv = true`).
    #[arg(long, global = true)]
    fd_grad_minv: bool,
    /// Bodies that take an external force `fext` in rnea, rnea_grad, fd and fd_grad (and,
    /// held constant, in the contact and step kernels), by the name of the joint that
    /// moves them (Pinocchio's names: `root_joint` for a floating base), comma-separated,
    /// or `*` for every body; replaces `[external_forces] joints`.
    #[arg(long, value_name = "JOINT,...", value_delimiter = ',', global = true)]
    fext: Vec<String>,
    /// rnea_grad and fd_grad do not return d/dfext (the scene's `[external_forces]
    /// derivatives = false`): the forces cost only their own work.
    #[arg(long, global = true)]
    no_fext_derivatives: bool,
    /// Contacts whose forces lambda those kernels take, in world axes at the frame's
    /// origin: FRAME:point (3-D force) or FRAME:wrench (6-D), comma-separated; the contact
    /// and step kernels hold them rigid and solve for lambda. Replaces the scene's
    /// `[[contact]]`.
    #[arg(long, value_name = "FRAME:TYPE,...", value_delimiter = ',', global = true, value_parser = parse_contact)]
    contact: Vec<grid_gen::ContactEntry>,
    /// The contacts are candidates chosen per state: contact_fd, contact_fd_grad, step and
    /// step_grad take `active`, one 0 or 1 per contact (an inactive one has lambda = 0 and
    /// no constraint). The scene's `contact_mask = true`.
    #[arg(long, global = true)]
    contact_mask: bool,
    /// Stabilise the contacts as Pinocchio's Baumgarte corrector: the kernels that solve for
    /// their forces take `gains` (Kp, Kd per contact) and `contact_ref` (a point's world
    /// position, a wrench's world placement). The scene's `baumgarte = true`.
    #[arg(long, global = true)]
    baumgarte: bool,
    /// Read every <origin rpy> angle within RAD of a multiple of pi/2 as that multiple
    /// (at most 1e-6): a URDF's pi/2 written to a few digits becomes a permutation the
    /// kernels apply for free, and the results move from the literal file's by about RAD
    /// (the book, Speed). Replaces the scene's `round_angles`.
    #[arg(long, value_name = "RAD", global = true)]
    round_angles: Option<f64>,
}

impl ModelArgs {
    /// The library's description of the job: these flags as overrides of the scene.
    fn config(&self, urdf: &Path) -> grid_gen::Config {
        let list = |v: &Vec<String>| (!v.is_empty()).then(|| v.clone());
        let mut config = grid_gen::Config::new(urdf);
        config.scene = self.scene.clone();
        config.strict = self.strict;
        config.options.lower.gradient = self.gradient;
        config.options.lower.solve = self.solve;
        config.options.lower.calls = self.calls;
        config.overrides = grid_gen::SceneOverrides {
            gravity: self.gravity,
            floating_base: self.floating_base.then_some(true),
            mimic: self.mimic,
            frames: list(&self.frames),
            reference_frame: self.reference_frame,
            scheme: self.step,
            dt: self.dt,
            // A scene's folded dt stays folded unless --dt replaces it.
            runtime_dt: false,
            actuated: list(&self.actuated),
            fd_grad_minv: self.fd_grad_minv.then_some(true),
            fext: list(&self.fext),
            fext_derivatives: self.no_fext_derivatives.then_some(false),
            contacts: (!self.contact.is_empty()).then(|| self.contact.clone()),
            round_angles: self.round_angles,
            contact_mask: self.contact_mask.then_some(true),
            baumgarte: self.baumgarte.then_some(true),
            source: grid_gen::settings::Source::Flags,
        };
        config
    }
}

fn parse_contact(s: &str) -> Result<grid_gen::ContactEntry, String> {
    let (frame, kind) = s
        .rsplit_once(':')
        .ok_or_else(|| format!("`{s}`: write a contact as FRAME:point or FRAME:wrench"))?;
    let kind = grid_gen::model::ContactKind::parse(kind)
        .ok_or_else(|| format!("`{s}`: unknown contact type `{kind}`; available: point, wrench"))?;
    Ok(grid_gen::ContactEntry { frame: frame.to_string(), kind })
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
        /// Backends to write, comma-separated: rust, wgsl, verilog, c (c writes the batch
        /// entry points and C ABI `<robot>_c.rs` and the header `<robot>.h`).
        #[arg(
            long,
            alias = "emit",
            value_name = "LIST",
            value_delimiter = ',',
            default_value = "rust"
        )]
        backend: Vec<grid_gen::generate::Target>,
        /// Write nothing; exit 1 if any file would change (for CI freshness checks).
        #[arg(long, requires = "out")]
        check: bool,
        /// Also emit the Rust module's `avx512` copy, run first on CPUs with AVX-512 F and VL
        /// (half again the module's size and compile time; results bit-identical to the
        /// `fma` copy; the book, Speed).
        #[arg(long)]
        avx512: bool,
        /// Which copies of the kernels the Rust module holds: `dispatch` (portable and
        /// AVX2+FMA, chosen per call: runs anywhere), `portable`, `fma` (x86-64 with AVX2 and
        /// FMA only, about 4x faster to compile than `dispatch`), or `host` (this machine's:
        /// `fma` where it has them, else `portable`).
        #[arg(long, value_name = "COPIES", default_value = "dispatch", value_parser = parse_copies)]
        copies: grid_gen::back::rust::Copies,
        /// Which kernels' C and batch entry points (`--backend c`) run four f64 or eight f32
        /// states per call in SIMD lanes: `auto` (where lanes were measured to pay: at most
        /// 150,000 operations and 6 per output entry), `all` or `none`. Each kernel with
        /// lanes is compiled twice (the book, Compile time).
        #[arg(long, value_name = "WHICH", default_value = "auto")]
        batch_lanes: grid_gen::back::c::BatchLanes,
        #[command(flatten)]
        wgsl: WgslArgs,
        #[command(flatten)]
        verilog: VerilogArgs,
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
        /// The pipelined Verilog netlists' levels of dependence depth between registers,
        /// as generation's --stage-depth.
        #[arg(long, value_name = "K", default_value_t = grid_gen::back::verilog::DEFAULT_STAGE_DEPTH)]
        stage_depth: u32,
        /// The Verilog netlists' number format, as generation's --fixed: `WIDTH.FRAC`, or
        /// `auto` (the narrowest whose analysed error is within 1e-3). The other Verilog
        /// figures are at default options.
        #[arg(long, value_name = "WIDTH.FRAC|auto", default_value = "auto")]
        fixed: String,
    },
    /// Evaluate the dynamics on states from a JSON file and print JSON.
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
        /// `reference` (f64, every key); `wgsl`: run the WGSL kernels on the first
        /// adapter (or the one WGPU_ADAPTER_NAME names), same keys, with the WGSL options;
        /// or `verilog`: simulate the rnea_grad and mass_matrix netlists under Icarus
        /// Verilog (keys drnea_dq, drnea_dqd, M, plus each netlist's overflow flag), with
        /// the Verilog options.
        #[arg(long, value_name = "BACKEND", default_value = "reference")]
        backend: EvalBackend,
        #[command(flatten)]
        wgsl: WgslArgs,
        #[command(flatten)]
        verilog: VerilogArgs,
    },
    /// Measure each kernel's error per number format against the double-double value
    /// of its graph, with cond(M) over the states.
    ///
    /// Formats: f64 and f32 (what the generated Rust computes), mixed (a mixed-precision
    /// plan), fixed (the Verilog datapath's bit-exact model in the --fixed/--rounding/
    /// --max-error format; also fixed:WIDTH.FRAC and fixed:auto); with --backend wgsl, the
    /// WGSL kernels on the first adapter too. Error per state: max|Δ| / max|true| over
    /// each output, the worst output; the table gives the median and largest over the
    /// states.
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
        /// Number formats, comma-separated: f64, f32, mixed, mixed:TARGET, fixed,
        /// fixed:WIDTH.FRAC, fixed:auto.
        #[arg(long, value_name = "LIST", value_delimiter = ',', default_value = "f64,f32,fixed")]
        formats: Vec<String>,
        /// Also measure the kernels run by a backend: `wgsl` (the WGSL kernels on the first
        /// adapter, with the WGSL options).
        #[arg(long, value_name = "BACKEND", value_delimiter = ',')]
        backend: Vec<AccuracyBackend>,
        /// Kernels to measure (default: every kernel the robot has).
        #[arg(long, value_name = "K,...", value_delimiter = ',')]
        kernels: Vec<grid_gen::ir::KernelKind>,
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
        wgsl: WgslArgs,
        #[command(flatten)]
        verilog: VerilogArgs,
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
        /// (then --batch, --seconds and the WGSL options are errors).
        #[arg(long, value_name = "BACKEND", default_value = "wgsl")]
        backend: BenchBackend,
        /// WGSL: batch sizes (default 1,16,128,1024,16384).
        #[arg(long, value_name = "N,...", value_delimiter = ',')]
        batch: Vec<usize>,
        /// Kernels to time.
        #[arg(
            long,
            value_name = "K,...",
            value_delimiter = ',',
            default_value = "rnea_grad,fd_grad"
        )]
        kernels: Vec<grid_gen::ir::KernelKind>,
        /// WGSL: time spent repeating each measurement (at least 5 runs each; default 0.5).
        #[arg(long, value_name = "S")]
        seconds: Option<f64>,
        #[command(flatten)]
        wgsl: WgslArgs,
    },
}

/// `eval --backend`.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum EvalBackend {
    Reference,
    Wgsl,
    Verilog,
}

/// `accuracy --backend`: the backends that run kernels beside the modelled formats.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum AccuracyBackend {
    Wgsl,
}

/// `bench --backend`.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum BenchBackend {
    Wgsl,
    Rust,
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

/// Loads the robot as the flags describe it, rendering every diagnostic; the exit code
/// after an error.
fn load(urdf: &Path, args: &ModelArgs) -> Result<(grid_gen::Config, grid_gen::Loaded), ExitCode> {
    let config = args.config(urdf);
    match config.load() {
        Ok(loaded) => {
            render(&loaded.urdf_path, &loaded.urdf_text, &loaded.warnings);
            Ok((config, loaded))
        }
        Err(grid_gen::ConfigError::Load(e)) => {
            render(&e.path, &e.source_text, &e.diagnostics);
            Err(ExitCode::from(1))
        }
        Err(e) => Err(fail(e)),
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
        Command::Generate {
            urdf,
            out,
            backend,
            check,
            avx512,
            copies,
            batch_lanes,
            wgsl,
            verilog,
        } => {
            let (mut config, loaded) = match load(&urdf, &cli.model) {
                Ok(loaded) => loaded,
                Err(code) => return code,
            };
            let Some(dir) = out else {
                return print(
                    &(Info::with_options(
                        &loaded.model,
                        loaded.gravity(),
                        cli.model.gradient,
                        cli.model.solve,
                        cli.model.calls,
                        verilog.stage_depth,
                        match verilog.options() {
                            Ok(v) => v.format,
                            Err(e) => return fail(e),
                        },
                    )
                    .to_text()
                        + &scene_lines(&loaded.scene)
                        + "(pass -o DIR to generate code)\n"),
                );
            };
            config.options.targets = backend;
            config.options.rust.avx512 = avx512;
            config.options.rust.copies = copies;
            config.options.c.lanes = batch_lanes;
            config.options.wgsl = wgsl.options();
            config.options.verilog = match verilog.options() {
                Ok(v) => v,
                Err(e) => return fail(e),
            };
            write_generated(&loaded.model, &dir, &loaded.options(&config.options), check)
        }
        Command::Info { urdf, json, stage_depth, fixed } => match load(&urdf, &cli.model) {
            Ok((_, loaded)) => {
                let default = grid_gen::back::verilog::VerilogOptions::default();
                let format = match format_choice(
                    &fixed,
                    grid_gen::back::verilog::DEFAULT_MAX_ERROR,
                    default.rounding,
                ) {
                    Ok(f) => f,
                    Err(e) => return fail(e),
                };
                let info = Info::with_options(
                    &loaded.model,
                    loaded.gravity(),
                    cli.model.gradient,
                    cli.model.solve,
                    cli.model.calls,
                    stage_depth,
                    format,
                );
                if json {
                    print(&(serde_json::to_string_pretty(&info).expect("info serialises") + "\n"))
                } else {
                    print(&(info.to_text() + &scene_lines(&loaded.scene)))
                }
            }
            Err(code) => code,
        },
        Command::Bench { urdf, backend, batch, kernels, seconds, wgsl } => {
            let wgsl_only = !batch.is_empty() || seconds.is_some() || !wgsl.is_default();
            if backend == BenchBackend::Rust && wgsl_only {
                return fail(
                    "`bench --backend rust` times one state per call on this CPU: --batch, \
                     --seconds and the WGSL options apply to `--backend wgsl` only",
                );
            }
            let (config, loaded) = match load(&urdf, &cli.model) {
                Ok(loaded) => loaded,
                Err(code) => return code,
            };
            match backend {
                BenchBackend::Rust => bench_rust(&loaded, &config, &kernels),
                BenchBackend::Wgsl => {
                    let batch =
                        if batch.is_empty() { vec![1, 16, 128, 1024, 16384] } else { batch };
                    let mut options = loaded.options(&config.options);
                    options.lower.kernels = kernels;
                    bench(&loaded.model, &options, &wgsl, &batch, seconds.unwrap_or(0.5))
                }
            }
        }
        Command::Accuracy {
            urdf,
            states,
            random,
            seed,
            formats,
            backend,
            kernels,
            json,
            plot,
            time,
            wgsl,
            verilog,
        } => match load(&urdf, &cli.model) {
            Ok((config, loaded)) => accuracy(
                &loaded,
                &config,
                &verilog,
                &wgsl,
                AccuracyArgs { states, random, seed, formats, backend, kernels, json, plot, time },
            ),
            Err(code) => code,
        },
        Command::Eval { urdf, states, backend, wgsl, verilog } => {
            let (config, loaded) = match load(&urdf, &cli.model) {
                Ok(loaded) => loaded,
                Err(code) => return code,
            };
            let (model, gravity) = (&loaded.model, loaded.gravity());
            let text = match std::fs::read_to_string(&states) {
                Ok(t) => t,
                Err(e) => return fail(format!("cannot read {}: {e}", states.display())),
            };
            let file = match grid_gen::eval::parse_states(&text) {
                Ok(f) => f,
                Err(e) => return fail(format!("{}: {e}", states.display())),
            };
            let out = match backend {
                EvalBackend::Reference => grid_gen::eval::evaluate(model, &file, gravity)
                    .map(|o| serde_json::to_string(&o).expect("results serialise"))
                    .map_err(|e| format!("{}: {e}", states.display())),
                EvalBackend::Verilog => verilog.options().and_then(|options| {
                    grid_gen::eval::evaluate_verilog(model, &file, gravity, &options)
                        .map(|o| serde_json::to_string(&o).expect("results serialise"))
                        .map_err(|e| format!("{}: {e}", states.display()))
                }),
                EvalBackend::Wgsl => eval_wgsl(model, &file, gravity, &config.options.lower, &wgsl)
                    .map(|o| serde_json::to_string(&o).expect("results serialise"))
                    .map_err(|e| format!("{}: {e}", states.display())),
            };
            match out {
                Ok(text) => print(&(text + "\n")),
                Err(e) => fail(e),
            }
        }
    }
}

/// `eval --backend wgsl`: the WGSL kernels on the first adapter.
#[cfg(feature = "wgpu")]
fn eval_wgsl(
    model: &Model,
    file: &grid_gen::eval::StatesFile,
    gravity: [f64; 3],
    routes: &grid_gen::ir::LowerOptions,
    wgsl: &WgslArgs,
) -> Result<grid_gen::eval::EvalOutput, String> {
    let strategy = wgsl.strategy("eval")?;
    let gpu = grid_gen_wgpu::Gpu::new().map_err(|e| e.to_string())?;
    let options = wgsl.options();
    // Which adapter and number type the JSON comes from (stdout stays JSON).
    eprintln!(
        "eval: WGSL on `{}`, {}, {} strategy, gradient {}, solve {}",
        gpu.adapter(),
        options.precision.name(),
        strategy.name(),
        routes.gradient.name(),
        routes.solve.name()
    );
    grid_gen_wgpu::evaluate(&gpu, model, file, gravity, routes, &options, strategy)
        .map_err(|e| e.to_string())
}

#[cfg(not(feature = "wgpu"))]
fn eval_wgsl(
    _: &Model,
    _: &grid_gen::eval::StatesFile,
    _: [f64; 3],
    _: &grid_gen::ir::LowerOptions,
    wgsl: &WgslArgs,
) -> Result<grid_gen::eval::EvalOutput, String> {
    wgsl.strategy("eval")?;
    Err(NO_WGPU.to_string())
}

struct AccuracyArgs {
    states: Option<PathBuf>,
    random: usize,
    seed: u64,
    formats: Vec<String>,
    backend: Vec<AccuracyBackend>,
    kernels: Vec<grid_gen::ir::KernelKind>,
    json: bool,
    plot: Option<PathBuf>,
    time: bool,
}

fn accuracy(
    loaded: &grid_gen::Loaded,
    config: &grid_gen::Config,
    verilog: &VerilogArgs,
    wgsl: &WgslArgs,
    args: AccuracyArgs,
) -> ExitCode {
    use grid_gen::accuracy::{self, NumberFormat};
    if verilog.fd_grad_netlist.is_some() || verilog.minv_max.is_some() || verilog.tau_max.is_some()
    {
        return fail("--fd-grad-netlist, --minv-max and --tau-max choose a netlist to generate or simulate; `accuracy` measures number formats on the kernels themselves");
    }
    let (model, gravity) = (&loaded.model, loaded.gravity());
    let gradient = config.options.lower.gradient;
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
        match &loaded.kernels {
            Some(wanted) => all.into_iter().filter(|k| wanted.contains(k)).collect(),
            None => all,
        }
    } else {
        args.kernels.clone()
    };
    let mut formats = Vec::new();
    for f in &args.formats {
        let parsed = match f.as_str() {
            "wgsl" => {
                return fail(
                    "--formats: `wgsl` is a backend, not a number format: pass --backend wgsl",
                )
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
                     fixed:WIDTH.FRAC (e.g. fixed:32.16), fixed:auto"
                ))
            }
        }
    }
    let want_wgsl = args.backend.contains(&AccuracyBackend::Wgsl);
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
        let strategy = match wgsl.strategy("accuracy") {
            Ok(s) => s,
            Err(e) => return fail(e),
        };
        let mut lower = config.options.lower.clone();
        lower.kernels = kernels.clone();
        let backend = grid_gen::ir::lower(model, gravity, &lower)
            .map_err(|e| e.to_string())
            .and_then(|module| {
                grid_gen_wgpu::accuracy_backend(gpu, &module, &wgsl.options(), strategy)
                    .map_err(|e| e.to_string())
            });
        match backend {
            Ok(b) => backends.push(b),
            Err(e) => return fail(format!("wgsl: {e}")),
        }
    }
    let options = accuracy::Options {
        kernels,
        formats,
        gravity,
        gradient,
        solve: config.options.lower.solve,
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
        match time_kernels(model, gravity, &config.options.lower, &options.kernels, &mixed) {
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

/// Times the generated Rust kernels in a scratch folder under the system's temp folder.
fn time_kernels(
    model: &Model,
    gravity: [f64; 3],
    routes: &grid_gen::ir::LowerOptions,
    kernels: &[grid_gen::ir::KernelKind],
    mixed: &[grid_gen::timing::MixedKernel],
) -> Result<Vec<grid_gen::timing::KernelTime>, grid_gen::timing::TimingError> {
    let work = std::env::temp_dir().join(format!("grid-gen-time-{}", std::process::id()));
    let result = grid_gen::timing::time_rust_kernels_with_mixed(
        model,
        gravity,
        routes,
        kernels,
        mixed,
        &grid_gen::tools::rustc::rustc(),
        &work,
    );
    // The folder holds only what this call wrote; failing to remove it changes nothing.
    let _ = std::fs::remove_dir_all(&work);
    result
}

fn bench_rust(
    loaded: &grid_gen::Loaded,
    config: &grid_gen::Config,
    kinds: &[grid_gen::ir::KernelKind],
) -> ExitCode {
    eprintln!("compiling the kernels with rustc -C opt-level=3...");
    match time_kernels(&loaded.model, loaded.gravity(), &config.options.lower, kinds, &[]) {
        Ok(times) => print(&grid_gen::timing::table(&times, kinds)),
        Err(e) => fail(e),
    }
}

/// Without the `wgpu` feature: the WGSL kernels cannot run here.
#[cfg(not(feature = "wgpu"))]
fn bench(
    _: &Model,
    _: &grid_gen::generate::Options,
    _: &WgslArgs,
    _: &[usize],
    _: f64,
) -> ExitCode {
    fail(NO_WGPU)
}

/// `bench`: the WGSL kernels of `options.lower` timed on the first adapter.
#[cfg(feature = "wgpu")]
fn bench(
    model: &Model,
    options: &grid_gen::generate::Options,
    wgsl: &WgslArgs,
    batch: &[usize],
    seconds: f64,
) -> ExitCode {
    let module = match grid_gen::ir::lower(model, options.gravity, &options.lower) {
        Ok(m) => m,
        Err(e) => return fail(e),
    };
    let gpu = match grid_gen_wgpu::Gpu::new() {
        Ok(g) => g,
        Err(e) => return fail(e),
    };
    match grid_gen_wgpu::bench::table(&gpu, &module, &wgsl.options(), batch, seconds) {
        Ok(table) => print(&table),
        Err(e) => fail(e),
    }
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

/// `--copies`: a name of [`grid_gen::back::rust::Copies`], or `host`.
fn parse_copies(s: &str) -> Result<grid_gen::back::rust::Copies, String> {
    grid_gen::back::rust::Copies::parse(s)
        .ok_or_else(|| format!("`{s}`: copies are dispatch, portable, fma or host"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every setting of `grid_gen::settings::SETTINGS` is the flag the table says, on every
    /// subcommand (the model flags are global): errors name that flag.
    #[test]
    fn every_setting_has_its_flag() {
        let cmd = Cli::command();
        for sub in cmd.get_subcommands() {
            for s in &grid_gen::settings::SETTINGS {
                let long = s.flag.strip_prefix("--").expect("a long flag");
                let found = sub.get_arguments().any(|a| a.get_long() == Some(long))
                    || cmd.get_arguments().any(|a| a.get_long() == Some(long) && a.is_global_set());
                assert!(
                    found,
                    "`grid-gen {}` has no {} (setting `{}`)",
                    sub.get_name(),
                    s.flag,
                    s.key
                );
            }
        }
    }
}
