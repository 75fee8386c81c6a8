#!/usr/bin/env bash
# Reproduces every speed figure in the book, side by side in one run on this machine:
#   1. Pinocchio's computeRNEADerivatives / computeABADerivatives (and rnea, aba), built
#      from the headers of the `pin` wheel with g++ -O3 (bench/pinocchio_bench.cpp);
#   2. Pinocchio's code-generation path: CppADCodeGen records its derivatives and prints C that
#      gcc compiles (bench/pinocchio_cg_bench.cpp; its own build takes several minutes);
#   3. the criterion benchmarks of the generated kernels and the reference
#      (crates/grid-gen-kernels/benches/kernels.rs), and `grid-gen bench --backend rust` for
#      floating Atlas, whose module is not checked in;
#   4. a table of times and ratios (scripts/bench_report.py), written to target/bench-report.md.
# Needs: pip install pin==4.1.0 cmeel-cppad cmeel-cppadcodegen; apt-get install libeigen3-dev g++.
#
# The placement protocol: a generated function's speed moves by 15-30 % with where the process
# lays out its stack, heap and libraries, on both sides. So every program above is run in
# BENCH_PROCESSES separate processes (default 5), interleaved (process 1 of each program, then
# process 2 of each, ...) so that drift in the machine's speed falls on every side alike; each
# figure in the report is the median over processes of each process's own median, and the
# report says how far the processes spread. Criterion's reference benchmarks (the slow Rust
# reference, not a placement question) run in the first process only.
# A process keeps its binary's code layout, and the layout moves a kernel too (2026-11-27: HyQ's
# rnea_grad at 0.70 µs in one link of the same code and 1.85 µs in another). So with
# BENCH_LAYOUTS=1 (the default) process p > 1 runs the criterion benchmarks relinked with their
# code sections shuffled (rust-lld's --shuffle-sections, seed p - 1; rustc links with rust-lld on
# x86-64 Linux), each process another layout; BENCH_LAYOUTS=0 keeps cargo's one layout.
set -euo pipefail
cd "$(dirname "$0")/.."
PROCESSES=${BENCH_PROCESSES:-5}
LAYOUTS=${BENCH_LAYOUTS:-1}
case "$LAYOUTS" in 0|1) ;; *) echo "error: BENCH_LAYOUTS must be 0 or 1, got '$LAYOUTS'" >&2; exit 1;; esac
case "$PROCESSES" in ''|*[!0-9]*|0) echo "error: BENCH_PROCESSES must be a positive integer, got '$PROCESSES'" >&2; exit 1;; esac
PREFIX=$(python3 -c "import pinocchio, pathlib; p = pathlib.Path(pinocchio.__file__).resolve(); print(next(x for x in p.parents if (x / 'cmeel.prefix').exists()) / 'cmeel.prefix')")
test -d /usr/include/eigen3 || { echo "error: Eigen headers missing: apt-get install libeigen3-dev" >&2; exit 1; }
mkdir -p target/bench
ROBOTS="grid_iiwa grid_hyq grid_atlas"
for r in $ROBOTS; do
    python3 -c "import pinocchio as pin; pin.buildModelFromUrdf('robots/$r.urdf').saveToText('target/bench/$r.pinmodel')"
done
# HyQ on a free-flyer (grid-gen's --floating-base, the scene examples/scenes/hyq_floating.toml).
python3 -c "import pinocchio as pin; pin.buildModelFromUrdf('robots/grid_hyq.urdf', pin.JointModelFreeFlyer()).saveToText('target/bench/grid_hyq_floating.pinmodel')"
# Atlas on a free-flyer (the speed issue's floating-base target names HyQ and Atlas). Its
# module is not checked in (fd_grad alone is 107,735 operations), so ours is timed by
# `grid-gen --floating-base bench --backend rust` below, not by criterion; CppADCodeGen is not
# recorded for it (the target is against Pinocchio's analytical functions).
python3 -c "import pinocchio as pin; pin.buildModelFromUrdf('robots/grid_atlas.urdf', pin.JointModelFreeFlyer()).saveToText('target/bench/grid_atlas_floating.pinmodel')"
MODELS="$(for r in $ROBOTS; do echo target/bench/$r.pinmodel; done) target/bench/grid_hyq_floating.pinmodel target/bench/grid_atlas_floating.pinmodel"
# HyQ with its right angles read as right angles (the scenes hyq_round_angles.toml and
# hyq_floating_round_angles.toml, round_angles = 1e-11): the same models with every joint
# placement's rotation entry within 1e-11 of 0 or +-1 made exact. Pinocchio's analytical
# functions cost the same on them (they do not look at values), but CppADCodeGen records the
# model's numbers as constants and drops products with an exact 0, so its C is recorded again
# from these models, for a fair third column.
python3 - <<'PY'
import numpy as np
import pinocchio as pin
for joint, out in [((), "grid_hyq_round"), ((pin.JointModelFreeFlyer(),), "grid_hyq_floating_round")]:
    m = pin.buildModelFromUrdf("robots/grid_hyq.urdf", *joint)
    for i in range(m.njoints):
        placement = m.jointPlacements[i]
        r = placement.rotation.copy()
        r[np.abs(r) <= 1e-11] = 0.0
        near_one = np.abs(np.abs(r) - 1.0) <= 1e-11
        r[near_one] = np.sign(r[near_one])
        placement.rotation = r
        m.jointPlacements[i] = placement
    m.saveToText(f"target/bench/{out}.pinmodel")
