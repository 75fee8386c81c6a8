#!/usr/bin/env bash
# Times the gradients of one robot's generated module with the avx512 copy (--avx512)
# against its fma and portable copies, one state per call (f64) and N states per call
# (Lanes<4>, Lanes<8>; in f32 Lanes<8, f32> and Lanes<16, f32>; the SIMD types F64x4,
# F64x8, F32x8, F32x16; time per state), in three interleaved rounds: the book's AVX-512
# table. Needs an x86-64 CPU with AVX-512 F and VL. Usage: scripts/bench_avx512.sh [ROBOT]
# (a fixed-base robot in robots/, default grid_iiwa; Atlas's lanes take LLVM very long).
set -euo pipefail
cd "$(dirname "$0")/.."
robot=${1:-grid_iiwa}
work=target/bench-avx512/$robot
rm -rf "$work" && mkdir -p "$work"
cargo run -q --release -p grid-gen-cli -- "robots/$robot.urdf" -o "$work/gen" --avx512 >/dev/null
cp "$work"/gen/*.rs "$work/robot.rs"
cp bench/avx512_lanes.rs "$work/main.rs"
rustc --edition 2021 -C opt-level=3 -C debuginfo=0 -o "$work/avx512_lanes" "$work/main.rs"
"$work/avx512_lanes"
