//! The Verilog backend: each datapath kernel (`rnea_grad`, `mass_matrix`; `rnea` on
//! request) as a synthesisable Verilog-2005 fixed-point netlist with a `clk`/`rst`,
//! `in_valid`/`in_ready`/`out_valid` handshake and a sticky `overflow` flag, plus a
//! testbench. sin q and cos q are inputs (computed by the host, as in robomorphic
//! computing); only structurally non-zero outputs are ports. Two architectures:
//! `pipelined` (every IR node its own operator, registers every K levels of depth, one
//! state per clock) and `shared` (the graph list-scheduled onto M multipliers and A
//! adders under a generated controller).

mod cells;
/// The two arithmetic cell modules of a format (`<top>_mul`, `<top>_add`), for synthesising
/// one cell on its own (the book's per-width gate counts).
pub use cells::{cells as cell_modules, Divider};
mod pipelined;
mod ports;
mod schedule;
mod shared;
mod testbench;
/// How many states one run of the testbench reads (its input memory's depth).
pub use testbench::MAX_STATES;

use serde::Serialize;

use super::names::{comment_text, identifier};
use super::{GeneratedFile, Target};
use crate::datapath::{
    analyse, choose_format, choose_format_measured, measure, Analysis, Bounds, ChipState, Datapath,
    FixedError, Format, Measured, Rounding,
};
use crate::ir::{KernelKind, Module};
pub use pipelined::Stages;
pub use ports::PortNames;
pub use schedule::SharedSchedule;

/// How the datapath is built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Arch {
    /// Every operation its own unit; pipeline registers every `stage_depth` levels.
    Pipelined { stage_depth: u32 },
    /// `multipliers` multipliers and `adders` adders (add, subtract, negate) shared over
    /// the graph by a list schedule.
    Shared { multipliers: usize, adders: usize },
}

impl Arch {
    pub fn name(&self) -> &'static str {
        match self {
            Arch::Pipelined { .. } => "pipelined",
            Arch::Shared { .. } => "shared",
        }
    }
}

/// The number format: given, or the narrowest that the analysis shows meets an error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FormatChoice {
    Fixed {
        width: u32,
        frac: u32,
    },
    /// Fewest fraction bits whose analysed error bound on every output is at most
    /// `max_error` (absolute, in the outputs' units), then fewest integer bits.
    Auto {
        max_error: f64,
    },
}

/// Default `--max-error`: a thousandth of a newton-metre per radian (or per rad/s) on
/// each gradient entry, far below what MPC solvers resolve.
pub const DEFAULT_MAX_ERROR: f64 = 1e-3;
/// Default `--stage-depth`: a multiplier and three adds between registers.
pub const DEFAULT_STAGE_DEPTH: u32 = 4;
/// Default shared units.
pub const DEFAULT_MULTIPLIERS: usize = 8;
pub const DEFAULT_ADDERS: usize = 8;

/// The kernels `--backend verilog` builds by default: the gradient and M (the host forms
/// M⁻¹ and ∂q̈ = −M⁻¹ ∂c, as robomorphic computing does), and the frame Jacobian when
/// frames are asked for (the kernel an FPGA controller runs at kHz rates).
pub const DEFAULT_KERNELS: [KernelKind; 3] =
    [KernelKind::RneaGrad, KernelKind::MassMatrix, KernelKind::FrameJacobian];

