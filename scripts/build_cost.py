#!/usr/bin/env python3
"""What a robot costs to build, as a user meets it: for each robot and scene, the CLI's
generation of its Rust module (wall time and peak memory) and `grid_gen.load` in a fresh
cache after the cache's first robot (wall time and the peak of the whole process tree:
Python, cargo, rustc and its threads), with the generated module's lines and megabytes.
Prints a markdown table; the first row is the cache's first robot, which also builds the
runtime. Every later case loads in a copy of that cache without its robots, so a case given
twice is built twice (alternated pairs in one run: `A B A B`).

Usage: target/python/bin/python scripts/build_cost.py [CASE ...], a CASE being
`URDF[:SCENE[:floating[:LANES[:CALLS]]]]`, LANES one of `grid_gen.load`'s `batch_lanes`
(auto, all, none; default auto) and CALLS its `calls` (auto, all, rnea_grad; default auto), which the
generation takes too (default: the cases below). Needs the CLI built in release
(`cargo build --release -p grid-gen-cli`) and the Python package installed in the
interpreter that runs it (`pip install ./python`, as `scripts/test.sh` does). A benchmark,
not a test: run it on an idle machine and compare rows of one run. `GRID_GEN_CRATES=1` in
its environment loads each robot as one crate (the default is one crate per core; the
book, Compile time, "A crate per core").
"""

import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "target", "release", "grid-gen")

CASES = [
    "robots/grid_iiwa.urdf",
    "tests/fixtures/go2.urdf::floating",
    "robots/grid_hyq.urdf:examples/scenes/hyq_step_floating.toml",
    "robots/grid_hyq.urdf:examples/scenes/hyq_gait_floating.toml",
    "robots/grid_atlas.urdf:examples/scenes/atlas_feet_floating.toml",
]


def tree_rss(pid: int) -> int:
    """Resident bytes of `pid` and every descendant (from /proc)."""
    children = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(entry))
        except OSError:
            continue
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/statm") as f:
                total += int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
        except OSError:
            pass
        stack.extend(children.get(p, []))
    return total


def measured(cmd, env=None):
    """Runs `cmd` in the repository; returns (seconds, peak bytes of its process tree),
    polled every 20 ms."""
    start = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak = [0]

    def poll():
        while proc.poll() is None:
            peak[0] = max(peak[0], tree_rss(proc.pid))
            time.sleep(0.02)

    t = threading.Thread(target=poll)
    t.start()
    _, err = proc.communicate()
    t.join()
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{err.decode()}")
    return time.monotonic() - start, peak[0]


def main():
    if not os.access(CLI, os.X_OK):
        sys.exit("build the CLI first: cargo build --release -p grid-gen-cli")
    cases = sys.argv[1:] or CASES
    first = tempfile.mkdtemp(prefix="grid-gen-build-cost-")
    mib = 1 << 20
    print("| robot | scene | lines | MB | generate (s) | generate peak (MiB) | `grid_gen.load` (s) | load peak (MiB) |")
    print("|---|---|---|---|---|---|---|---|")
    for i, case in enumerate(cases):
        # The first case builds the runtime in `first`; each later one loads in a copy of
        # that cache without its robots (their libraries, crates and cargo's artifacts), so
        # that no case finds a library built before it, its own included.
        cache = first if i == 0 else tempfile.mkdtemp(prefix="grid-gen-build-cost-case-")
        if i > 0:
            robots = lambda d, names: [n for n in names if "grid_gen_robot_" in n
                                       or (d == first and n in ("robots", "build"))]
            shutil.copytree(first, cache, symlinks=True, dirs_exist_ok=True, ignore=robots)
        env = dict(os.environ, GRID_GEN_CACHE=cache)
        urdf, scene, floating, lanes, calls = (case.split(":") + ["", "", "", ""])[:5]
        lanes, calls = lanes or "auto", calls or "auto"
        out = tempfile.mkdtemp(prefix="grid-gen-build-cost-gen-")
        cmd = [CLI, urdf, "-o", out, "--backend", "rust", "--calls", calls]
        cmd += ["--scene", scene] if scene else []
        cmd += ["--floating-base"] if floating else []
        gen_s, gen_peak = measured(cmd)
        module = os.path.join(out, next(f for f in os.listdir(out) if f.endswith(".rs")))
        text = open(module).read()
        load = (
            f"import grid_gen; grid_gen.load({urdf!r}, scene={scene or None!r}, "
            f"floating_base={bool(floating)}, verbose=False, batch_lanes={lanes!r}, calls={calls!r})"
        )
        load_s, load_peak = measured([sys.executable, "-c", load], env)
        what = os.path.basename(scene) if scene else ("floating base" if floating else "every kernel")
        what += "" if lanes == "auto" else f", `batch_lanes={lanes!r}`"
        what += "" if calls == "auto" else f", `calls={calls!r}`"
        print(
            f"| {os.path.basename(urdf)} | {what} | {text.count(chr(10))} | {len(text) / 1e6:.1f} | "
            f"{gen_s:.1f} | {gen_peak / mib:.0f} | {load_s:.1f} | {load_peak / mib:.0f} |",
            flush=True,
        )
        shutil.rmtree(out, ignore_errors=True)
        if i > 0:
            shutil.rmtree(cache, ignore_errors=True)
    shutil.rmtree(first, ignore_errors=True)


if __name__ == "__main__":
    main()
