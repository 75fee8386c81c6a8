#!/usr/bin/env bash
# What one gait library costs and how fast its step runs: generates floating HyQ's gait
# scene (examples/scenes/hyq_gait_floating.toml: four candidate feet, a contact mask, a
# run-time dt) as the `fma` copy alone, as `grid_gen.load` compiles it on this machine,
# then compiles step, step_grad, contact_fd and contact_fd_grad for f64 in release in a
# scratch crate under target/gait-cost/ (wall time, peak memory of cargo and rustc), and
# times step_grad and contact_fd_grad on one state (three rounds of 20,000 calls).
# A benchmark, not a test: to compare two revisions, run it in each checkout, one after
# the other on an idle machine (docs/guide/compile-time.md).
# Needs: cargo build --release -p grid-gen-cli --no-default-features; x86-64 with AVX2+FMA.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
crate=target/gait-cost
rm -rf "$crate"
mkdir -p "$crate/src"
target/release/grid-gen robots/grid_hyq.urdf --scene examples/scenes/hyq_gait_floating.toml \
    --copies fma -o "$crate/gen" >/dev/null
cat > "$crate/Cargo.toml" <<TOML
[package]
name = "gait-cost"
version = "0.0.0"
edition = "2021"
[workspace]
TOML
cat > "$crate/src/main.rs" <<RS
mod robot { include!("$root/$crate/gen/hyq.rs"); }
use robot::*;
use std::hint::black_box;
fn main() {
    // A standing-like state: the base upright, small joint angles and velocities.
    let mut q = [0.0f64; NQ];
    for i in 7..NQ { q[i] = 0.1 * (i as f64).sin(); }
    q[6] = 1.0;
    let v: [f64; NV] = std::array::from_fn(|i| 0.2 * (i as f64).cos());
    let (u, t, act, dt) = ([0.3f64; NU], [0.3f64; NV], [1.0f64; NCONTACTS], [0.01f64]);
    for round in 0..3 {
        let n = 20000;
        let s = std::time::Instant::now();
        for _ in 0..n { black_box(step_grad(black_box(&q), &v, &u, &act, &dt)); }
        let a = s.elapsed().as_secs_f64() / n as f64 * 1e6;
        let s = std::time::Instant::now();
        for _ in 0..n { black_box(contact_fd_grad(black_box(&q), &v, &t, &act)); }
        let b = s.elapsed().as_secs_f64() / n as f64 * 1e6;
        let c = step(&q, &v, &u, &act, &dt).0[0] + contact_fd(&q, &v, &t, &act).0[0];
        println!("round {round}: step_grad {a:.2} us, contact_fd_grad {b:.2} us ({c:.3})");
    }
}
RS
echo "generated: $(wc -l < "$crate/gen/hyq.rs") lines"
(cd "$crate" && /usr/bin/time -f "release compile: %e s, peak %M KB" cargo build --release --quiet)
"$crate/target/release/gait-cost"