/// Options of the Verilog backend.
#[derive(Clone, Debug, PartialEq)]
pub struct VerilogOptions {
    pub format: FormatChoice,
    pub rounding: Rounding,
    pub arch: Arch,
    /// Override every joint's speed bound (else the URDF's `<limit velocity>`, else
    /// [`crate::datapath::DEFAULT_QD_MAX`]).
    pub qd_max: Option<f64>,
    /// Override every joint's acceleration bound (else [`crate::datapath::DEFAULT_QDD_MAX`]).
    pub qdd_max: Option<f64>,
    /// Bound on every entry of the forces (else [`crate::datapath::DEFAULT_FORCE_MAX`]).
    pub force_max: Option<f64>,
    /// Which of the module's kernels to build (those without division).
    pub kernels: Vec<KernelKind>,
    /// Also build `fd_grad`'s netlist, with M⁻¹ taken from where this says.
    pub fd_grad: Option<FdGradPartition>,
    /// Bound on every diagonal entry of M⁻¹ (the host partition's input contract; else
    /// sampled from the `minv` kernel, see [`crate::datapath::minv_diagonal`]).
    pub minv_max: Option<f64>,
    /// Override every coordinate's |τ| bound (the chip partition's input; else
    /// [`crate::datapath::DEFAULT_TAU_MAX`]).
    pub tau_max: Option<f64>,
}

/// How `fd_grad`'s netlist splits the seeds' ∇Dynamics between host and chip.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum FdGradPartition {
    /// Robomorphic computing's: the host computes q̈ and M⁻¹ (and sin/cos of q); the chip
    /// computes ∂c/∂u and ∂q̈/∂u = −M⁻¹ ∂c/∂u. The netlist is `<robot>_fd_grad_host`.
    Host,
    /// Everything but sin and cos of q on the chip: from q̇ and τ, M and its LTDL
    /// factorisation (one reciprocal per coordinate), q̈ = M⁻¹(τ − c), ∂c/∂u at that q̈ and
    /// ∂q̈/∂u. The netlist is `<robot>_fd_grad_chip`.
    Chip,
    /// `Chip` where its bounds cover the robot, else `Host` (the netlist's name says which).
    Auto,
}

impl FdGradPartition {
    pub fn name(self) -> &'static str {
        match self {
            FdGradPartition::Host => "host",
            FdGradPartition::Chip => "chip",
            FdGradPartition::Auto => "auto",
        }
    }
}

impl Default for VerilogOptions {
    fn default() -> Self {
        VerilogOptions {
            format: FormatChoice::Auto { max_error: DEFAULT_MAX_ERROR },
            rounding: Rounding::HalfUp,
            arch: Arch::Pipelined { stage_depth: DEFAULT_STAGE_DEPTH },
            qd_max: None,
            qdd_max: None,
            force_max: None,
            kernels: DEFAULT_KERNELS.to_vec(),
            fd_grad: None,
            minv_max: None,
            tau_max: None,
        }
    }
}

/// Resources and timing of one netlist, as `info --json` reports them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NetlistStats {
    pub kernel: KernelKind,
    /// `fd_grad`'s partition (`host`: M⁻¹ is an input).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub partition: Option<FdGradPartition>,
    /// `pipelined` or `shared`.
    pub arch: &'static str,
    /// Pipelined: levels of depth between registers.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage_depth: Option<u32>,
    /// `WIDTH.FRAC`.
    pub format: String,
    pub rounding: Rounding,
    /// Multiplier units (pipelined: one per product, of which `constant_multipliers`
    /// have a constant operand).
    pub multipliers: usize,
    pub constant_multipliers: usize,
    /// Adder/subtractor units (negation included).
    pub adders: usize,
    /// Reciprocal (divider) units: `fd_grad`'s chip partition only (pipelined: one per
    /// coordinate; shared: one).
    #[serde(skip_serializing_if = "is_zero")]
    pub dividers: usize,
    /// With dividers: the clock stages each divider spans ([`Stages::divider_stages`],
    /// [`SharedSchedule::divider_stages`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub divider_stages: Option<u32>,
    /// Data registers (each WIDTH bits), control excluded; a divider's remainder, divisor
    /// and partial quotient count as three at each boundary inside it.
    pub registers: usize,
    /// Clock edges from the edge that takes a state to the one that raises `out_valid`.
    pub latency_cycles: usize,
    /// Clock cycles between successive states.
    pub cycles_per_state: usize,
    /// Pipelined: the cells of the slowest chain between two registers, in order
    /// ([`Stages::slowest_path`]), which sets the clock.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage_path: Option<Vec<&'static str>>,
    /// Non-zero output ports.
    pub outputs: usize,
    /// Analysed worst-case |fixed − exact| over the outputs, for inputs within the bounds.
    pub error_bound: f64,
    /// Largest magnitude the analysis allows any value (must be ≤ the format's maximum).
    pub range_bound: f64,
    /// `fd_grad`'s chip partition: the largest output error measured on seeded states (its
    /// `error_bound` is infinite: the analysis bounds its ranges, not its error).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_error: Option<f64>,
    /// `fd_grad`'s chip partition: the narrowest format whose error the backward analysis
    /// bounds within `--max-error` (`datapath::backward`), if one of at most 120 bits does,
    /// and that bound.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub proven_format: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub proven_error_bound: Option<f64>,
}

