#!/usr/bin/env python3
"""The Python package's speed, side by side in one run:

1. go2 on a floating base, fd_grad, per state, at B = 1, 64, 1024:
   - `rust loop`: the library's own batch loop on one core, called through ctypes with
     prepared pointers at B = 1024 (the call's overhead spread over 1024 states): the
     kernels in a Rust loop, the floor any binding can reach;
   - `python, 1 thread` and `python, all cores`: `robot.fd_grad(q, qd, tau)` as a user
     calls it, argument checks and output arrays included;
   - `pinocchio loop`: Pinocchio's Python `computeABADerivatives` in a loop over the batch;
2. two cores against one at B = 64;
3. load times of iiwa, go2 and Atlas: cold (an empty cache, so rayon compiles too for the
   first robot; then each robot alone) and cached (a fresh Python process).

Usage: python scripts/bench_python.py [--out target/bench/python.md]. Needs the package
installed (pip install ./python) and pin. Times are medians of repeated runs; on a shared
machine only the ratios of one run mean anything.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

import grid_gen

ROOT = Path(__file__).resolve().parents[1]
GO2 = ROOT / "tests" / "fixtures" / "go2.urdf"
ROBOTS = [("iiwa", ROOT / "robots" / "grid_iiwa.urdf", False), ("go2", GO2, True), ("atlas", ROOT / "robots" / "grid_atlas.urdf", True)]


def median_time(fn, repeat: int, min_time: float = 0.2) -> float:
    """Median seconds of one call of fn, over `repeat` rounds of enough calls for min_time."""
    fn()
    t0 = time.perf_counter()
    fn()
    once = max(time.perf_counter() - t0, 1e-7)
    calls = max(1, int(min_time / once / repeat))
    rounds = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        rounds.append((time.perf_counter() - t0) / calls)
    return statistics.median(rounds)


def states(robot, n, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.0, 1.0, (n, robot.nq))
    quat = rng.normal(size=(n, 4))
    q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return q, rng.uniform(-1, 1, (n, robot.nv)), rng.uniform(-10, 10, (n, robot.nv))


def batch_figures(lines):
    robot = grid_gen.load(GO2, floating_base=True, kernels=["fd_grad"], verbose=False)
    kernel = robot.fd_grad
    model = pin.buildModelFromUrdf(str(GO2), pin.JointModelFreeFlyer())
    data = model.createData()
    # The same joint order in both (checked by python/tests against Pinocchio).
    assert [model.names[j] for j in range(2, model.njoints)] == robot.joint_names[6:]
    big = 1024
    q, qd, tau = states(robot, big)
    outs = [np.empty((big,) + dims) for _, dims in kernel.outputs]
    raw = kernel._fn
    ptrs = [a.ctypes.data for a in (q, qd, tau)] + [o.ctypes.data for o in outs]
    robot.threads = 1
    rust = median_time(lambda: raw(big, *ptrs), 9) / big
    lines.append("go2 on a floating base (nq 19, nv 18), fd_grad, per state (median):\n")
    lines.append("| B | rust loop, 1 core | python, 1 thread | ratio | python, all cores | pinocchio loop | pinocchio / python (all cores) |")
    lines.append("|---|---|---|---|---|---|---|")
    two_vs_one = None
    for b in (1, 64, 1024):
        qb, qdb, taub = q[:b].copy(), qd[:b].copy(), tau[:b].copy()
        if b == 1:
            qb, qdb, taub = qb[0], qdb[0], taub[0]
        robot.threads = 1
        one = median_time(lambda: kernel(qb, qdb, taub), 9) / b
        robot.threads = 0
        allc = median_time(lambda: kernel(qb, qdb, taub), 9) / b
        qs, vs, ts = q[:b], qd[:b], tau[:b]

        def pin_loop():
            for i in range(b):
                pin.computeABADerivatives(model, data, qs[i], vs[i], ts[i])

        pinocchio = median_time(pin_loop, 5) / b
        if b == 64:
            two_vs_one = one / allc
        lines.append(f"| {b} | {rust * 1e6:.2f} us | {one * 1e6:.2f} us | {one / rust:.2f}x | {allc * 1e6:.2f} us | {pinocchio * 1e6:.2f} us | {pinocchio / allc:.1f}x |")
    lines.append(f"\nAll cores ({os.cpu_count()}) against one at B = 64: {two_vs_one:.2f}x faster.\n")


def load_times(lines):
    cache = Path(tempfile.mkdtemp(prefix="grid-gen-bench-cache-"))
    env = dict(os.environ, GRID_GEN_CACHE=str(cache))
    lines.append("Load times (cold: an empty cache, the first robot also compiles rayon; cached: a new Python process):\n")
    lines.append("| robot | cold | cached |")
    lines.append("|---|---|---|")
    code = "import time, sys, grid_gen; t = time.perf_counter(); grid_gen.load(sys.argv[1], floating_base=sys.argv[2] == '1', verbose=False); print(time.perf_counter() - t)"
    try:
        for name, urdf, floating in ROBOTS:
            run = lambda: float(subprocess.run([sys.executable, "-c", code, str(urdf), "1" if floating else "0"], env=env, check=True, capture_output=True, text=True).stdout)
            cold = run()
            cached = statistics.median(run() for _ in range(3))
            lines.append(f"| {name}{' (floating)' if floating else ''} | {cold:.1f} s | {cached * 1e3:.1f} ms |")
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "target" / "bench" / "python.md"))
    parser.add_argument("--no-load", action="store_true", help="skip the load times (minutes: three robots compiled cold)")
    args = parser.parse_args()
    lines = [f"# grid_gen from Python ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores)\n"]
    batch_figures(lines)
    if not args.no_load:
        load_times(lines)
    text = "\n".join(lines) + "\n"
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
