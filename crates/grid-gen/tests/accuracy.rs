//! `grid_gen::accuracy`, the measurement behind `grid-gen accuracy`: each format's error
//! within the bound the rest of the project states for it, fixed point inside its
//! analysed guarantee, the formats that cannot run a kernel saying so, seeded states
//! inside the bounds, and the plot escaping what it prints.

use grid_gen::accuracy::{self, NumberFormat, Options};
use grid_gen::datapath::{Bounds, Format, Rounding};
use grid_gen::ir::{Gradient, KernelKind, Robot};
use grid_gen::{reference, Model};
use grid_gen_test_support::*;

/// f64: the tolerance of the IR and generated-code tests (cond(M) ≤ 2e3 on these robots).
const F64: f64 = 1e-12;
/// f32, from f64 states rounded to f32: the generated-code tests' bounds (1e-5 direct,
/// 1e-4 through M⁻¹; see crates/grid-gen-kernels/tests/against_reference.rs).
const F32_DIRECT: f64 = 1e-5;
const F32_MINV: f64 = 1e-4;
/// `fixed:auto`'s target: the analysis guarantees this absolute error on every output
/// entry for states inside the bounds.
const MAX_ERROR: f64 = 1e-3;

fn options(model: &Model) -> Options {
    Options {
        kernels: accuracy::default_kernels(model),
        formats: vec![
            NumberFormat::F64,
            NumberFormat::F32,
            NumberFormat::FixedAuto { max_error: MAX_ERROR, rounding: Rounding::HalfUp },
            NumberFormat::Fixed(Format::new(32, 16, Rounding::Truncate).unwrap()),
        ],
        gravity: reference::DEFAULT_GRAVITY,
        gradient: Gradient::Auto,
        solve: grid_gen::ir::Solve::Auto,
        qd_max: None,
        qdd_max: None,
    }
}

#[test]
fn every_format_within_its_bound() {
    for robot in ["grid_iiwa", "grid_hyq", "ur5"] {
        let model = load(robot);
        let states = accuracy::random_states(&model, reference::DEFAULT_GRAVITY, 12, 3, None, None);
        let report = accuracy::measure(&model, &states, "test", &options(&model), &mut []).unwrap();
        assert_eq!(report.rows.len(), 6 * 4, "{robot}: a row per kernel and format");
        let c = report.cond_m.unwrap();
        assert!(
            c.median >= 1.0 && c.max >= c.median && c.max.is_finite(),
            "{robot}: cond(M) {c:?}"
        );
        for r in &report.rows {
            let datapath = matches!(
                r.kernel,
                KernelKind::Rnea | KernelKind::RneaGrad | KernelKind::MassMatrix
            );
            let through_minv =
                matches!(r.kernel, KernelKind::Minv | KernelKind::Fd | KernelKind::FdGrad);
            assert_eq!(r.states, 12);
            match r.format.as_str() {
                "f64" => {
                    assert!(r.error.unwrap().max <= F64, "{robot} {} f64: {:?}", r.kernel, r.error)
                }
                "f32" => {
                    let tol = if through_minv { F32_MINV } else { F32_DIRECT };
                    let e = r.error.unwrap();
                    assert!(e.max <= tol, "{robot} {} f32: {e:?}", r.kernel);
                    // f32 is really f32: far from f64's error.
                    assert!(e.max > 1e-9, "{robot} {} f32: {e:?} is not an f32 error", r.kernel);
                }
                f if f.starts_with("fixed auto") && datapath => {
                    assert_eq!(
                        r.overflowed,
                        Some(0),
                        "{robot} {}: states inside the bounds overflowed",
                        r.kernel
                    );
                    let abs = r.max_abs_error.unwrap();
                    assert!(
                        abs <= MAX_ERROR,
                        "{robot} {} {f} {:?}: {abs:.2e} above the analysed bound",
                        r.kernel,
                        r.fixed
                    );
                    assert!(r.fixed.is_some());
                }
                f if f.starts_with("fixed") && !datapath => {
                    assert!(
                        r.error.is_none() && r.skipped.as_deref().unwrap().contains("divides"),
                        "{robot} {} {f}: {r:?}",
                        r.kernel
                    )
                }
                f => {
                    assert!(
                        f.starts_with("fixed 32.16 truncate") && r.skipped.is_none(),
                        "{robot}: {r:?}"
                    );
                    assert!(
                        r.overflowed.is_some() && (r.error.is_some() || r.overflowed == Some(12))
                    );
                }
            }
        }
        eprintln!("{}", report.to_text());
    }
}