/// One kernel planned for hardware: the datapath, its format and analysis, its names.
#[derive(Clone, Debug)]
pub struct Netlist {
    pub kind: KernelKind,
    pub datapath: Datapath,
    pub format: Format,
    pub analysis: Analysis,
    pub bounds: Bounds,
    /// Verilog module name of the top.
    pub top: String,
    pub names: PortNames,
    pub layout: Layout,
    /// The measured error, where the analysis bounds the ranges only (`fd_grad`'s chip
    /// partition): the format's fraction bits rest on it.
    pub measured: Option<Measured>,
    /// `fd_grad`'s chip partition with `--fixed auto`: the narrowest format the error
    /// analysis proves, and its bound (`None` where none of at most 120 bits does).
    pub proven: Option<(Format, f64)>,
}

/// Where each operation sits in time, by architecture (each carries its parameters).
#[derive(Clone, Debug)]
pub enum Layout {
    Pipelined(Stages),
    Shared(SharedSchedule),
}

/// Builds each requested kernel's datapath, picks or checks its format, and schedules it.
pub fn plan(module: &Module, options: &VerilogOptions) -> Result<Vec<Netlist>, VerilogError> {
    // A frame kernel exists only where frames were asked for: without them it is not built.
    let kernels: Vec<KernelKind> = KernelKind::ALL
        .into_iter()
        .filter(|k| options.kernels.contains(k) && !(k.is_frame() && module.function(*k).is_none()))
        .collect();
    if kernels.is_empty() && options.fd_grad.is_none() {
        return Err(VerilogError::NoKernels);
    }
    match options.arch {
        Arch::Pipelined { stage_depth: 0 } => {
            return Err(VerilogError::Arch("--stage-depth must be at least 1".into()))
        }
        Arch::Shared { multipliers, adders } if multipliers == 0 || adders == 0 => {
            return Err(VerilogError::Arch("--multipliers and --adders must be at least 1".into()))
        }
        _ => {}
    }
    let stem = identifier(&module.robot.name);
    let mut bounds = Bounds::new(&module.robot, options.qd_max, options.qdd_max);
    if let Some(f) = options.force_max {
        bounds.force = f;
    }
    let mut out = Vec::new();
    for kind in kernels {
        let f = module.function(kind).ok_or(VerilogError::Missing(kind))?;
        let datapath = Datapath::new(f, module.robot.nv())?;
        out.push(netlist(
            module,
            options,
            kind,
            datapath,
            &bounds,
            format!("{stem}_{}", kind.name()),
            None,
        )?);
    }
    if let Some(partition) = options.fd_grad {
        let build = |p| fd_grad_netlist(module, options, p, &bounds, &stem);
        out.push(match partition {
            // The chip partition where it is built, else the host's; the chip's reason when
            // neither is.
            FdGradPartition::Auto => build(FdGradPartition::Chip)
                .or_else(|chip| build(FdGradPartition::Host).map_err(|_| chip))?,
            p => build(p)?,
        });
    }
    Ok(out)
}

