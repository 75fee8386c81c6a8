//! `grid-gen accuracy`: every kernel's error in each number format, measured against the
//! double-double value of its graph, with cond(M) over the states: the
//! speed/accuracy trade, measured rather than assumed.
//!
//! The true value is the kernel's graph lowered without constant folding (so every model
//! constant is the f64 the model holds) and evaluated in double-double ([`crate::numerics::Dd`],
//! about 106 bits): the exact dynamics of the f64 model at the f64 state. Each format runs
//! the folded graph that the backends emit: f64 and f32 as the generated Rust's portable
//! copy computes it, fixed point through the Verilog datapath's bit-exact model, and any
//! other backend (WGSL on an adapter) through a caller-supplied runner.

mod plot;
mod states;

use serde::Serialize;

pub use plot::svg;
pub use states::{random_states, Rng};

use crate::datapath::{
    choose_format, quantize_ports, Bounds, Datapath, FixedError, Format, Rounding,
};
use crate::eval::{check_states, EvalError, State, StatesFile};
use crate::ir::{self, Function, Gradient, Input, KernelKind, LowerError, LowerOptions, Solve};
use crate::model::Model;
use crate::reference;

/// A number format to measure.
#[derive(Clone, Debug, PartialEq)]
pub enum NumberFormat {
    F64,
    F32,
    /// Signed fixed point through the Verilog datapath's bit-exact model.
    Fixed(Format),
    /// For each kernel, the narrowest fixed-point format whose analysed error bound meets
    /// `max_error` on the input bounds: what `--backend verilog --fixed auto` builds.
    FixedAuto {
        max_error: f64,
        rounding: Rounding,
    },
    /// f32 except the nodes the first-order error analysis puts in f64 to bound each
    /// output's relative error by `target` ([`crate::numerics::precision`]), planned at
    /// [`MIXED_PLAN_STATES`] states of their own (not the measured ones).
    Mixed {
        target: f64,
    },
}

/// States the mixed-precision plan is analysed at: seeded random states
/// ([`random_states`], seed [`MIXED_PLAN_SEED`]), apart from the states it is measured on.
pub const MIXED_PLAN_STATES: usize = 16;
pub const MIXED_PLAN_SEED: u64 = 0x6d_6978_6564;

/// The mixed-precision target of a bare `mixed`: f64-like accuracy, 1e-12 relative.
pub const DEFAULT_MIXED_TARGET: f64 = 1e-12;

/// Plans a kernel's mixed precision (see [`NumberFormat::Mixed`]).
pub fn mixed_plan(
    model: &Model,
    gravity: [f64; 3],
    f: &Function,
    target: f64,
) -> crate::numerics::precision::Plan {
    let states = random_states(model, gravity, MIXED_PLAN_STATES, MIXED_PLAN_SEED, None, None);
    crate::numerics::precision::plan(f, &kernel_states(f, &states), target)
}

/// `f`'s arguments (in its input order) at each state of `file` that has the input it
/// needs (q̈ for the RNEA kernels, τ for `fd*`).
pub fn kernel_states(f: &Function, file: &StatesFile) -> Vec<Vec<Vec<f64>>> {
    file.states
        .iter()
        .filter_map(|s| {
            let u = match u_of(f.kind, s) {
                None => &[][..],
                Some(Some(u)) => &u[..],
                Some(None) => return None,
            };
            Some(
                kernel_inputs(f, &[&s.q[..], &s.qd[..], u])
                    .into_iter()
                    .map(|v| v.to_vec())
                    .collect(),
            )
        })
        .collect()
}

impl NumberFormat {
    pub fn label(&self) -> String {
        match self {
            NumberFormat::F64 => "f64".into(),
            NumberFormat::F32 => "f32".into(),
            NumberFormat::Fixed(f) => format!("fixed {}.{} {}", f.width, f.frac, f.rounding.name()),
            NumberFormat::FixedAuto { max_error, rounding } => {
                format!("fixed auto ≤{max_error:e} {}", rounding.name())
            }
            NumberFormat::Mixed { target } => format!("mixed ≤{target:e}"),
        }
    }

