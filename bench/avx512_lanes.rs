//! Per-state time of the gradients in each machine-code copy (portable, fma, avx512) and
//! lane width (one state, Lanes<4>, Lanes<8>; in f32 one state, Lanes<8, f32> (one ymm) and
//! Lanes<16, f32> (one zmm)), and the explicit SIMD types (F64x4, F64x8, F32x8, F32x16: one
//! vector instruction per operation), interleaved over three rounds; compiled by
//! scripts/bench_avx512.sh beside a module generated with --avx512 (robot.rs). Protocol
//! as timing.rs: 64 fixed states cycled, samples of at least 2 ms, median of 15.
#![allow(dead_code, unused_unsafe, clippy::all)]
mod robot { include!("robot.rs"); }
use robot::{Lanes, F32x16, F32x8, F64x4, F64x8};
use std::hint::black_box;
use std::time::Instant;
const STATES: usize = 64;
const N: usize = robot::NV;
fn state(k: usize, i: usize, salt: usize) -> f64 { (((k * 7919 + i * 104_729 + salt * 15_485_863) % 2001) as f64 / 1000.0) - 1.0 }
fn time<F: FnMut(usize)>(mut f: F) -> f64 {
    let mut reps = 1usize;
    loop { let t = Instant::now(); for r in 0..reps { f(r % STATES); } if t.elapsed().as_secs_f64() > 2e-3 { break; } reps *= 2; }
    let mut s: Vec<f64> = (0..15).map(|_| { let t = Instant::now(); for r in 0..reps { f(r % STATES); } t.elapsed().as_secs_f64() * 1e9 / reps as f64 }).collect();
    s.sort_by(f64::total_cmp); s[7]
}
fn lanes<const L: usize>(s: &[[[f64; N]; 3]], j: usize) -> [[Lanes<L>; N]; 3] {
    std::array::from_fn(|a| std::array::from_fn(|i| Lanes(std::array::from_fn(|l| s[(j * L + l) % STATES][a][i]))))
}
fn lanes32<const L: usize>(s: &[[[f64; N]; 3]], j: usize) -> [[Lanes<L, f32>; N]; 3] {
    std::array::from_fn(|a| std::array::from_fn(|i| Lanes(std::array::from_fn(|l| s[(j * L + l) % STATES][a][i] as f32))))
}
fn main() {
    let s: Vec<[[f64; N]; 3]> = (0..STATES).map(|j| std::array::from_fn(|a| std::array::from_fn(|i| state(j, i, a)))).collect();
    let l4: Vec<_> = (0..STATES).map(|j| lanes::<4>(&s, j)).collect();
    let l8: Vec<_> = (0..STATES).map(|j| lanes::<8>(&s, j)).collect();
    let s32: Vec<[[f32; N]; 3]> = s.iter().map(|x| x.map(|v| v.map(|e| e as f32))).collect();
    let f8: Vec<_> = (0..STATES).map(|j| lanes32::<8>(&s, j)).collect();
    let f16: Vec<_> = (0..STATES).map(|j| lanes32::<16>(&s, j)).collect();
    let x4: Vec<[[F64x4; N]; 3]> = l4.iter().map(|x| x.map(|v| v.map(|e| F64x4::new(e.0).unwrap()))).collect();
    let x8: Vec<[[F64x8; N]; 3]> = l8.iter().map(|x| x.map(|v| v.map(|e| F64x8::new(e.0).unwrap()))).collect();
    let y8: Vec<[[F32x8; N]; 3]> = f8.iter().map(|x| x.map(|v| v.map(|e| F32x8::new(e.0).unwrap()))).collect();
    let y16: Vec<[[F32x16; N]; 3]> = f16.iter().map(|x| x.map(|v| v.map(|e| F32x16::new(e.0).unwrap()))).collect();
    if !robot::has_avx512() {
        eprintln!("this CPU has no AVX-512 F and VL: nothing to compare");
        std::process::exit(1);
    }
    // The copies compute the same operations, and a lane what one state computes: check
    // that before timing them.
    // SAFETY: the CPU has AVX-512 F and VL, AVX2 and FMA (checked above).
    let (a, b, c) = unsafe {
        (
            robot::fma::fd_grad(&s[3][0], &s[3][1], &s[3][2]),
            robot::avx512::fd_grad(&s[3][0], &s[3][1], &s[3][2]),
            robot::avx512::fd_grad(&l8[0][0], &l8[0][1], &l8[0][2]),
        )
    };
    let (a32, c32, d32) = unsafe {
        (
            robot::avx512::fd_grad(&s32[3][0], &s32[3][1], &s32[3][2]),
            robot::fma::fd_grad(&f8[0][0], &f8[0][1], &f8[0][2]),
            robot::avx512::fd_grad(&f16[0][0], &f16[0][1], &f16[0][2]),
        )
    };
    for i in 0..N {
        for j in 0..N {
            assert!(a.1[i][j].to_bits() == b.1[i][j].to_bits(), "the fma and avx512 copies differ");
            assert!(c.1[i][j].0[3].to_bits() == b.1[i][j].to_bits(), "lane 3 of Lanes<8> differs from one state");
            assert!(c32.1[i][j].0[3].to_bits() == a32.1[i][j].to_bits(), "lane 3 of Lanes<8, f32> differs from one f32 state");
            assert!(d32.1[i][j].0[3].to_bits() == a32.1[i][j].to_bits(), "lane 3 of Lanes<16, f32> differs from one f32 state");
        }
    }
    // The explicit SIMD types compute what the lanes of the same width do, bit for bit.
    let (x, y) = unsafe { (robot::avx512::fd_grad(&x8[0][0], &x8[0][1], &x8[0][2]), robot::fma::fd_grad(&y8[0][0], &y8[0][1], &y8[0][2])) };
    let (x4r, y16r) = unsafe { (robot::fma::fd_grad(&x4[0][0], &x4[0][1], &x4[0][2]), robot::avx512::fd_grad(&y16[0][0], &y16[0][1], &y16[0][2])) };
    let l4r = unsafe { robot::fma::fd_grad(&l4[0][0], &l4[0][1], &l4[0][2]) };
    for i in 0..N {
        for j in 0..N {
            assert!(x.1[i][j].to_array() == c.1[i][j].0, "F64x8 differs from Lanes<8>");
            assert!(y.1[i][j].to_array() == c32.1[i][j].0, "F32x8 differs from Lanes<8, f32>");
            assert!(y16r.1[i][j].to_array() == d32.1[i][j].0, "F32x16 differs from Lanes<16, f32>");
            assert!(x4r.1[i][j].to_array() == l4r.1[i][j].0, "F64x4 differs from Lanes<4>");
        }
    }
    println!("round copy kernel states/call ns/state");
    for round in 0..3 {
        macro_rules! t { ($label:expr, $m:ident, $k:ident, $st:expr, $per:expr) => {{
            let ns = time(|j| { let x = &$st[j]; black_box(unsafe { robot::$m::$k(&x[0], &x[1], &x[2]) }); }) / $per as f64;
            println!("{round} {:>8} {:>10} {:>8} {:8.1}", stringify!($m), stringify!($k), $label, ns);
        }}}
        t!("f64", portable, fd_grad, s, 1); t!("f64", fma, fd_grad, s, 1); t!("f64", avx512, fd_grad, s, 1);
        t!("L4", fma, fd_grad, l4, 4); t!("L4", avx512, fd_grad, l4, 4);
        t!("L8", fma, fd_grad, l8, 8); t!("L8", avx512, fd_grad, l8, 8);
        t!("f64", portable, rnea_grad, s, 1); t!("f64", fma, rnea_grad, s, 1); t!("f64", avx512, rnea_grad, s, 1);
        t!("L4", fma, rnea_grad, l4, 4); t!("L4", avx512, rnea_grad, l4, 4);
        t!("L8", fma, rnea_grad, l8, 8); t!("L8", avx512, rnea_grad, l8, 8);
        t!("F64x4", fma, fd_grad, x4, 4); t!("F64x4", avx512, fd_grad, x4, 4); t!("F64x8", avx512, fd_grad, x8, 8);
        t!("F64x4", fma, rnea_grad, x4, 4); t!("F64x4", avx512, rnea_grad, x4, 4); t!("F64x8", avx512, rnea_grad, x8, 8);
        t!("F32x8", fma, fd_grad, y8, 8); t!("F32x8", avx512, fd_grad, y8, 8); t!("F32x16", avx512, fd_grad, y16, 16);
        t!("F32x8", fma, rnea_grad, y8, 8); t!("F32x8", avx512, rnea_grad, y8, 8); t!("F32x16", avx512, rnea_grad, y16, 16);
        t!("f32", fma, fd_grad, s32, 1); t!("f32", avx512, fd_grad, s32, 1);
        t!("f32L8", fma, fd_grad, f8, 8); t!("f32L8", avx512, fd_grad, f8, 8); t!("f32L16", avx512, fd_grad, f16, 16);
        t!("f32", fma, rnea_grad, s32, 1); t!("f32", avx512, rnea_grad, s32, 1);
        t!("f32L8", fma, rnea_grad, f8, 8); t!("f32L8", avx512, rnea_grad, f8, 8); t!("f32L16", avx512, rnea_grad, f16, 16);
    }
}