/// `fd_grad`'s netlist in `partition` (not `Auto`).
fn fd_grad_netlist(
    module: &Module,
    options: &VerilogOptions,
    partition: FdGradPartition,
    bounds: &Bounds,
    stem: &str,
) -> Result<Netlist, VerilogError> {
    let robot = &module.robot;
    // The product reads whole columns of ∂c/∂u.
    if robot.specialisation.selects() {
        return Err(VerilogError::Arch(format!(
            "fd_grad's {} partition multiplies whole columns of rnea_grad, and the scene selects gradient entries; drop the scene's [gradient] selection",
            partition.name()
        )));
    }
    let function = |kind| module.function(kind).ok_or(VerilogError::Missing(kind));
    // ∂c/∂q and ∂c/∂q̇ alone: the derivatives with respect to forces are not multiplied.
    let mut dc = function(KernelKind::RneaGrad)?.clone();
    dc.outputs.retain(|o| matches!(o.name, "dc_dq" | "dc_dqd"));
    let dc = Datapath::new(&dc, robot.nv())?;
    let top = format!("{stem}_fd_grad_{}", partition.name());
    let mut bounds = bounds.clone();
    let mut states = None;
    let datapath = match partition {
        FdGradPartition::Auto => unreachable!("plan resolves Auto"),
        FdGradPartition::Host => {
            let diagonal = match options.minv_max {
                Some(b) => vec![b; robot.nv()],
                None => crate::datapath::minv_diagonal(
                    module.function(KernelKind::Minv).ok_or(VerilogError::MinvBound)?,
                    robot,
                ),
            };
            bounds.minv = crate::datapath::minv_entries(&diagonal);
            Datapath::fd_grad_host(&dc, |i, k| robot.root_of(i) == robot.root_of(k))
        }
        FdGradPartition::Chip => {
            if !robot.fext.is_empty() || !robot.contacts.is_empty() {
                return Err(VerilogError::Arch("fd_grad's chip partition takes no external or contact forces (its q̈ would need them); use --fd-grad-netlist host".into()));
            }
            if robot.pivot_floor.is_empty() {
                return Err(VerilogError::Arch("fd_grad's chip partition factorises M, and with coupled mimic joints M is a projection; use --mimic independent or --fd-grad-netlist host".into()));
            }
            if let Some(j) = robot.minv_floor.iter().position(|&f| f <= 0.0) {
                return Err(VerilogError::Arch(format!(
                    "fd_grad's chip partition bounds q̈ through M⁻¹'s diagonal, and nothing bounds M⁻¹'s entry at joint `{}` over all configurations: its body's or its parent body's spatial inertia is not positive definite (none, or a physically implausible `<inertia>`, which loading warns of), or it is prismatic under a moving body; use --fd-grad-netlist host",
                    comment_text(&robot.joint_names[j])
                )));
            }
            if let Some(j) = robot.pivot_floor.iter().position(|&f| f <= 0.0) {
                return Err(VerilogError::Arch(format!(
                    "fd_grad's chip partition divides by the pivots of M's factorisation, and the body of joint `{}` has no inertia about its axis (none, or a physically implausible `<inertia>`), so nothing bounds its pivot away from zero; use --fd-grad-netlist host",
                    comment_text(&robot.joint_names[j])
                )));
            }
            if let Some(t) = options.tau_max {
                for b in bounds.tau.iter_mut().filter(|b| **b > 0.0) {
                    *b = t;
                }
            }
            let rnea = function(KernelKind::Rnea)?;
            states = Some(crate::datapath::chip_states(
                rnea,
                robot,
                &bounds,
                crate::datapath::MEASURED_STATES,
            ));
            let bias = Datapath::new(rnea, robot.nv())?;
            let mass = Datapath::new(function(KernelKind::MassMatrix)?, robot.nv())?;
            crate::datapath::fd_grad_chip(
                &bias,
                &mass,
                &dc,
                &robot.parents,
                &robot.pivot_floor,
                &robot.minv_floor,
                &bounds.tau.iter().map(|&b| b > 0.0).collect::<Vec<_>>(),
            )
        }
    };
    let states = states.as_deref();
    netlist(module, options, KernelKind::FdGrad, datapath, &bounds, top, states)
}