PY
# Frames (the scenes examples/scenes/iiwa_tool_frame.toml and hyq_feet_floating.toml):
# MODEL:LINK,... times getFrameJacobian and getFrameClassicalAcceleration for those links.
MODELS="$MODELS target/bench/grid_iiwa.pinmodel:iiwa_link_7 target/bench/grid_hyq_floating.pinmodel:lf_lowerleg,rf_lowerleg,lh_lowerleg,rh_lowerleg"
# The step (examples/scenes/hyq_step_floating.toml): Pinocchio's composition of the semi-implicit
# Euler step and its [A | B] over 10 ms.
MODELS="$MODELS step=0.01@target/bench/grid_hyq_floating.pinmodel"
# Rigid contacts (examples/scenes/hyq_standing_floating.toml): constraintDynamics and its
# derivatives with a CONTACT_3D at each lower leg, LOCAL_WORLD_ALIGNED.
MODELS="$MODELS contact@target/bench/grid_hyq_floating.pinmodel:lf_lowerleg,rf_lowerleg,lh_lowerleg,rh_lowerleg"
# Pinocchio's own build defines these (see its exported CMake targets). Built twice, for
# the default target and with -march=native; the report takes the faster of the two per
# algorithm, so Pinocchio gets the same wide instructions as our FMA copy.
# Each harness takes several minutes of g++: one newer than its source and than the installed
# Pinocchio library is kept (BENCH_REBUILD=1 builds them all again).
built() {
    [ "${BENCH_REBUILD:-0}" != 1 ] && [ "$1" -nt "$2" ] && [ "$1" -nt "$(ls "$PREFIX"/lib/libpinocchio_default.so* | head -1)" ]
}
for variant in default native; do
    arch=""
    [ "$variant" = native ] && arch="-march=native"
    built target/bench/pinocchio_bench_$variant bench/pinocchio_bench.cpp && continue
    g++ -O3 $arch -DNDEBUG -std=c++17 -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS -DBOOST_MPL_LIMIT_LIST_SIZE=30 \
        -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 -DBOOST_FUSION_INVOKE_MAX_ARITY=12 \
        -I"$PREFIX/include" -I/usr/include/eigen3 bench/pinocchio_bench.cpp -o target/bench/pinocchio_bench_$variant \
        -L"$PREFIX/lib" -lpinocchio_default -lboost_filesystem -lboost_serialization -Wl,-rpath,"$PREFIX/lib"
done
# Pinocchio's code-generation path: the derivatives recorded by CppADCodeGen and compiled by gcc,
# and (jac@) the AD Jacobian of rnea and aba, on every robot; the report takes the faster route.
test -d "$PREFIX/include/cppad/cg" || { echo "error: CppADCodeGen headers missing: pip install cmeel-cppad cmeel-cppadcodegen" >&2; exit 1; }
mkdir -p target/bench/cg
built target/bench/cg/pinocchio_cg_bench bench/pinocchio_cg_bench.cpp ||
g++ -O3 -march=native -DNDEBUG -std=c++17 -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS -DBOOST_MPL_LIMIT_LIST_SIZE=30 \
    -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 -DBOOST_FUSION_INVOKE_MAX_ARITY=12 \
    -I"$PREFIX/include" -I/usr/include/eigen3 bench/pinocchio_cg_bench.cpp -o target/bench/cg/pinocchio_cg_bench \
    -L"$PREFIX/lib" -lpinocchio_default -lboost_filesystem -lboost_serialization -lcppad_lib -ldl -Wl,-rpath,"$PREFIX/lib"
# The generated libraries land in the working directory; the first process compiles them
# (after an earlier run's are removed), the later ones load them.
rm -f target/bench/cg/*.so
source scripts/bench_exe.sh
rm -rf target/bench/criterion target/bench/grid-gen-bench
mkdir -p target/bench/grid-gen-bench
cargo build --release -p grid-gen-cli
: >target/bench/pinocchio.jsonl
for p in $(seq 1 "$PROCESSES"); do
    echo "== process $p of $PROCESSES" >&2
    for variant in default native; do
        target/bench/pinocchio_bench_$variant $MODELS | sed "s/^{/{\"variant\": \"$variant\", \"process\": $p, /"
    done | tee -a target/bench/pinocchio.jsonl
    (cd target/bench/cg && ./pinocchio_cg_bench jac@../grid_iiwa.pinmodel jac@../grid_hyq.pinmodel ../grid_atlas.pinmodel \
        ../grid_hyq_floating.pinmodel jac@../grid_hyq_round.pinmodel ../grid_hyq_floating_round.pinmodel) | sed "s/^{/{\"variant\": \"codegen\", \"process\": $p, /; s#\.\./grid#target/bench/grid#" | tee -a target/bench/pinocchio.jsonl
    filter=()
    [ "$p" -gt 1 ] && filter=("generated|without")
    seed=0
    [ "$LAYOUTS" = 1 ] && seed=$((p - 1))
    exe=$(bench_exe "$seed")
    [ -x "$exe" ] || { echo "error: the benchmarks did not build in layout $seed (a linker without --shuffle-sections? BENCH_LAYOUTS=0 keeps one layout)" >&2; exit 1; }
    # Floating Atlas: grid-gen's own timing program (the same protocol as criterion's: 64
    # seeded states cycled, median of 15 samples of 2 ms), compiled by rustc in each process.
    out=target/bench/grid-gen-bench/grid_atlas_floating.$p
    target/release/grid-gen --floating-base bench --backend rust --kernels rnea_grad,fd_grad \
        robots/grid_atlas.urdf >"$out.txt" 2>"$out.err" || { cat "$out.err" >&2; exit 1; }
    cat "$out.txt"
    rm -rf target/criterion
    "$exe" --bench --noplot "${filter[@]}"
    mkdir -p target/bench/criterion
    mv target/criterion target/bench/criterion/$p
done
python3 scripts/bench_report.py target/bench/pinocchio.jsonl target/bench/criterion target/bench/grid-gen-bench | tee target/bench-report.md
