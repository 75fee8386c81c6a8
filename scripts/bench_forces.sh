#!/usr/bin/env bash
# The external forces' cost (the forces issue's target: rnea_grad and fd_grad with f_ext on
# every body within 1.3x of their times without forces): floating HyQ's rnea_grad and fd_grad
# generated three ways and timed side by side, one state per call, f64, the dispatching copy
# (`grid-gen bench --backend rust`: rustc -C opt-level=3, 64 states cycled, median of 15):
#   none     no forces (examples/scenes/hyq_floating.toml's kernels);
#   fext     an external force on each of the 13 bodies as an input, no d/dfext outputs
#            (`[external_forces] derivatives = false`, `--no-fext-derivatives`);
#   fext+d   the same with the d/dfext outputs (78 more columns: dc/dfext and dqdd/dfext).
# Each variant is compiled and run in its own process, BENCH_ROUNDS times (default 5),
# interleaved so that drift in the machine's speed falls on every variant alike; the table
# gives the median over rounds and each variant's ratio to `none` in the same round's median.
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS=${BENCH_ROUNDS:-5}
case "$ROUNDS" in ''|*[!0-9]*|0) echo "error: BENCH_ROUNDS must be a positive integer, got '$ROUNDS'" >&2; exit 1;; esac
cargo build -q -p grid-gen-cli
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
base='floating_base = true
outputs = ["rnea_grad", "fd_grad"]'
printf '%s\n' "$base" >"$dir/none.toml"
printf '%s\n\n[external_forces]\njoints = ["*"]\nderivatives = false\n' "$base" >"$dir/fext.toml"
printf '%s\n\n[external_forces]\njoints = ["*"]\n' "$base" >"$dir/fext+d.toml"
: >"$dir/times"
for r in $(seq 1 "$ROUNDS"); do
    for v in none fext fext+d; do
        echo "== round $r of $ROUNDS: $v" >&2
        # Columns: kernel, f64 portable, f64 fma, f64 dispatch, ...: the dispatching copy.
        target/debug/grid-gen bench robots/grid_hyq.urdf --scene "$dir/$v.toml" --backend rust --kernels rnea_grad,fd_grad \
            | awk -v v="$v" -v r="$r" '$1 == "rnea_grad" || $1 == "fd_grad" { print r, v, $1, $4 }' | tee -a "$dir/times"
    done
done
python3 - "$dir/times" <<'EOF'
import statistics, sys
rows = [line.split() for line in open(sys.argv[1])]
t = {(r, v, k): float(ns) for r, v, k, ns in rows}
rounds = sorted({r for r, _, _ in t})
print("| kernel | no forces | fext on 13 bodies | ratio | with d/dfext | ratio |")
print("|---|---|---|---|---|---|")
for k in ["rnea_grad", "fd_grad"]:
    med = {v: statistics.median(t[r, v, k] for r in rounds) for v in ["none", "fext", "fext+d"]}
    ratio = {v: statistics.median(t[r, v, k] / t[r, "none", k] for r in rounds) for v in ["fext", "fext+d"]}
    print(f"| `{k}` | {med['none']:.0f} ns | {med['fext']:.0f} ns | {ratio['fext']:.2f}x | {med['fext+d']:.0f} ns | {ratio['fext+d']:.2f}x |")
print(f"\n(f64, one state per call, the dispatching copy; median of {len(rounds)} interleaved rounds, each a separate compile and process)")
EOF
