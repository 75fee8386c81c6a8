//! The `--plot` figure of `grid-gen accuracy`: error against cost (time or operations per
//! call), one point per kernel and format, on log-log axes, as a self-contained SVG (no plotting
//! crate: the figure is a few dozen elements).

use super::Report;

const W: f64 = 760.0;
const H: f64 = 480.0;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 210.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 50.0;
/// Colour-blind-safe palette (Okabe & Ito 2008), one colour per format.
const COLOURS: [&str; 8] =
    ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000"];

/// Escapes text for SVG element content and attributes: markup characters as entities,
/// other non-ASCII characters as numeric references (so `≤` shows as itself), control
/// characters, which XML 1.0 forbids even as references, as U+FFFD.
fn xml(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            c if c.is_control() => out.push_str("&#xFFFD;"),
            c if !c.is_ascii() => out.push_str(&format!("&#x{:X};", c as u32)),
            c => out.push(c),
        }
    }
    out
}

/// Powers of ten spanning `[lo, hi]` (both positive).
fn decades(lo: f64, hi: f64) -> (i32, i32) {
    let a = lo.log10().floor() as i32;
    let b = (hi.log10().ceil() as i32).max(a + 1);
    (a, b)
}

/// Error (median as a dot, a bar up to the largest) against operations per call.
/// Error against time per call where the report has times (`accuracy --time`: f64 and
/// f32 only), else against operations per call.
pub fn svg(report: &Report) -> String {
    let timed = report.rows.iter().any(|r| r.time_ns.is_some());
    let cost = |r: &super::Row| if timed { r.time_ns.unwrap_or(0.0) } else { r.ops as f64 };
    let points: Vec<_> = report
        .rows
        .iter()
        .filter_map(|r| r.error.map(|e| (r, e)))
        .filter(|(r, _)| cost(r) > 0.0)
        .collect();
    let mut formats: Vec<&str> = Vec::new();
    for (r, _) in &points {
        if !formats.contains(&r.format.as_str()) {
            formats.push(&r.format);
        }
    }
    // Errors of exactly 0 (a kernel that is exact in a format) sit on the bottom axis, a
    // decade under the smallest nonzero error, so that no measured point is pinned to it.
    let smallest = points
        .iter()
        .flat_map(|(_, e)| [e.median, e.max])
        .filter(|&x| x > 0.0)
        .fold(f64::INFINITY, f64::min);
    let floor = if smallest.is_finite() { smallest / 10.0 } else { 1e-17 };
    // The axis spans the cost actually drawn: time per call with `--time`, else operations.
    let (x_lo, x_hi) = decades(
        points.iter().map(|(r, _)| cost(r)).fold(f64::INFINITY, f64::min).min(1e6),
        points.iter().map(|(r, _)| cost(r)).fold(1.0, f64::max),
    );
    let (y_lo, y_hi) = decades(
        points.iter().map(|(_, e)| e.median.max(floor)).fold(1.0, f64::min),
        points.iter().map(|(_, e)| e.max.max(floor)).fold(floor * 10.0, f64::max),
    );
    let px = |x: f64| LEFT + (x.log10() - x_lo as f64) / (x_hi - x_lo) as f64 * (W - LEFT - RIGHT);
    let py = |y: f64| {
        H - BOTTOM
            - (y.max(floor).log10() - y_lo as f64) / (y_hi - y_lo) as f64 * (H - TOP - BOTTOM)
    };
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{W}\" height=\"{H}\" viewBox=\"0 0 {W} {H}\" font-family=\"sans-serif\" font-size=\"11\">\n\
         <rect width=\"{W}\" height=\"{H}\" fill=\"white\"/>\n\
         <text x=\"{LEFT}\" y=\"22\" font-size=\"13\">{}: error against {}, {} states</text>\n",
        xml(&report.robot),
        if timed { "time per call" } else { "operations per call" },
        report.states
    );
    for d in x_lo..=x_hi {
        let x = px(10f64.powi(d));
        s += &format!(
            "<line x1=\"{x:.1}\" y1=\"{TOP}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#ddd\"/><text x=\"{x:.1}\" y=\"{:.1}\" text-anchor=\"middle\">1e{d}</text>\n",
            H - BOTTOM,
            H - BOTTOM + 16.0
        );
    }
    for d in y_lo..=y_hi {
        let y = py(10f64.powi(d));
        s += &format!(
            "<line x1=\"{LEFT}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">1e{d}</text>\n",
            W - RIGHT,
            LEFT - 6.0,
            y + 4.0
        );
    }
    s += &format!(
        "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>\n\
         <text transform=\"translate(16 {:.1}) rotate(-90)\" text-anchor=\"middle\">relative error (dot: median, bar: largest)</text>\n",
        (LEFT + W - RIGHT) / 2.0,
        H - 12.0,
        if timed { "time per call, ns (generated Rust, portable copy)" } else { "operations per call (the generated graph)" },
        (TOP + H - BOTTOM) / 2.0
    );
    for (r, e) in &points {
        let colour =
            COLOURS[formats.iter().position(|f| *f == r.format).unwrap_or(0) % COLOURS.len()];
        let (x, y, top) = (px(cost(r)), py(e.median), py(e.max));
        s += &format!(
            "<line x1=\"{x:.1}\" y1=\"{y:.1}\" x2=\"{x:.1}\" y2=\"{top:.1}\" stroke=\"{colour}\"/><circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"4\" fill=\"{colour}\"><title>{} {}: median {:.1e}, max {:.1e}</title></circle>\
             <text x=\"{:.1}\" y=\"{:.1}\" fill=\"{colour}\">{}</text>\n",
            r.kernel.name(),
            xml(&r.format),
            e.median,
            e.max,
            x + 6.0,
            y + 4.0,
            match &r.fixed {
                Some(f) => format!("{} {f}", r.kernel.name()),
                None => r.kernel.name().to_string(),
            }
        );
    }
    for (i, f) in formats.iter().enumerate() {
        let y = TOP + 14.0 + 18.0 * i as f64;
        s += &format!(
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"{}\"/><text x=\"{:.1}\" y=\"{:.1}\">{}</text>\n",
            W - RIGHT + 20.0,
            y - 4.0,
            COLOURS[i % COLOURS.len()],
            W - RIGHT + 30.0,
            y,
            xml(f)
        );
    }
    s += "</svg>\n";
    s
}
