#!/usr/bin/env bash
# Two checkouts' kernels side by side over several code layouts: the criterion benchmarks
# (crates/grid-gen-kernels/benches/kernels.rs) built in OLD and in NEW (paths to checkouts of
# this repository; each builds into its own target/), once per seed in LAYOUT_SEEDS (default
# "0 7": cargo's layout, and the code sections shuffled by rust-lld's --shuffle-sections with
# seed 7), then run interleaved over BENCH_ROUNDS rounds (default 2). Each figure is the
# median over rounds, then over layouts, so that neither side's number is one link's luck
# (docs/bench/layouts-2026-11-27.md). FILTER picks the benchmarks (a criterion regex).
# Writes target/bench-layouts.md.
# Usage: OLD=../old NEW=. bash scripts/bench_layouts.sh
set -euo pipefail
cd "$(dirname "$0")/.."
: "${OLD:?OLD must name a checkout of the revision before the change}"
: "${NEW:?NEW must name a checkout of the revision after it}"
SEEDS=${LAYOUT_SEEDS:-0 7}
ROUNDS=${BENCH_ROUNDS:-2}
FILTER=${FILTER:-'^(grid_iiwa|grid_hyq|grid_atlas|grid_hyq\.hyq_floating)/generated/(rnea_grad|fd_grad)$|hyq_step_floating/generated/(step_grad|fd_grad)$|hyq_standing_floating/generated/contact_fd_grad$'}
OUT=$PWD/target/bench/layouts
source scripts/bench_exe.sh
rm -rf "$OUT" && mkdir -p "$OUT"
for side in OLD NEW; do
    for seed in $SEEDS; do
        exe=$(cd "${!side}" && CARGO_TARGET_DIR="$PWD/target" bench_exe "$seed")
        [ -x "$exe" ] || { echo "error: $side did not build in layout $seed" >&2; exit 1; }
        cp "$exe" "$OUT/$side-s$seed"
    done
done
for r in $(seq 1 "$ROUNDS"); do
    for seed in $SEEDS; do
        for side in OLD NEW; do
            rm -rf target/criterion
            "$OUT/$side-s$seed" --bench --noplot --warm-up-time 1 --measurement-time 2 "$FILTER" >&2
            mv target/criterion "$OUT/$side-s$seed-$r"
        done
    done
done
python3 - "$OUT" "$ROUNDS" "$SEEDS" <<'PY' | tee target/bench-layouts.md
import json, pathlib, statistics, sys
out, rounds, seeds = pathlib.Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3].split()
med = statistics.median
def t(ns): return f"{ns / 1000:.2f} µs" if ns >= 1000 else f"{ns:.0f} ns"
first = out / f"OLD-s{seeds[0]}-1"
names = sorted(str(p.parent.parent.relative_to(first)) for p in first.glob("**/new/estimates.json"))
print(f"| benchmark | before ({' / '.join('s' + s for s in seeds)}) | after | before | after | after / before |")
print("|---|---|---|---|---|---|")
for n in names:
    per = {side: [med([json.loads((out / f"{side}-s{s}-{r}" / n / "new" / "estimates.json").read_text())["median"]["point_estimate"]
                       for r in range(1, rounds + 1)]) for s in seeds] for side in ("OLD", "NEW")}
    o, a = med(per["OLD"]), med(per["NEW"])
    print(f"| {n} | {' / '.join(map(t, per['OLD']))} | {' / '.join(map(t, per['NEW']))} | {t(o)} | {t(a)} | {a / o:.2f} |")
PY
