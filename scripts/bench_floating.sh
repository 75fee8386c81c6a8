#!/usr/bin/env bash
# Floating HyQ's kernels before and after a change, side by side with Pinocchio in one run:
# two builds of the criterion benchmarks (OLD and NEW, paths to `kernels-*` executables from
# `cargo bench -p grid-gen-kernels --bench kernels --no-run` at each commit) and Pinocchio's
# free-flyer derivatives, step composition and constraint dynamics (bench/pinocchio_bench.cpp,
# built by scripts/bench.sh), interleaved over BENCH_ROUNDS rounds (default 3) so that the
# machine's drift falls on every side alike. Each figure is the median over rounds of each
# process's own median. Writes target/bench-floating.md.
# Usage: OLD=path NEW=path bash scripts/bench_floating.sh
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS=${BENCH_ROUNDS:-3}
: "${OLD:?OLD must name the benchmark executable built before the change}"
: "${NEW:?NEW must name the benchmark executable built after it}"
test -x target/bench/pinocchio_bench_native || { echo "error: run scripts/bench.sh once first (it builds Pinocchio's benchmark)" >&2; exit 1; }
M=target/bench/grid_hyq_floating.pinmodel
LEGS=lf_lowerleg,rf_lowerleg,lh_lowerleg,rh_lowerleg
FILTER='grid_hyq\.hyq_floating/generated/(rnea_grad|fd_grad)$|grid_hyq\.hyq_step_floating/generated/step_grad$|grid_hyq\.hyq_standing_floating/generated/contact_fd_grad$'
OUT=target/bench/floating
rm -rf "$OUT" && mkdir -p "$OUT"
for r in $(seq 1 "$ROUNDS"); do
    echo "== round $r of $ROUNDS" >&2
    for variant in default native; do
        target/bench/pinocchio_bench_$variant $M step=0.01@$M contact@$M:$LEGS | sed "s/^{/{\"variant\": \"$variant\", \"round\": $r, /"
    done >>"$OUT/pinocchio.jsonl"
    # Alternate which build runs first.
    order="OLD NEW"; [ $((r % 2)) -eq 0 ] && order="NEW OLD"
    for side in $order; do
        rm -rf target/criterion
        "${!side}" --bench --noplot "$FILTER" >&2
        mv target/criterion "$OUT/$side-$r"
    done
done
python3 - "$OUT" "$ROUNDS" <<'PY' | tee target/bench-floating.md
import json, pathlib, statistics, sys
out, rounds = pathlib.Path(sys.argv[1]), int(sys.argv[2])
def med(xs): return statistics.median(xs)
pin = [json.loads(l) for l in (out / "pinocchio.jsonl").read_text().splitlines()]
def pin_ns(key, pred):
    # The faster of the two builds per round, then the median over rounds.
    per = [min(p[key] for p in pin if p["round"] == r and pred(p)) for r in range(1, rounds + 1)]
    return med(per)
plain = lambda p: "frames" not in p and "dt" not in p and "contact_fd_grad_ns" not in p and "contacts" not in p
rows = [
    ("grid_hyq.hyq_floating", "rnea_grad", pin_ns("rnea_derivatives_ns", plain), "computeRNEADerivatives"),
    ("grid_hyq.hyq_floating", "fd_grad", pin_ns("aba_derivatives_ns", plain), "computeABADerivatives"),
    ("grid_hyq.hyq_step_floating", "step_grad", pin_ns("step_grad_ns", lambda p: "dt" in p), "composition"),
    ("grid_hyq.hyq_standing_floating", "contact_fd_grad", pin_ns("contact_fd_grad_ns", lambda p: "contact_fd_grad_ns" in p), "constraintDynamics + derivatives"),
]
def ours(side, group, kernel):
    return med([json.loads((out / f"{side}-{r}" / group / f"generated_{kernel}" / "new" / "estimates.json").read_text())["median"]["point_estimate"] for r in range(1, rounds + 1)])
def t(ns): return f"{ns / 1000:.2f} µs" if ns >= 1000 else f"{ns:.0f} ns"
print("| scene | kernel | before | after | after / before | Pinocchio | ratio before | ratio after |")
print("|---|---|---|---|---|---|---|---|")
for group, kernel, p, what in rows:
    o, n = ours("OLD", group, kernel), ours("NEW", group, kernel)
    print(f"| {group} | {kernel} | {t(o)} | {t(n)} | {n / o:.2f} | {t(p)} ({what}) | {p / o:.1f}x | {p / n:.1f}x |")
PY