    /// `f64`, `f32`, `fixed:WIDTH.FRAC` or `fixed:auto` (with `rounding` and, for auto,
    /// `max_error`).
    pub fn parse(s: &str, rounding: Rounding, max_error: f64) -> Result<NumberFormat, String> {
        match s {
            "f64" => Ok(NumberFormat::F64),
            "f32" => Ok(NumberFormat::F32),
            "fixed:auto" => Ok(NumberFormat::FixedAuto { max_error, rounding }),
            "mixed" => Ok(NumberFormat::Mixed { target: DEFAULT_MIXED_TARGET }),
            _ if s.starts_with("mixed:") => match s["mixed:".len()..].parse::<f64>() {
                Ok(t) if t > 0.0 && t.is_finite() => Ok(NumberFormat::Mixed { target: t }),
                _ => Err(format!(
                    "`{s}`: mixed:TARGET takes a positive relative error, e.g. mixed:1e-10"
                )),
            },
            _ => match s.strip_prefix("fixed:").and_then(|f| Format::parse(f, rounding)) {
                Some(Ok(f)) => Ok(NumberFormat::Fixed(f)),
                Some(Err(e)) => Err(e.to_string()),
                None => Err(format!("unknown number format `{s}`")),
            },
        }
    }
}

/// Runs one kernel on a batch through another backend: `(kind, q, qd, u)` state-major
/// (`u` is q̈ or τ, empty for kernels without it), outputs concatenated per state.
pub type Runner<'a> =
    dyn FnMut(KernelKind, &[f64], &[f64], &[f64]) -> Result<Vec<f64>, String> + 'a;

/// A backend measured next to the number formats, e.g. WGSL on a GPU.
pub struct Backend<'a> {
    pub label: String,
    pub run: Box<Runner<'a>>,
}

/// Median and largest of a set of values.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Spread {
    pub median: f64,
    pub max: f64,
}

impl Spread {
    fn of(values: &mut [f64]) -> Option<Spread> {
        if values.is_empty() {
            return None;
        }
        values.sort_by(f64::total_cmp);
        let n = values.len();
        let median =
            if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) };
        Some(Spread { median, max: values[n - 1] })
    }
}

/// One kernel in one format.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub kernel: KernelKind,
    pub format: String,
    /// `fixed:auto`: the `WIDTH.FRAC` the analysis chose for this kernel.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fixed: Option<String>,
    /// Operations of the graph this format runs (a proxy for time; the times of the
    /// generated kernels are measured by `scripts/bench.sh`).
    pub ops: usize,
    /// States the kernel ran on (those with q̈ for the RNEA kernels, with τ for `fd*`).
    pub states: usize,
    /// Relative error per state, `max |Δ| / max |true|` over each output, the worst
    /// output taken: median and largest over the states without overflow.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<Spread>,
    /// The largest absolute error of any entry over those states (what the fixed-point
    /// analysis bounds, `--max-error`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_abs_error: Option<f64>,
    /// Mixed precision: the operations the plan runs in f64, as `W of N in f64`, and the
    /// analysis's first-order bound at the planning states.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mixed: Option<String>,
    /// Fixed point: states whose datapath saturated (their numbers are excluded above).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub overflowed: Option<usize>,
    /// Time per call of the generated Rust kernel in this format (portable copy), when
    /// measured (`accuracy --time`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_ns: Option<f64>,
    /// Why there is no error (the format cannot run this kernel).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skipped: Option<String>,
}