/// Where a refused datapath's widest value is computed (at the best format tried): what a
/// user needs to see why no format fits.
fn widest(
    dp: &Datapath,
    bounds: &Bounds,
    frac: u32,
    rounding: Rounding,
    robot: &crate::ir::Robot,
) -> String {
    let a = analyse(dp, bounds, frac, rounding);
    let (at, size) = (0..dp.nodes.len())
        .map(|i| (i, a.lo[i].abs().max(a.hi[i].abs())))
        .fold((0, 0.0f64), |best, x| if x.1 > best.1 { x } else { best });
    match dp.links[at] {
        Some(j) => {
            let j = j as usize;
            let mut depth = 1;
            let mut k = j;
            while let Some(p) = robot.parents[k] {
                depth += 1;
                k = p;
            }
            format!(
                "its widest value, bounded by {size:.1e}, is computed for joint `{}` ({depth} joints from the root): the interval analysis bounds vectors entry by entry (one joint's rotation of two entries by their norm, but sums of several entries by |a| + |b|), so bounds grow along a chain faster than the values and a deep tree needs more bits than its values do",
                comment_text(&robot.joint_names[j])
            )
        }
        None => format!("its widest value, bounded by {size:.1e}, is in the product with M⁻¹"),
    }
}

/// One datapath's netlist: its format (given and checked, or chosen) and its schedule.
fn netlist(
    module: &Module,
    options: &VerilogOptions,
    kind: KernelKind,
    datapath: Datapath,
    bounds: &Bounds,
    top: String,
    measured_on: Option<&[ChipState]>,
) -> Result<Netlist, VerilogError> {
    let mut proven = None;
    let (format, analysis, measured) = match (measured_on, options.format) {
        (Some(states), _) => {
            let (format, analysis, measured) = measured_format(&datapath, options, bounds, states)?;
            if let FormatChoice::Auto { max_error } = options.format {
                proven = choose_format(&datapath, bounds, options.rounding, max_error)
                    .ok()
                    .map(|(f, a)| (f, a.output_error));
            }
            (format, analysis, Some(measured))
        }
        (None, FormatChoice::Fixed { width, frac }) => {
            let format = Format::new(width, frac, options.rounding)?;
            let analysis = analyse(&datapath, bounds, frac, options.rounding);
            analysis.check(&datapath, &format)?;
            (format, analysis, None)
        }
        (None, FormatChoice::Auto { max_error }) => {
            let (format, analysis) = choose_format(&datapath, bounds, options.rounding, max_error)
                .map_err(|error| match error {
                    FixedError::Unreachable { frac, .. } => {
                        let why = widest(&datapath, bounds, frac, options.rounding, &module.robot);
                        VerilogError::Refused { error, why }
                    }
                    e => e.into(),
                })?;
            (format, analysis, None)
        }
    };
    let layout = layout_of(&datapath, options.arch, format.width);
    let names = PortNames::new(&module.robot, &datapath);
    Ok(Netlist {
        kind,
        datapath,
        format,
        analysis,
        bounds: bounds.clone(),
        top,
        names,
        layout,
        measured,
        proven,
    })
}

fn layout_of(datapath: &Datapath, arch: Arch, width: u32) -> Layout {
    match arch {
        Arch::Shared { multipliers, adders } => {
            Layout::Shared(SharedSchedule::new(datapath, multipliers, adders, width))
        }
        Arch::Pipelined { stage_depth } => {
            Layout::Pipelined(Stages::new(datapath, stage_depth, width))
        }
    }
}

