#!/usr/bin/env bash
# The GPU table of the WGSL chapter: `grid-gen bench` on iiwa, HyQ and Atlas, `fd_grad` and
# `rnea_grad`, both strategies, N = 1, 32, 256, 1024, 16384, f32 with accurate trig; per row
# the dispatch as the host sees it, the round trip on an uploaded batch (`Gpu::run_on`) and
# with fresh buffers (`Gpu::run`), and the device's own time (timestamp queries).
# Usage: scripts/bench_gpu.sh [OUT_DIR]; GRID_GEN names the binary (default: build it with
# cargo in release mode); WGPU_ADAPTER_NAME picks the adapter (e.g. NVIDIA).
# Atlas's thread pipelines (80k statements in stages) may take a driver minutes to build.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/bench-gpu}
mkdir -p "$out"
if [ -z "${GRID_GEN:-}" ]; then
    cargo build -q --release -p grid-gen-cli
    GRID_GEN=target/release/grid-gen
fi
batch=1,32,256,1024,16384
status=0
# One process per robot, kernel and strategy, each under a time limit, so a pipeline the
# driver is slow to build costs its own row and no other.
for robot in grid_iiwa grid_hyq grid_atlas; do
    for kernel in fd_grad rnea_grad; do
        for strategy in cooperative thread; do
            limit=${ROW_LIMIT:-120}
            [ "$robot" = grid_atlas ] && [ "$strategy" = thread ] && limit=${ATLAS_THREAD_LIMIT:-240}
            name=$robot-$kernel-$strategy
            if timeout "$limit" "$GRID_GEN" bench "robots/$robot.urdf" --batch "$batch" \
                --kernels "$kernel" --wgsl-strategy "$strategy" --seconds "${SECONDS_PER_ROW:-0.2}" \
                >"$out/$name.txt" 2>&1; then
                cat "$out/$name.txt"
            else
                echo "$name: exit $? (limit $limit s)" | tee -a "$out/failed.txt"
                status=1
            fi
        done
    done
done
exit $status