/// Everything `grid-gen accuracy` prints.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub robot: String,
    pub nv: usize,
    pub gravity: [f64; 3],
    pub states: usize,
    /// Where the states came from.
    pub source: String,
    /// cond(M) = λmax / λmin over the states (infinite where M is singular).
    pub cond_m: Option<Spread>,
    /// The worst-case relative error a backward-stable recursion guarantees through M⁻¹
    /// (`minv`, `fd`, `fd_grad`) at the largest cond(M): 10 · nv · u · cond(M), with u the
    /// unit roundoff of f64 and of f32 (the constant of the identity tests). Near 1, that
    /// format has no digits it can promise; the measured errors are usually far smaller.
    pub bound_through_minv: Option<Bounds2>,
    pub rows: Vec<Row>,
    /// The mixed-precision kernels measured, as planned, for timing the emitted Rust
    /// (`accuracy --time`) without planning them again.
    #[serde(skip)]
    pub mixed: Vec<MixedKernel>,
}

/// One (mixed format, kernel) pair of a [`Report`]: the row's format label, the folded
/// kernel and its plan's f64 nodes.
#[derive(Clone, Debug)]
pub struct MixedKernel {
    pub label: String,
    pub function: Function,
    pub wide: Vec<bool>,
}

/// [`Report::bound_through_minv`] per float format.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Bounds2 {
    pub f64: f64,
    pub f32: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum AccuracyError {
    #[error(transparent)]
    States(#[from] EvalError),
    #[error(transparent)]
    Lower(#[from] LowerError),
    #[error("{label}, kernel `{kernel}`: {message}")]
    Backend { label: String, kernel: KernelKind, message: String },
    #[error("kernel `{kernel}`: {error}")]
    Fixed { kernel: KernelKind, error: FixedError },
    #[error("`accuracy` does not measure kernels that take external or contact forces yet; leave out --fext, --contact and the scene's [external_forces] and [[contact]] (the forces' own arithmetic is checked against the reference by the tests)")]
    Forces,
}

/// The kernels `accuracy` measures by default: all six, less those M's singularity blocks.
pub fn default_kernels(model: &Model) -> Vec<KernelKind> {
    // The step kernels are held to the reference by tests/step.rs and the Lie-group ones by
    // tests/lie.rs; `accuracy` skips them.
    KernelKind::for_model(model)
        .into_iter()
        .filter(|k| (model.singular.is_none() || !k.needs_minv()) && !k.is_step() && !k.is_lie())
        .collect()
}

/// The input `u` of a kernel at a state: q̈ for the RNEA kernels, τ for `fd*`, none else.
fn u_of(kind: KernelKind, s: &State) -> Option<Option<&Vec<f64>>> {
    match kind.inputs().get(2) {
        Some(Input::Qdd) => Some(s.qdd.as_ref()),
        Some(Input::Tau) => Some(s.tau.as_ref()),
        _ => None,
    }
}

/// What to measure.
#[derive(Clone, Debug)]
pub struct Options {
    pub kernels: Vec<KernelKind>,
    pub formats: Vec<NumberFormat>,
    pub gravity: [f64; 3],
    pub gradient: Gradient,
    /// How `fd_grad` applies M⁻¹ (its accuracy differs per route on deep chains).
    pub solve: Solve,
    /// Input bounds for `fixed:auto` (as `--qd-max` / `--qdd-max` of the Verilog backend).
    pub qd_max: Option<f64>,
    pub qdd_max: Option<f64>,
}

/// Measures every kernel of `options` in each format (and backend) on `file`'s states.
pub fn measure<'a>(
    model: &Model,
    file: &'a StatesFile,
    source: &str,
    options: &Options,
    backends: &mut [Backend],
) -> Result<Report, AccuracyError> {
    check_states(model, file)?;
    if model.nfext() + model.nlambda() > 0 {
        return Err(AccuracyError::Forces);
    }
    let (nv, gravity, kernels, formats) =
        (model.nv(), options.gravity, &options.kernels, &options.formats);
    let lower = LowerOptions {
        kernels: kernels.clone(),
        gradient: options.gradient,
        solve: options.solve,
        ..LowerOptions::default()
    };
    let exact = ir::lower(model, gravity, &LowerOptions { fold: false, ..lower.clone() })?;
    let fast = ir::lower(model, gravity, &lower)?;
    let bounds = Bounds::new(&fast.robot, options.qd_max, options.qdd_max);
    let mut rows = Vec::new();
    let mut mixed = Vec::new();
    for &kind in kernels.iter() {
        let (Some(exact_f), Some(f)) = (exact.function(kind), fast.function(kind)) else {
            continue;
        };
        if kind.is_step() || kind.is_lie() {
            let skipped = Some(
                if kind.is_step() {
                    "the step kernels take the actuated joints' forces; tests/step.rs measures them"
                } else {
                    "the Lie-group kernels take a second configuration or a tangent; tests/lie.rs measures them"
                }
                .to_string(),
            );
            let ops = f
                .nodes
                .iter()
                .enumerate()
                .filter(|(i, _)| f.is_operation(ir::Id(*i as u32)))
                .count();
            for format in formats.iter() {
                rows.push(Row {
                    kernel: kind,
                    format: format.label(),
                    fixed: None,
                    ops,
                    states: 0,
                    error: None,
                    max_abs_error: None,
                    mixed: None,
                    overflowed: None,
                    time_ns: None,
                    skipped: skipped.clone(),
                });
            }
            continue;
        }
        let chosen: Vec<&State> =
            file.states.iter().filter(|s| !matches!(u_of(kind, s), Some(None))).collect();
        let args: Vec<[&[f64]; 3]> = chosen
            .iter()
            .map(|s| [&s.q[..], &s.qd[..], u_of(kind, s).flatten().map_or(&[][..], |v| &v[..])])
            .collect();
        let inputs = |a: &[&'a [f64]; 3]| kernel_inputs(f, a);
        let truth: Vec<Vec<Vec<f64>>> = args
            .iter()
            .map(|a| {
                exact_f
                    .eval_as::<crate::numerics::Dd>(&inputs(a))
                    .into_iter()
                    .map(|o| o.into_iter().map(|x| x.to_f64()).collect())
                    .collect()
            })
            .collect();
        let ops =
            f.nodes.iter().enumerate().filter(|(i, _)| f.is_operation(ir::Id(*i as u32))).count();
        let row = |format: String,
                   fixed: Option<String>,
                   errors: Option<Vec<(f64, f64)>>,
                   overflowed: Option<usize>,
                   skipped: Option<String>| Row {
            kernel: kind,
            format,
            fixed,
            ops,
            states: chosen.len(),
            error: errors
                .as_ref()
                .and_then(|e| Spread::of(&mut e.iter().map(|x| x.0).collect::<Vec<_>>())),
            max_abs_error: errors
                .as_ref()
                .filter(|e| !e.is_empty())
                .map(|e| e.iter().map(|x| x.1).fold(0.0, f64::max)),
            overflowed,
            mixed: None,
            time_ns: None,
            skipped,
        };
        for format in formats.iter() {
            match format {
                NumberFormat::F64 => {
                    let e = args
                        .iter()
                        .zip(&truth)
                        .map(|(a, t)| error(&f.eval(&inputs(a)), t))
                        .collect();
                    rows.push(row(format.label(), None, Some(e), None, None));
                }
                NumberFormat::F32 => {
                    let e = args
                        .iter()
                        .zip(&truth)
                        .map(|(a, t)| error(&widen(f.eval_f32(&inputs(a))), t))
                        .collect();
                    rows.push(row(format.label(), None, Some(e), None, None));
                }
                NumberFormat::Mixed { target } => {
                    let plan = mixed_plan(model, gravity, f, *target);
                    let e = args
                        .iter()
                        .zip(&truth)
                        .map(|(a, t)| error(&f.eval_mixed(&inputs(a), &plan.wide), t))
                        .collect();
                    let (wide, all) = plan.wide_operations(f);
                    let mut r = row(format.label(), None, Some(e), None, None);
                    r.mixed = Some(format!(
                        "{wide} of {all} ops in f64, bound {:.1e} (all f32: {:.1e})",
                        plan.bound, plan.all_f32_bound
                    ));
                    rows.push(r);
                    mixed.push(MixedKernel {
                        label: format.label(),
                        function: f.clone(),
                        wide: plan.wide,
                    });
                }
                NumberFormat::Fixed(_) | NumberFormat::FixedAuto { .. } => {
                    let dp = match Datapath::new(f, nv) {
                        Ok(dp) => dp,
                        Err(FixedError::Unsupported { .. }) => {
                            let why = "it divides; the fixed-point datapath has +, −, × only (rnea, rnea_grad, mass_matrix)";
                            rows.push(row(format.label(), None, None, None, Some(why.into())));
                            continue;
                        }
                        Err(error) => return Err(AccuracyError::Fixed { kernel: kind, error }),
                    };
                    let fmt = match format {
                        NumberFormat::FixedAuto { max_error, rounding } => {
                            choose_format(&dp, &bounds, *rounding, *max_error)
                                .map_err(|error| AccuracyError::Fixed { kernel: kind, error })?
                                .0
                        }
                        NumberFormat::Fixed(fmt) => *fmt,
                        _ => unreachable!("matched above"),
                    };
                    let (mut errors, mut overflowed) = (Vec::new(), 0);
                    for (s, t) in chosen.iter().zip(&truth) {
                        let zeros = vec![0.0; nv];
                        let qdd = s.qdd.as_ref().unwrap_or(&zeros);
                        let tau = s.tau.as_ref().unwrap_or(&zeros);
                        let (ports, input_overflow) =
                            quantize_ports(&dp, &fmt, &s.q, &s.qd, qdd, tau);
                        let run = dp.run(&fmt, &ports);
                        if run.overflow || input_overflow {
                            overflowed += 1;
                            continue;
                        }
                        let got: Vec<Vec<f64>> = run
                            .outputs
                            .iter()
                            .map(|o| o.iter().map(|&r| fmt.to_f64(r)).collect())
                            .collect();
                        errors.push(error(&got, t));
                    }
                    let auto = matches!(format, NumberFormat::FixedAuto { .. })
                        .then(|| format!("{}.{}", fmt.width, fmt.frac));
                    rows.push(row(format.label(), auto, Some(errors), Some(overflowed), None));
                }
            }
        }
        for b in backends.iter_mut() {
            let flat =
                |k: usize| -> Vec<f64> { args.iter().flat_map(|a| a[k].iter().copied()).collect() };
            let velocity = f.inputs().contains(&Input::Qd);
            let out =
                (b.run)(kind, &flat(0), &if velocity { flat(1) } else { Vec::new() }, &flat(2))
                    .map_err(|message| AccuracyError::Backend {
                        label: b.label.clone(),
                        kernel: kind,
                        message,
                    })?;
            let per = out.len() / chosen.len().max(1);
            let e = truth
                .iter()
                .enumerate()
                .map(|(k, t)| {
                    let mut values = &out[k * per..(k + 1) * per];
                    let got: Vec<Vec<f64>> = t
                        .iter()
                        .map(|o| {
                            let (head, rest) = values.split_at(o.len());
                            values = rest;
                            head.to_vec()
                        })
                        .collect();
                    error(&got, t)
                })
                .collect();
            rows.push(row(b.label.clone(), None, Some(e), None, None));
        }
    }
    let mut conds: Vec<f64> = file
        .states
        .iter()
        .map(|s| {
            let eig = reference::crba(model, &s.q).symmetric_eigenvalues();
            if eig.min() > 0.0 {
                eig.max() / eig.min()
            } else {
                f64::INFINITY
            }
        })
        .collect();
    let cond_m = Spread::of(&mut conds);
    let bound = |u: f64, c: f64| (10.0 * nv as f64 * u * c).min(f64::MAX);
    let bound_through_minv = cond_m.map(|c| Bounds2 {
        f64: bound(f64::EPSILON / 2.0, c.max),
        f32: bound(f32::EPSILON as f64 / 2.0, c.max),
    });
    Ok(Report {
        robot: model.name.clone(),
        nv,
        gravity,
        states: file.states.len(),
        source: source.to_string(),
        cond_m,
        bound_through_minv,
        rows,
        mixed,
    })
}

/// The arguments of `f` in its input order, from `[q, q̇, u]`.
fn kernel_inputs<'a>(f: &Function, a: &[&'a [f64]; 3]) -> Vec<&'a [f64]> {
    f.inputs()
        .iter()
        .map(|i| {
            if *i == Input::Q {
                a[0]
            } else if *i == Input::Qd {
                a[1]
            } else {
                a[2]
            }
        })
        .collect()
}