/// The format of a datapath whose error the analysis cannot bound (module `measure`): the
/// ranges proven, the fraction bits from the error measured on `states`.
fn measured_format(
    datapath: &Datapath,
    options: &VerilogOptions,
    bounds: &Bounds,
    states: &[ChipState],
) -> Result<(Format, Analysis, Measured), VerilogError> {
    match options.format {
        FormatChoice::Fixed { width, frac } => {
            let format = Format::new(width, frac, options.rounding)?;
            let analysis = analyse(datapath, bounds, frac, options.rounding);
            let needed = analysis.range();
            if !(needed.is_finite() && needed <= format.max_value()) {
                return Err(FixedError::Range {
                    kernel: datapath.kernel.to_string(),
                    width,
                    frac,
                    needed,
                    max: format.max_value(),
                }
                .into());
            }
            let measured = measure(datapath, &format, states);
            Ok((format, analysis, measured))
        }
        FormatChoice::Auto { max_error } => {
            choose_format_measured(datapath, bounds, options.rounding, max_error, states).map_err(
                |error| {
                    let range = analyse(datapath, bounds, 0, options.rounding).range();
                    VerilogError::Refused {
                        error,
                        why: format!(
                            "the proven range of its values is {range:.1e}, so {} integer bits leave too few for the fraction",
                            range.log2().ceil() + 1.0
                        ),
                    }
                },
            )
        }
    }
}

impl Netlist {
    /// The architecture and its parameters.
    pub fn arch(&self) -> Arch {
        match &self.layout {
            Layout::Pipelined(st) => Arch::Pipelined { stage_depth: st.stage_depth },
            Layout::Shared(s) => Arch::Shared { multipliers: s.multipliers, adders: s.adders },
        }
    }

    pub fn stats(&self) -> NetlistStats {
        let dp = &self.datapath;
        let (muls, adds) = dp.op_counts();
        let (
            multipliers,
            constant_multipliers,
            adders,
            dividers,
            registers,
            latency_cycles,
            cycles_per_state,
        ) = match &self.layout {
            Layout::Shared(s) => (
                s.multipliers,
                0,
                s.adders,
                s.dividers,
                s.registers + cells::divider_registers(s.dividers, s.divider_stages),
                s.cycles + 1,
                s.cycles + 1,
            ),
            Layout::Pipelined(st) => (
                muls,
                dp.constant_muls(),
                adds,
                dp.reciprocals(),
                st.registers(dp),
                st.count as usize + 1,
                1,
            ),
        };
        NetlistStats {
            kernel: self.kind,
            partition: (self.kind == KernelKind::FdGrad).then_some(if self.reads_minv() {
                FdGradPartition::Host
            } else {
                FdGradPartition::Chip
            }),
            arch: self.arch().name(),
            stage_depth: match &self.layout {
                Layout::Pipelined(st) => Some(st.stage_depth),
                Layout::Shared(_) => None,
            },
            format: self.format.label(),
            rounding: self.format.rounding,
            multipliers,
            constant_multipliers,
            adders,
            dividers,
            divider_stages: match &self.layout {
                _ if dividers == 0 => None,
                Layout::Pipelined(st) => Some(st.divider_stages),
                Layout::Shared(s) => Some(s.divider_stages),
            },
            registers,
            latency_cycles,
            cycles_per_state,
            stage_path: match &self.layout {
                Layout::Pipelined(st) => Some(st.slowest_path(dp)),
                Layout::Shared(_) => None,
            },
            outputs: dp.nonzero_outputs().len(),
            error_bound: self.analysis.output_error,
            range_bound: match self.measured {
                Some(_) => self.analysis.range(),
                None => self.analysis.needed,
            },
            measured_error: self.measured.as_ref().map(|m| m.error),
            proven_format: self.proven.map(|(f, _)| f.label()),
            proven_error_bound: self.proven.map(|(_, e)| e),
        }
    }

    /// Whether the netlist takes M⁻¹ from the host (`fd_grad`'s host partition).
    pub fn reads_minv(&self) -> bool {
        self.datapath.ports.iter().any(|p| matches!(p, crate::datapath::Port::Minv(..)))
    }

    /// The netlist file's name and the testbench's.
    pub fn file_names(&self) -> (String, String) {
        (
            Target::Verilog.file_name(&self.top),
            Target::Verilog.file_name(&format!("{}_tb", self.top)),
        )
    }

