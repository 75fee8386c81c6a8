#!/usr/bin/env bash
# Runs every test of grid-gen. Installs what it needs where it can; with CI set, a tool
# that is missing and cannot be installed is a failure, never a silent skip.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '\n== %s\n' "$*"; }
die() { printf 'error: %s\n' "$*" >&2; exit 1; }

say "toolchain"
command -v cargo >/dev/null || die "cargo is required (https://rustup.rs)"
command -v python3 >/dev/null || die "python3 is required for the Pinocchio/yourdfpy fixture check"
cargo --version

say "python packages (pin, yourdfpy) for the fixture check, in target/python"
# A virtual environment under target/ leaves the user's Python alone; it sees packages
# already installed system-wide (no download then) and installs what is missing into itself.
VENV=target/python
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv --system-site-packages "$VENV" || die "could not create a virtual environment in $VENV (Debian: apt-get install python3-venv)"
fi
PY="$VENV/bin/python"
if ! "$PY" -c "import pinocchio, yourdfpy" 2>/dev/null; then
    "$PY" -m pip install --quiet "pin==4.1.0" "yourdfpy==0.0.60" \
        || die "could not install pin and yourdfpy with pip into $VENV; they check the fixtures against Pinocchio"
fi
"$PY" -c "import pinocchio, yourdfpy; print('pinocchio', pinocchio.__version__)" || die "pin/yourdfpy do not import"

say "lavapipe (software Vulkan) so the WGSL kernels run through wgpu without a GPU"
if ! ldconfig -p 2>/dev/null | grep -q libvulkan.so.1 || ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null) \
            || die "could not install mesa-vulkan-drivers and libvulkan1 (lavapipe) with apt-get"
    elif [ -n "${CI:-}" ]; then
        die "lavapipe is missing: install mesa-vulkan-drivers and libvulkan1 (Debian) to run the WGSL kernels"
    else
        echo "warning: lavapipe is missing and cannot be installed here; the WGSL run test will say it skipped"
    fi
fi

say "Icarus Verilog and Yosys, to simulate and synthesise the Verilog netlists"
if ! command -v iverilog >/dev/null || ! command -v vvp >/dev/null || ! command -v yosys >/dev/null; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq iverilog yosys >/dev/null) \
            || die "could not install iverilog and yosys with apt-get"
    elif [ -n "${CI:-}" ]; then
        die "iverilog and yosys are missing: install the Debian packages iverilog and yosys"
    else
        echo "warning: iverilog/yosys are missing and cannot be installed here; the Verilog tests will say they skipped"
    fi
fi
# sed reads to the end, so iverilog never sees a closed pipe (pipefail would fail on it).
if command -v iverilog >/dev/null; then iverilog -V 2>&1 | sed -n 1p; fi
if command -v yosys >/dev/null; then yosys -V; fi
say "CMake, a C++ compiler and Eigen, to build and run the C++ example (examples/cpp)"
if ! command -v cmake >/dev/null || ! command -v c++ >/dev/null || [ ! -f /usr/include/eigen3/Eigen/Dense ]; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq cmake g++ libeigen3-dev >/dev/null) \
            || die "could not install cmake, g++ and libeigen3-dev with apt-get"
    elif [ -n "${CI:-}" ]; then
        die "cmake, g++ or Eigen is missing: install the Debian packages cmake g++ libeigen3-dev"
    else
        echo "warning: cmake/g++/Eigen are missing and cannot be installed here; the C++ example test will say it skipped"
    fi
fi
if command -v cmake >/dev/null; then cmake --version | sed -n 1p; fi
# Mesa warns on every run without it.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"

say "formatting"
if ! cargo fmt --version >/dev/null 2>&1; then
    rustup component add rustfmt || die "rustfmt is missing and could not be installed (rustup component add rustfmt)"
fi
cargo fmt --all -- --check || die "code is not formatted: run cargo fmt --all"

say "cargo test (workspace): build"
# Every target (--all-targets would also build the libraries that declare `test = false`,
# such as grid-gen-kernels, whose modules have no unit tests and take minutes to build again).
TARGETS=(--workspace --tests --benches --examples)
# A clean clone (CI) compiles everything once, so incremental compilation's bookkeeping is
# all cost there (it writes a dependency graph for every unrolled kernel); locally it stays
# on, so that a rerun after an edit rebuilds little. Every cargo command below sees it, so
# none rebuilds what this one built.
if [ -n "${CI:-}" ]; then export CARGO_INCREMENTAL=0; fi
cargo test "${TARGETS[@]}" --no-run

