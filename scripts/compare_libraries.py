#!/usr/bin/env python3
"""Two compiled robot libraries side by side: each kernel's batch, on one thread, called
alternately on the same states, median microseconds per state, and how far apart their
results are. For comparing builds of one robot (compiler flags, generator changes), not
robots: both libraries must hold the same kernels of the same robot.

Usage: python scripts/compare_libraries.py LIB_A LIB_B [--prefix P] [--batch 64]
       [--rounds 15] [KERNEL ...]

A library is what `grid_gen.load` caches (`cache_dir()/robots/<key>/librobot.so`, its
`source.json` beside it names the prefix), or any cdylib of a generated module and its C
ABI with `--prefix`. Copy a cached library elsewhere before rebuilding it, so that the
two are different files. Needs the Python package (`pip install ./python`).
"""

import argparse
import json
import os
import time

import numpy as np
from grid_gen._robot import Robot


def prefix_of(lib, given):
    if given:
        return given
    source = os.path.join(os.path.dirname(os.path.abspath(lib)), "source.json")
    if not os.path.exists(source):
        raise SystemExit(f"{lib}: no source.json beside it; pass --prefix")
    return json.load(open(source))["prefix"]


def states(robot, kernel, batch, rng):
    """Inputs for `batch` states: unit quaternions where the robot has them, every contact
    active, dt 0.01 s, the rest uniform in [-1, 1] (configurations in [-0.5, 0.5])."""
    args = {}
    for name, length in kernel.inputs:
        if name in ("q", "q0", "q1"):
            a = rng.uniform(-0.5, 0.5, (batch, length))
            for _, at in robot._quaternions:
                v = rng.normal(size=(batch, 4))
                a[:, at:at + 4] = v / np.linalg.norm(v, axis=1, keepdims=True)
        elif name == "active":
            a = np.ones((batch, length))
        elif name == "dt":
            a = np.full((batch,), 0.01)
        else:
            a = rng.uniform(-1, 1, (batch, length))
        args[name] = a
    return args


def fields(result):
    if hasattr(result, "_fields"):
        return [getattr(result, f) for f in result._fields]
    return list(result) if isinstance(result, tuple) else [result]


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("kernels", nargs="*")
    p.add_argument("--prefix")
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--rounds", type=int, default=15)
    o = p.parse_args()
    robots = [Robot(lib, prefix_of(lib, o.prefix), "f64") for lib in (o.a, o.b)]
    for r in robots:
        r.threads = 1
    names = o.kernels or list(robots[0].kernels)
    rng = np.random.default_rng(0)
    print(f"{'kernel':18s} {'A (µs)':>9s} {'B (µs)':>9s}  B/A    max |A-B|/(1+|A|)")
    for name in names:
        ks = [getattr(r, name) for r in robots]
        args = states(robots[0], ks[0], o.batch, rng)
        got = [fields(k(**args)) for k in ks]
        diff = max(float(np.max(np.abs(x - y) / (1 + np.abs(x)))) for x, y in zip(*got))
        times = [[], []]
        for _ in range(o.rounds):
            for i, k in enumerate(ks):
                t0 = time.perf_counter()
                k(**args)
                times[i].append((time.perf_counter() - t0) / o.batch * 1e6)
        a, b = (float(np.median(t)) for t in times)
        print(f"{name:18s} {a:9.3f} {b:9.3f}  {b / a:5.3f}  {diff:.1e}", flush=True)


if __name__ == "__main__":
    main()