    /// The netlist (cells and top module) as Verilog-2005.
    pub fn verilog(&self, robot: &crate::ir::Robot) -> String {
        let mut out = self.header(robot);
        let divider = match (&self.layout, self.datapath.reciprocals()) {
            (_, 0) => Divider::None,
            (Layout::Pipelined(st), _) => Divider::Pipelined(st.divider_stages),
            (Layout::Shared(s), _) => Divider::Pipelined(s.divider_stages),
        };
        out.push_str(&cells::cells(&self.top, &self.format, divider));
        match &self.layout {
            Layout::Pipelined(st) => out.push_str(&pipelined::top(self, st)),
            Layout::Shared(s) => out.push_str(&shared::top(self, s)),
        }
        out
    }

    /// `module <top> (` … `);`: the handshake, the input ports, `out_valid`, the output
    /// ports and `overflow`, in the order the header documents.
    fn module_ports(&self) -> String {
        let w = self.format.width;
        let mut v = format!("module {} (\n", self.top);
        v.push_str("    input  wire clk,\n    input  wire rst,\n    input  wire in_valid,\n    output wire in_ready,\n");
        for name in &self.names.inputs {
            v.push_str(&format!("    input  wire signed [{}:0] {name},\n", w - 1));
        }
        v.push_str("    output wire out_valid,\n");
        for (name, _) in &self.names.outputs {
            v.push_str(&format!("    output wire signed [{}:0] {name},\n", w - 1));
        }
        v.push_str("    output wire overflow\n);\n");
        v
    }

    /// The self-checking-free testbench: reads states from a hex file and writes outputs.
    pub fn testbench(&self) -> String {
        testbench::testbench(self)
    }

