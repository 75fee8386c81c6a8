#!/usr/bin/env bash
# Two commits' generated kernels side by side with Pinocchio, in one run: builds the CLI of
# OLD and of NEW (git revisions) in worktrees under target/bench/commits/, then runs, over
# BENCH_ROUNDS rounds (default 3), Pinocchio's benchmark once (target/bench/pinocchio_bench_native
# with the arguments in PIN) and `grid-gen bench --backend rust` of each commit (the arguments
# after --), the two commits' order alternating, so that the machine's drift falls on every
# side alike. Each `grid-gen bench` compiles its timing program again (a minute or two for
# floating Atlas), so every round also samples another build. Prints the raw lines; each is
# one process's medians. A benchmark, not a test.
#
# Usage: OLD=rev NEW=rev PIN="pinocchio_bench arguments" bash scripts/bench_commits.sh -- GRID_GEN_ARGS...
# The speed book's 2026-12-02 rows, for example:
#   OLD=50947e7 NEW=2992215 PIN=target/bench/grid_atlas_floating.pinmodel BENCH_ROUNDS=5 \
#     bash scripts/bench_commits.sh -- --floating-base bench --backend rust --kernels fd_grad robots/grid_atlas.urdf
# Needs the Pinocchio harness and models of scripts/bench.sh (run it once first).
set -euo pipefail
cd "$(dirname "$0")/.."
: "${OLD:?OLD must name the revision before the change}"
: "${NEW:?NEW must name the revision after it}"
: "${PIN:?PIN must hold the arguments of pinocchio_bench_native (a model, contact@MODEL:LINKS, ...)}"
ROUNDS=${BENCH_ROUNDS:-3}
case "$ROUNDS" in ''|*[!0-9]*|0) echo "error: BENCH_ROUNDS must be a positive integer, got '$ROUNDS'" >&2; exit 1;; esac
[ "${1:-}" = "--" ] && shift
[ $# -gt 0 ] || { echo "error: give grid-gen's arguments after --" >&2; exit 1; }
test -x target/bench/pinocchio_bench_native || { echo "error: run scripts/bench.sh once first (it builds Pinocchio's benchmark)" >&2; exit 1; }
WORK=target/bench/commits
mkdir -p "$WORK"
for side in OLD NEW; do
    rev=${!side}
    dir="$WORK/$side"
    git worktree remove --force "$dir" 2>/dev/null || rm -rf "$dir"
    git worktree add --detach "$dir" "$rev" >/dev/null
    # One target folder for both: the dependencies build once.
    (cd "$dir" && CARGO_TARGET_DIR="$PWD/../target" cargo build --release -q -p grid-gen-cli)
    cp "$WORK/target/release/grid-gen" "$WORK/grid-gen-$side"
done
for r in $(seq 1 "$ROUNDS"); do
    echo "== round $r of $ROUNDS"
    # shellcheck disable=SC2086 # PIN is a list of arguments
    echo "pinocchio $(target/bench/pinocchio_bench_native $PIN | tr '\n' ' ')"
    order="OLD NEW"; [ $((r % 2)) -eq 0 ] && order="NEW OLD"
    for side in $order; do
        echo "$side (${!side})"
        "$WORK/grid-gen-$side" "$@" 2>/dev/null
    done
done
for side in OLD NEW; do git worktree remove --force "$WORK/$side"; done
