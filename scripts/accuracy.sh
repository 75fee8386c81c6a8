#!/usr/bin/env bash
# Writes docs/accuracy/<robot>.txt and .svg for every bundled robot: `grid-gen accuracy`
# on 100 seeded random states in f64, f32, mixed precision (targets 1e-6 and 1e-12) and the --fixed format (default: auto, the
# narrowest format whose analysed error bound is 1e-3), against the double-double value,
# with the f64, f32 and mixed kernels compiled by rustc and timed (--time).
# With --wgsl, also the WGSL kernels (f32) on the first adapter (lavapipe without a GPU).
# The errors are deterministic apart from the WGSL rows (the adapter's sin/cos and
# fusing); the times are not.
set -euo pipefail
cd "$(dirname "$0")/.."
formats="f64,f32,mixed:1e-6,mixed,fixed"
backend=()
[ "${1:-}" = "--wgsl" ] && backend=(--backend wgsl)
cargo build -q --release -p grid-gen-cli
mkdir -p docs/accuracy
for urdf in robots/*.urdf; do
    r=$(basename "$urdf" .urdf)
    # Every format against operations per call, then f64 and f32 against time per call.
    target/release/grid-gen accuracy "$urdf" --random 100 --seed 1 --formats "$formats" "${backend[@]}" --plot "docs/accuracy/$r.svg" > /dev/null
    target/release/grid-gen accuracy "$urdf" --random 100 --seed 1 --formats "$formats" "${backend[@]}" --time --plot "docs/accuracy/$r-time.svg" > "docs/accuracy/$r.txt"
    echo "wrote docs/accuracy/$r.txt, $r.svg and $r-time.svg"
done