fn widen(out: Vec<Vec<f32>>) -> Vec<Vec<f64>> {
    out.into_iter().map(|o| o.into_iter().map(f64::from).collect()).collect()
}

/// The worst output's `max |got − true| / max |true|` (absolute where the truth is 0),
/// and the largest absolute error of any entry.
fn error(got: &[Vec<f64>], truth: &[Vec<f64>]) -> (f64, f64) {
    got.iter().zip(truth).fold((0.0f64, 0.0f64), |(rel, abs), (g, t)| {
        let scale = t.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let diff = g.iter().zip(t).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        (rel.max(if scale > 0.0 { diff / scale } else { diff }), abs.max(diff))
    })
}

impl Report {
    /// Puts each f64 and f32 row's time per call (portable copy) beside its error.
    pub fn add_times(&mut self, times: &[crate::timing::KernelTime]) {
        for r in &mut self.rows {
            let scalar = match r.format.as_str() {
                "f64" | "f32" => r.format.as_str(),
                f if f.starts_with("mixed") => f,
                _ => continue,
            };
            r.time_ns = times
                .iter()
                .find(|t| t.kernel == r.kernel && t.scalar == scalar && t.copy == "portable")
                .map(|t| t.ns_per_call);
        }
    }

    /// The table `grid-gen accuracy` prints.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "accuracy of `{}` ({} joints) on {} states ({}): relative error max|Δ| / max|true| per output (worst output), \
             against the double-double value of each kernel's graph\n",
            self.robot, self.nv, self.states, self.source
        );
        if let Some(c) = self.cond_m {
            s += &format!("cond(M): median {:.1e}, max {:.1e}\n", c.median, c.max);
        }
        if let Some(b) = self.bound_through_minv {
            s += &format!("worst-case bound through M⁻¹ (10·nv·u·cond(M) at the largest cond(M)): f64 {:.1e}, f32 {:.1e}\n", b.f64, b.f32);
        }
        let timed = self.rows.iter().any(|r| r.time_ns.is_some());
        s += &format!(
            "{:<12} {:<32} {:>7} {:>7} {:>9} {:>9}",
            "kernel", "format", "ops", "states", "median", "max"
        );
        s += if timed { "   ns/call (portable)\n" } else { "\n" };
        for r in &self.rows {
            let (median, max) = r.error.map_or(("-".to_string(), "-".to_string()), |e| {
                (format!("{:.1e}", e.median), format!("{:.1e}", e.max))
            });
            let format = match &r.fixed {
                Some(f) => format!("{} = {f}", r.format),
                None => r.format.clone(),
            };
            s += &format!(
                "{:<12} {:<32} {:>7} {:>7} {:>9} {:>9}",
                r.kernel.name(),
                format,
                r.ops,
                r.states,
                median,
                max
            );
            if let Some(t) = r.time_ns {
                s += &format!("   {t:>9.0}");
            }
            if let Some(o) = r.overflowed.filter(|&o| o > 0) {
                s += &format!("   {o} of {} states overflowed (excluded)", r.states);
            }
            if let Some(m) = &r.mixed {
                s += &format!("   {m}");
            }
            if let Some(why) = &r.skipped {
                s += &format!("   not run: {why}");
            }
            s.push('\n');
        }
        s
    }
}