# While the tests run, the tools of the later steps build in the background (lavapipe's tests
# start after the other tests, by when these builds have ended; see .config/nextest.toml): mdBook, and the Python package (the
# README's one install command, `pip install ./python`: maturin, downloaded by pip, builds
# the native generator with cargo). Each logs to target/ and is waited for below.
mkdir -p target/tools
MDBOOK="$(command -v mdbook || true)"
MDBOOK_PID=""
if [ -z "$MDBOOK" ]; then
    MDBOOK=target/tools/bin/mdbook
    if [ ! -x "$MDBOOK" ]; then
        # No server or file watcher: the build alone.
        cargo install --quiet --locked --no-default-features --root target/tools mdbook --version 0.5.4 \
            >target/tools/mdbook-install.log 2>&1 &
        MDBOOK_PID=$!
    fi
fi
"$PY" -m pip install --quiet pytest "jax[cpu]" ./python >target/tools/python-install.log 2>&1 &
PYTHON_PID=$!
# Clippy, warnings denied: the workspace with every target, and the CLI without wgpu (what
# `cargo install --no-default-features` builds). Its own target folder, so that it never
# waits on the test run's lock.
if ! cargo clippy --version >/dev/null 2>&1; then
    rustup component add clippy || die "clippy is missing and could not be installed (rustup component add clippy)"
fi
(
    export CARGO_TARGET_DIR=target/clippy
    cargo clippy --workspace --all-targets -- -D warnings &&
        cargo clippy -p grid-gen-cli --no-default-features -- -D warnings
) >target/tools/clippy.log 2>&1 &
CLIPPY_PID=$!

say "cargo test (workspace): run"
# cargo-nextest (on this project's machines) runs each test as a process and the tests of
# every binary side by side, two at a time on two cores; `cargo test` runs one binary after
# another, and a binary's slowest test (lavapipe compiling a shader, Icarus simulating a
# netlist) leaves the other core idle. .config/nextest.toml runs lavapipe's tests alone and
# last. Both run every test; without nextest it is `cargo test`.
if cargo nextest --version >/dev/null 2>&1; then
    cargo nextest run "${TARGETS[@]}"
else
    echo "cargo-nextest is not installed: cargo test runs the same tests, one binary at a time (cargo install cargo-nextest --locked for the faster run)"
    cargo test "${TARGETS[@]}"
fi

say "lints: cargo clippy -D warnings, the workspace and the CLI without wgpu"
wait "$CLIPPY_PID" || { cat target/tools/clippy.log; die "cargo clippy reports warnings (listed above): fix them, or allow one with a reason"; }

say "the step example: 64 knots of floating HyQ rolled out and linearised"
# Without -p: cargo then resolves features over the whole workspace, as the test build did,
# so only the example itself compiles (with -p grid-gen-kernels its dependencies built
# again, a minute of the test command).
cargo run -q --example hyq_rollout

say "the Python package: pip install ./python, then its tests against Pinocchio"
wait "$PYTHON_PID" || { cat target/tools/python-install.log; die "pip install ./python (with pytest and jax for its tests) failed: it needs cargo, and PyPI for maturin"; }
# Compiled robots go under target/, not the user's cache.
GRID_GEN_CACHE="$PWD/target/grid-gen-cache" "$PY" -m pytest -q -s python/tests

say "the MPC knot example: an iLQR for A1 on four stabilised feet, grid-gen beside Pinocchio"
# It asserts that both solvers' costs agree (1e-8) and that the solver made progress.
GRID_GEN_CACHE="$PWD/target/grid-gen-cache" "$PY" examples/a1_ilqr.py --iterations 10

say "the book: mdbook build docs/book, and every link in it and in the README"
if [ -n "$MDBOOK_PID" ]; then
    wait "$MDBOOK_PID" || { cat target/tools/mdbook-install.log; die "could not install mdbook 0.5.4 with cargo (crates.io)"; }
fi
"$MDBOOK" build docs/book || die "mdbook build docs/book failed"
"$PY" scripts/check_links.py || die "broken links in README.md or docs/ (listed above)"
"$PY" scripts/check_figures.py || die "the README's speed table differs from the run it names"

say "fixtures are what Pinocchio and yourdfpy compute"
"$PY" scripts/make_fixtures.py --check

say "all tests passed"
echo "Tests print their measured figures (errors against their tolerances, sizes, timings);"
echo "the runner hides them for passing tests: add --no-capture to a cargo nextest run command"
echo "(or -- --nocapture to a cargo test command) to see them."
