#!/usr/bin/env python3
"""What one call of a checked-in kernel costs the instruction cache, measured by
cachegrind (valgrind's cache simulator, configured from this CPU's caches): per call of
the dispatching `rnea_grad` or `fd_grad`, the instructions executed, the L1
instruction-cache misses, the data writes, and the share of the instructions spent in
memset (the zeroing of the kernel's scratch array and of the returned matrices). This VM
exposes no hardware counters (`perf stat` reports them as <not supported>), so a simulated
cache is the measurement the speed chapter uses for code size.

Usage: scripts/cache_stats.py [ROBOT ...]   (default: grid_iiwa grid_hyq grid_atlas)
Needs valgrind (apt-get install valgrind). Builds the example `kernel_calls` of
grid-gen-kernels in release and runs it under cachegrind with 0 and CALLS calls; the
difference, divided by CALLS, is one call. valgrind does not run AVX-512, so the
dispatching functions take their `fma` copy (what the checked-in modules have).
"""
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile

CALLS = 2000
robots = sys.argv[1:] or ["grid_iiwa", "grid_hyq", "grid_atlas"]
if not shutil.which("valgrind"):
    sys.exit("error: valgrind is missing: apt-get install valgrind")
root = pathlib.Path(__file__).resolve().parent.parent
subprocess.run(["cargo", "build", "--release", "-p", "grid-gen-kernels", "--example", "kernel_calls"], cwd=root, check=True)
exe = root / "target/release/examples/kernel_calls"


def counts(robot, kernel, calls, tmp):
    """cachegrind's totals for one run, and the instructions it attributes to memset."""
    out = pathlib.Path(tmp) / f"cg.{robot}.{kernel}.{calls}"
    run = subprocess.run(
        ["valgrind", "--tool=cachegrind", "--cache-sim=yes", f"--cachegrind-out-file={out}", str(exe), robot, kernel, str(calls)],
        capture_output=True, text=True, check=True,
    )
    totals = {}
    for key, pattern in (("Ir", r"I\s+refs:\s+([\d,]+)"), ("I1mr", r"I1\s+misses:\s+([\d,]+)"), ("Dw", r"D\s+refs:.*\+\s+([\d,]+) wr")):
        m = re.search(pattern, run.stderr)
        if not m:
            sys.exit(f"error: no `{key}` in cachegrind's summary:\n{run.stderr}")
        totals[key] = int(m.group(1).replace(",", ""))
    annotated = subprocess.run(["cg_annotate", "--show=Ir", str(out)], capture_output=True, text=True, check=True).stdout
    totals["memset"] = sum(
        int(m.group(1).replace(",", "")) for m in re.finditer(r"^\s*([\d,]+) \([\s\d.]+%\)\s+\S*memset\S*", annotated, re.M)
    )
    return totals


print(f"cachegrind, per call (the difference between {CALLS} calls and none, over {CALLS}); dispatching function, f64:\n")
print("| robot | kernel | instructions | of them in memset | L1 instruction misses | bytes of code missed (64 B lines) | data writes |")
print("|---|---|---:|---:|---:|---:|---:|")
with tempfile.TemporaryDirectory() as tmp:
    for robot in robots:
        for kernel in ("rnea_grad", "fd_grad"):
            base, many = counts(robot, kernel, 0, tmp), counts(robot, kernel, CALLS, tmp)
            per = {k: (many[k] - base[k]) / CALLS for k in base}
            print(f"| {robot} | {kernel} | {per['Ir']:,.0f} | {per['memset']:,.0f} | {per['I1mr']:,.0f} | {64 * per['I1mr'] / 1024:,.0f} KiB | {per['Dw']:,.0f} |")
print("\n(cachegrind counts each iteration of `rep stosb` as an instruction: memset's large blocks count once per byte zeroed.)")
