//! Calls one checked-in robot's `rnea_grad` or `fd_grad` (the dispatching function) a
//! given number of times over 64 seeded states and nothing else: the program that
//! `scripts/cache_stats.py` runs under cachegrind, once with no calls and once with many, so
//! that the difference is what the calls cost (instructions, instruction-cache misses,
//! writes). `cargo run --release -p grid-gen-kernels --example kernel_calls ROBOT KERNEL N`,
//! ROBOT a file stem of `robots/` (`grid_atlas`).

use std::hint::black_box;

/// One robot's kernel, `calls` times; `false` if the robot is not this module.
macro_rules! drive {
    ($m:ident, $stem:expr, $robot:expr, $kernel:expr, $calls:expr) => {
        if $robot == $stem {
            use grid_gen_kernels::$m as m;
            const NV: usize = m::NV;
            // A 64-bit LCG (Knuth's MMIX constants): any fixed numbers in [-1, 1) do.
            let mut seed = 12345u64;
            let mut draw = || {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            };
            let states: Vec<[[f64; NV]; 3]> =
                (0..64).map(|_| std::array::from_fn(|_| std::array::from_fn(|_| draw()))).collect();
            let mut sum = 0.0;
            for i in 0..$calls {
                let [q, qd, u] = &states[i % 64];
                sum += match $kernel {
                    "rnea_grad" => m::rnea_grad(black_box(q), black_box(qd), black_box(u)).0[0][0],
                    "fd_grad" => m::fd_grad(black_box(q), black_box(qd), black_box(u)).1[0][0],
                    other => panic!("kernel `{other}`: rnea_grad or fd_grad"),
                };
            }
            black_box(sum);
            return;
        }
    };
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, robot, kernel, calls] = &args[..] else {
        panic!("usage: kernel_calls ROBOT KERNEL CALLS");
    };
    let calls: usize = calls.parse().expect("CALLS: a count");
    let (robot, kernel) = (robot.as_str(), kernel.as_str());
    macro_rules! each {
        ($m:ident, $stem:expr) => {
            drive!($m, $stem, robot, kernel, calls)
        };
    }
    grid_gen_kernels::for_each_robot!(each);
    panic!("robot `{robot}`: not a checked-in robot");
}