    fn header(&self, robot: &crate::ir::Robot) -> String {
        let s = self.stats();
        let mut h = String::new();
        h.push_str(&format!(
            "// Generated by grid-gen {} from robot \"{}\". Do not edit.\n",
            env!("CARGO_PKG_VERSION"),
            comment_text(&robot.name)
        ));
        h.push_str(&crate::back::source_line(&robot.source));
        h.push_str(&crate::back::specialisation_lines(robot));
        if self.reads_minv() {
            h.push_str("// fd_grad, host partition (robomorphic computing's): dqdd_dq and dqdd_dqd = -Minv * (dc_dq, dc_dqd) at the qdd and Minv the host computed for this state.\n");
        } else if self.measured.is_some() {
            h.push_str("// fd_grad, chip partition: M and its LTDL factorisation (one reciprocal per state-dependent pivot), qdd = Minv (tau - c), dqdd_dq and dqdd_dqd = -Minv * (dc_dq, dc_dqd) at that qdd; the host computes sin and cos of q only.\n");
        } else {
            h.push_str(&format!("// {}: {}\n", self.kind.name(), comment_text(self.kind.doc())));
        }
        h.push_str(&format!(
            "// Signed fixed point {} ({} bits, {} after the point; multipliers {}; every result saturates and sets `overflow`).\n",
            self.format.label(),
            self.format.width,
            self.format.frac,
            match self.format.rounding {
                Rounding::Truncate => "truncate (keep the high bits)",
                Rounding::HalfUp => "round half up",
            }
        ));
        match self.arch() {
            Arch::Pipelined { stage_depth } => h.push_str(&format!(
                "// Architecture: pipelined, registers every {stage_depth} levels; one state per clock, latency {} clocks.\n",
                s.latency_cycles
            )),
            Arch::Shared { multipliers, adders } => {
                h.push_str(&format!("// Architecture: shared, {multipliers} multipliers and {adders} adders; one state every {} clocks.\n", s.cycles_per_state))
            }
        }
        let dividers = match (s.dividers, s.divider_stages) {
            (0, _) | (_, None) => String::new(),
            (d, Some(k)) => {
                let plural = if d == 1 { "" } else { "s" };
                format!(", {d} divider{plural} pipelined over {k} stages")
            }
        };
        h.push_str(&format!(
            "// Units: {} multipliers ({} by a constant), {} adders{dividers}, {} data registers.\n",
            s.multipliers, s.constant_multipliers, s.adders, s.registers
        ));
        // Forces appear in the bounds only where the netlist takes them.
        let forces = if self.datapath.ports.iter().any(|p| {
            matches!(
                p,
                crate::datapath::Port::Value(crate::ir::Input::Fext | crate::ir::Input::Lambda, _)
            )
        }) {
            format!(", |fext|, |lambda| <= {} per entry", self.bounds.force)
        } else {
            String::new()
        };
        let minv = if self.reads_minv() {
            let nv = self.bounds.qd.len();
            let diagonal: Vec<f64> = (0..nv).map(|j| self.bounds.minv[j * nv + j]).collect();
            format!(", Minv's diagonal <= {} (the host checks it; off the diagonal, |Minv_ik| <= sqrt(Minv_ii Minv_kk))", list(&diagonal))
        } else {
            String::new()
        };
        match &self.measured {
            None => h.push_str(&format!(
                "// Analysed for |qd| <= {}, |qdd| <= {} (per joint, in order){forces}{minv}: every value within {:.6e}; every output within {:.6e} of exact.\n",
                list(&self.bounds.qd),
                list(&self.bounds.qdd),
                s.range_bound,
                s.error_bound
            )),
            Some(m) => h.push_str(&format!(
                "// Analysed for |qd| <= {}, |tau| <= {} (per joint, in order): every exact value within {:.6e} (M's pivots and Minv's diagonal bounded from the link inertias). The error is measured: at most {:.6e} on the outputs over {} seeded states with |qdd| <= {}; the backward error analysis {}{}; a saturation anywhere sets `overflow`.\n",
                list(&self.bounds.qd),
                list(&self.bounds.tau),
                s.range_bound,
                m.error,
                m.states,
                list(&self.bounds.qdd),
                match s.error_bound {
                    b if b.is_finite() => format!("bounds it by {b:.6e} at this format"),
                    _ => "does not bound it at this format".to_string(),
                },
                match self.proven {
                    Some((f, e)) => format!(" (at {}: {e:.6e})", f.label()),
                    None => String::new(),
                },
            )),
        }
        h.push_str("//\n// Ports (inputs and outputs raw two's complement, value = raw * 2^-FRAC; outputs valid while out_valid is high):\n");
        h.push_str(&self.names.doc(robot));
        h.push('\n');
        h
    }
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

fn list(v: &[f64]) -> String {
    let all_same = v.windows(2).all(|w| w[0] == w[1]);
    if all_same && !v.is_empty() {
        format!("{}", v[0])
    } else {
        format!("[{}]", v.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join(", "))
    }
}

/// Every file of the Verilog target: each netlist and its testbench.
pub fn emit(module: &Module, options: &VerilogOptions) -> Result<Vec<GeneratedFile>, VerilogError> {
    let mut files = Vec::new();
    for n in plan(module, options)? {
        let (v, tb) = n.file_names();
        files.push(GeneratedFile { name: v, contents: n.verilog(&module.robot) });
        files.push(GeneratedFile { name: tb, contents: n.testbench() });
    }
    Ok(files)
}

/// Why the Verilog backend could not print a module.
#[derive(Debug, thiserror::Error)]
pub enum VerilogError {
    #[error("Verilog: {0}")]
    Fixed(#[from] FixedError),
    #[error("Verilog: {error}; {why}")]
    Refused { error: FixedError, why: String },
    #[error("Verilog: no datapath kernel selected (available: rnea, rnea_grad, mass_matrix)")]
    NoKernels,
    #[error("Verilog: kernel `{0}` was not lowered")]
    Missing(crate::ir::KernelKind),
    #[error("Verilog: {0}")]
    Arch(String),
    #[error("Verilog: fd_grad's host partition bounds its M⁻¹ input from the minv kernel, which was not generated; generate minv too, or give --minv-max")]
    MinvBound,
}
