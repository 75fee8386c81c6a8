#!/usr/bin/env bash
# Issue 56's humanoid, side by side: floating Atlas (30 joints) standing on both feet as rigid
# 6-D contacts (LOCAL_WORLD_ALIGNED), the semi-implicit step over 10 ms.
#   Pinocchio 4.1: constraintDynamics + computeConstraintDynamicsDerivatives, and the step
#     composed from them with integrate and dIntegrate (bench/pinocchio_bench.cpp, the
#     `step=DT@contact@MODEL:LINK/6d,...` argument; g++ -O3 -march=native);
#   grid-gen: contact_fd_grad and step_grad of the same scene (`grid-gen bench --backend
#     rust`, compiled by rustc in each process).
# The two run interleaved in BENCH_PROCESSES rounds (default 2); each prints its own medians.
# A benchmark, not a test. Needs what scripts/bench.sh needs (pin 4.1.0 in PYTHON, default
# python3; Eigen; g++) and the CLI in release (cargo build --release -p grid-gen-cli).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
PROCESSES=${BENCH_PROCESSES:-2}
case "$PROCESSES" in ''|*[!0-9]*|0) echo "error: BENCH_PROCESSES must be a positive integer, got '$PROCESSES'" >&2; exit 1;; esac
PREFIX=$("$PY" -c "import pinocchio, pathlib; p = pathlib.Path(pinocchio.__file__).resolve(); print(next(x for x in p.parents if (x / 'cmeel.prefix').exists()) / 'cmeel.prefix')")
test -d /usr/include/eigen3 || { echo "error: Eigen headers missing: apt-get install libeigen3-dev" >&2; exit 1; }
test -x target/release/grid-gen || { echo "error: build the CLI first: cargo build --release -p grid-gen-cli" >&2; exit 1; }
mkdir -p target/bench
"$PY" -c "import pinocchio as pin; pin.buildModelFromUrdf('robots/grid_atlas.urdf', pin.JointModelFreeFlyer()).saveToText('target/bench/grid_atlas_floating.pinmodel')"
harness=target/bench/pinocchio_bench_native
if [ ! "$harness" -nt bench/pinocchio_bench.cpp ]; then
    g++ -O3 -march=native -DNDEBUG -std=c++17 -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS -DBOOST_MPL_LIMIT_LIST_SIZE=30 \
        -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 -DBOOST_FUSION_INVOKE_MAX_ARITY=12 -Wno-deprecated-declarations \
        -I"$PREFIX/include" -I/usr/include/eigen3 bench/pinocchio_bench.cpp -o "$harness" \
        -L"$PREFIX/lib" -lpinocchio_default -lboost_filesystem -lboost_serialization -Wl,-rpath,"$PREFIX/lib"
fi
scene=target/bench/atlas_feet_step.toml
cat >"$scene" <<'TOML'
floating_base = true
outputs = ["contact_fd_grad", "step_grad"]
[step]
scheme = "semi_implicit_euler"
dt = 0.01
[[contact]]
frame = "l_foot"
type = "wrench"
[[contact]]
frame = "r_foot"
type = "wrench"
TOML
for p in $(seq 1 "$PROCESSES"); do
    echo "== process $p of $PROCESSES"
    "$harness" "step=0.01@contact@target/bench/grid_atlas_floating.pinmodel:l_foot/6d,r_foot/6d"
    target/release/grid-gen bench robots/grid_atlas.urdf --scene "$scene" --backend rust \
        --kernels contact_fd_grad,step_grad 2>/dev/null
done