#[test]
fn random_states_are_seeded_and_inside_the_bounds() {
    let model = load("grid_iiwa");
    let g = reference::DEFAULT_GRAVITY;
    let a = accuracy::random_states(&model, g, 20, 5, None, None);
    let b = accuracy::random_states(&model, g, 20, 5, None, None);
    let c = accuracy::random_states(&model, g, 20, 6, None, None);
    assert_eq!(format!("{:?}", a.states), format!("{:?}", b.states), "same seed, same states");
    assert_ne!(format!("{:?}", a.states), format!("{:?}", c.states), "another seed, other states");
    let bounds = Bounds::new(&Robot::of(&model), None, None);
    for s in &a.states {
        assert!(bounds.contains(&s.qd, s.qdd.as_ref().unwrap()));
        for (j, q) in model.joints.iter().zip(&s.q) {
            let (lo, hi) = j.limit.unwrap();
            assert!((lo..=hi).contains(q), "{}: {q} outside [{lo}, {hi}]", j.name);
        }
        // τ is RNEA at some q̈ inside the bounds, so forward dynamics answers one.
        let qdd = reference::forward_dynamics(&model, &s.q, &s.qd, s.tau.as_ref().unwrap(), g);
        assert!(qdd.iter().zip(&bounds.qdd).all(|(a, b)| a.abs() <= b * (1.0 + 1e-9)));
    }
    let slow = accuracy::random_states(&model, g, 5, 5, Some(0.5), Some(2.0));
    assert!(slow.states.iter().all(|s| s.qd.iter().all(|v| v.abs() <= 0.5)
        && s.qdd.as_ref().unwrap().iter().all(|v| v.abs() <= 2.0)));
}

#[test]
fn the_plot_has_a_point_per_measured_row_and_escapes_names() {
    let urdf = chain_urdf(2).replace("name=\"chain\"", "name=\"a&lt;b&amp;c ≤ \"");
    let model = Model::from_urdf_str("x.urdf", &urdf, false).unwrap().0;
    assert_eq!(model.name, "a<b&c ≤ ");
    let states = accuracy::random_states(&model, reference::DEFAULT_GRAVITY, 4, 1, None, None);
    let report = accuracy::measure(&model, &states, "test", &options(&model), &mut []).unwrap();
    let svg = accuracy::svg(&report);
    assert!(svg.starts_with("<svg ") && svg.trim_end().ends_with("</svg>"));
    assert!(
        svg.contains("a&lt;b&amp;c &#x2264; ") && !svg.contains("a<b"),
        "the robot name is escaped"
    );
    let measured = report.rows.iter().filter(|r| r.error.is_some()).count();
    let legend = 4;
    assert_eq!(svg.matches("<circle").count(), measured + legend);
    // The axes follow the data: times of 0.5 to 3 ns (under any operation count)
    // and an error of 7.5e-18 (under the old 1e-17 floor) are drawn inside the plot area.
    let mut timed = report.clone();
    for (k, r) in timed.rows.iter_mut().enumerate() {
        r.time_ns = Some(0.5 + 0.5 * (k % 6) as f64);
        if let Some(e) = r.error.as_mut() {
            e.median = 7.5e-18;
        }
    }
    let svg = accuracy::svg(&timed);
    let number = |s: &str, key: &str| -> f64 {
        s.split(key).nth(1).unwrap().split('"').next().unwrap().parse().unwrap()
    };
    for point in svg.split("<line x1=").skip(1).filter(|l| l.contains("<circle cx=\"")) {
        let (cx, cy) = (number(point, "<circle cx=\""), number(point, "cy=\""));
        assert!(
            (70.0..=550.0).contains(&cx) && (40.0..430.0).contains(&cy),
            "point at ({cx}, {cy}) outside the plot area"
        );
    }
}
