//! Accurate sin and cos in WGSL, the same on every adapter (WGSL's built-ins may be off by
//! 2^-11 absolute on [-π, π] and are unspecified outside it; Vulkan has no f64 sine).
//! x = k·π/2 + r with |r| ≤ π/4: k = round(x · 2/π), r by Cody–Waite subtraction of π/2
//! split into three parts whose leading parts have few enough bits that k·part is exact
//! (for |k| < 2^13 in f32, 2^20 in f64, so |x| up to about 1.2e4 and 1.6e6 rad); then
//! minimax polynomials on [-π/4, π/4] and the quadrant k mod 4.
//! f32: the split and polynomials of Cephes' sinf/cosf (S. Moshier, Cephes Math Library
//! 2.2, sinf.c, for π/4: DP1..DP3 doubled here). f64: fdlibm's __kernel_sin/__kernel_cos
//! coefficients and its pio2_1/pio2_2/pio2_3 split (Sun Microsystems, k_sin.c, k_cos.c,
//! e_rem_pio2.c). Both about 1 ulp on the reduced range.

use super::Precision;

const F32: &str = "\
fn gg_sin_poly(r: f32, z: f32) -> f32 {
    return r + r * z * (-1.6666654611e-1f + z * (8.3321608736e-3f + z * -1.9515295891e-4f));
}

fn gg_cos_poly(z: f32) -> f32 {
    return 1.0f - 0.5f * z + z * z * (4.166664568298827e-2f + z * (-1.388731625493765e-3f + z * 2.443315711809948e-5f));
}

fn gg_reduce(x: f32) -> vec2<f32> {
    let k = round(x * 0.63661977236758134f);
    let r = ((x - k * 1.5703125f) - k * 4.837512969970703125e-4f) - k * 7.549789954891882e-8f;
    return vec2<f32>(r, k);
}
";

const F64: &str = "\
fn gg_sin_poly(r: f64, z: f64) -> f64 {
    return r + r * z * (-1.66666666666666324348e-01lf + z * (8.33333333332248946124e-03lf + z * (-1.98412698298579493134e-04lf
        + z * (2.75573137070700676789e-06lf + z * (-2.50507602534068634195e-08lf + z * 1.58969099521155010221e-10lf)))));
}

fn gg_cos_poly(z: f64) -> f64 {
    let p = z * (4.16666666666666019037e-02lf + z * (-1.38888888888741095749e-03lf + z * (2.48015872894767294178e-05lf
        + z * (-2.75573143513906633035e-07lf + z * (2.08757232129817482790e-09lf + z * -1.13596475577881948265e-11lf)))));
    return 1.0lf - (0.5lf * z - z * p);
}

fn gg_reduce(x: f64) -> vec2<f64> {
    let k = round(x * 6.36619772367581382433e-01lf);
    let r = ((x - k * 1.57079632673412561417e+00lf) - k * 6.07710050630396597660e-11lf) - k * 2.02226624871116645580e-21lf;
    return vec2<f64>(r, k);
}
";

/// The quadrant selection, the same text for both precisions through `real`.
const QUADRANT: &str = "\
fn gg_sin(x: real) -> real {
    let rk = gg_reduce(x);
    let z = rk.x * rk.x;
    let n = i32(rk.y) & 3;
    let v = select(gg_sin_poly(rk.x, z), gg_cos_poly(z), (n & 1) == 1);
    return select(v, -v, n >= 2);
}

fn gg_cos(x: real) -> real {
    let rk = gg_reduce(x);
    let z = rk.x * rk.x;
    let n = i32(rk.y) & 3;
    let v = select(gg_cos_poly(z), gg_sin_poly(rk.x, z), (n & 1) == 1);
    return select(v, -v, n == 1 || n == 2);
}
";

pub(super) fn source(precision: Precision) -> String {
    let kernels = match precision {
        Precision::F32 => F32,
        Precision::F64 => F64,
    };
    format!("{kernels}\n{QUADRANT}")
}
