#!/usr/bin/env python3
"""Prints the book's speed table from one run of scripts/bench.sh: Pinocchio's times
(JSON lines from bench/pinocchio_bench.cpp and bench/pinocchio_cg_bench.cpp) and criterion's
estimates (median, ns).

The placement protocol (scripts/bench.sh): every program ran in several processes. Each
figure here is the median over processes of each process's own median, and a last table
gives the spread over processes, (slowest - fastest) / median, for the headline rows. The
criterion argument is either one criterion folder (one process) or a folder of them, one
per process (target/bench/criterion/1, 2, ...). Pinocchio rows without a "process" field
(runs before the protocol) count as process 1."""
import json
import pathlib
import statistics
import sys

pin_file, criterion = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
# Optional: the folder of `grid-gen bench --backend rust` tables, ROBOT.PROCESS.txt (floating
# Atlas, whose module is not checked in for criterion).
grid_gen_bench = pathlib.Path(sys.argv[3]) if len(sys.argv) > 3 else None

# Per (robot, variant, key), one figure per process: the fastest row of that process (a
# robot has several rows, e.g. the step row repeats aba_derivatives_ns).
per_process = {}
for line in pin_file.read_text().splitlines():
    if line.strip():
        row = json.loads(line)
        robot, variant, process = pathlib.Path(row["robot"]).stem, row.get("variant", "default"), row.get("process", 1)
        for key, value in row.items():
            if key.endswith("_ns"):
                slot = per_process.setdefault((robot, variant, key), {})
                slot[process] = min(slot.get(process, value), value)
# Pinocchio's analytical builds (default target and -march=native): the faster variant's
# median, per algorithm. pin[robot][key] = (median, spread, processes).
pin = {}


def summary(values):
    m = statistics.median(values)
    return m, (max(values) - min(values)) / m, len(values)


for (robot, variant, key), slot in per_process.items():
    s = summary(list(slot.values()))
    best = pin.setdefault(robot, {})
    if key not in best or s[0] < best[key][0]:
        best[key] = s

runs = sorted((d for d in criterion.iterdir() if d.is_dir() and d.name.isdigit()), key=lambda d: int(d.name))
runs = runs or [criterion]


def criterion_summary(robot, name):
    values = []
    for run in runs:
        f = run / robot / name.replace("/", "_") / "new" / "estimates.json"
        if f.exists():
            values.append(json.loads(f.read_text())["median"]["point_estimate"])
    if not values:
        raise FileNotFoundError(f"no criterion estimate for {robot}/{name} in {criterion}")
    return summary(values)


def ns(robot, name, missing_ok=False):
    """The median of `robot`'s criterion benchmark `name`; None if `missing_ok` and there is
    none (`F64x4` rows: a CPU without AVX2 and FMA, or a run from before they existed)."""
    try:
        return criterion_summary(robot, name)[0]
    except FileNotFoundError:
        if missing_ok:
            return None
        raise


def fmt(t):
    return f"{t / 1000:.2f} µs" if t >= 1000 else f"{t:.0f} ns"


# Pinocchio's code-generation path (bench/pinocchio_cg_bench.cpp), its faster route per kernel:
# the recorded derivatives or the AD Jacobian of rnea / aba.
CODEGEN = {"rnea_grad": ("cg_rnea_derivatives_ns", "cg_rnea_jacobian_ns"), "fd_grad": ("cg_aba_derivatives_ns", "cg_aba_jacobian_ns")}


def codegen_summary(robot, kernel):
    times = [pin.get(robot, {}).get(k) for k in CODEGEN.get(kernel, ())]
    times = [t for t in times if t]
    return min(times) if times else None


def codegen(robot, kernel):
    s = codegen_summary(robot, kernel)
    return s[0] if s else None


def pin_ns(robot, key):
    s = pin.get(robot, {}).get(key)
    return s[0] if s else None


def ratio(p, g):
    return f"{p / g:.1f}x" if p else "-"


print("| robot | kernel | generated | reference | Pinocchio | CppADCodeGen | vs reference | vs Pinocchio | vs CppADCodeGen |")
print("|---|---|---|---|---|---|---|---|---|")
pairs = {"rnea": "rnea_ns", "rnea_grad": "rnea_derivatives_ns", "mass_matrix": None, "minv": None, "fd": "aba_ns", "fd_grad": "aba_derivatives_ns"}
for robot in ["grid_iiwa", "grid_hyq", "grid_atlas"]:
    for kernel, pin_key in pairs.items():
        g = ns(robot, f"generated/{kernel}")
        r = ns(robot, f"reference/{kernel}")
        p = pin_ns(robot, pin_key) if pin_key else None
        c = codegen(robot, kernel)
        print(f"| {robot} | {kernel} | {fmt(g)} | {fmt(r)} | {fmt(p) if p else '-'} | {fmt(c) if c else '-'} | {r / g:.1f}x | {ratio(p, g)} | {ratio(c, g)} |")
        if kernel in ("rnea_grad", "fd_grad"):
            g = ns(robot, f"generated/portable/{kernel}")
            print(f"| {robot} | {kernel}, portable copy (no FMA) | {fmt(g)} | {fmt(r)} | {fmt(p)} | {fmt(c) if c else '-'} | {r / g:.1f}x | {ratio(p, g)} | {ratio(c, g)} |")
            for label, bench, lanes in (("2 states per call", "lanes2", 2), ("4 states per call", "lanes4", 4), ("`F64x4` (4 states in one AVX register)", "f64x4", 4)):
                # Atlas has no Lanes rows (LLVM takes too long over them; see kernels.rs).
                g = ns(robot, f"generated/{kernel}_{bench}", missing_ok=bench == "f64x4" or robot == "grid_atlas")
                if g is None:
                    continue
                g /= lanes
                print(
                    f"| {robot} | {kernel}, {label} (per state) | {fmt(g)} | {fmt(r)} | {fmt(p)} | {fmt(c) if c else '-'} | {r / g:.1f}x | {ratio(p, g)} | {ratio(c, g)} |"
                )

# Floating base: HyQ on a free-flyer, the checked-in scene kernels against
# Pinocchio's computeRNEADerivatives / computeABADerivatives with JointModelFreeFlyer.
# HyQ with round_angles = 1e-11 (fixed and floating): Pinocchio's analytical functions on the
# literal models (they cost the same on any values), CppADCodeGen's C recorded from the
# rounded models (its tape drops products with an exact 0; scripts/bench.sh writes them).
for group, label, pin_robot, cg_robot in [
    ("grid_hyq.hyq_floating", "grid_hyq.hyq_floating (floating base)", "grid_hyq_floating", "grid_hyq_floating"),
    ("grid_hyq.hyq_round_angles", "grid_hyq.hyq_round_angles (round_angles 1e-11)", "grid_hyq", "grid_hyq_round"),
    ("grid_hyq.hyq_floating_round_angles", "grid_hyq.hyq_floating_round_angles (floating base, round_angles 1e-11)", "grid_hyq_floating", "grid_hyq_floating_round"),
]:
    for kernel, pin_key in (("rnea_grad", "rnea_derivatives_ns"), ("fd_grad", "aba_derivatives_ns")):
        g = ns(group, f"generated/{kernel}", missing_ok=group != "grid_hyq.hyq_floating")
        if g is None:
            continue
        p = pin_ns(pin_robot, pin_key)
        c = codegen(cg_robot, kernel)
        print(f"| {label} | {kernel} | {fmt(g)} | - | {fmt(p)} | {fmt(c) if c else '-'} | - | {ratio(p, g)} | {ratio(c, g)} |")



def grid_gen_bench_summary(robot, kernel):
    """The median over processes of `grid-gen bench --backend rust`'s f64 time for `kernel`:
    its `fma` copy where the table has one (an AVX-512 CPU, where `dispatch` runs the avx512
    copy that the checked-in modules do not have), else `dispatch` (the fma copy). None when
    there is no such table (a run from before it existed)."""
    values = []
    for f in sorted(grid_gen_bench.glob(f"{robot}.*.txt")) if grid_gen_bench else []:
        for line in f.read_text().splitlines():
            cells = line.split()
            if cells[:1] == [kernel]:
                values.append(float(cells[2] if cells[2] != "-" else cells[3]))
    return summary(values) if values else None


# Floating Atlas, timed by grid-gen's own program (see scripts/bench.sh), against Pinocchio's
# analytical derivatives on the free-flyer model; CppADCodeGen is not recorded for it.
for kernel, pin_key in (("rnea_grad", "rnea_derivatives_ns"), ("fd_grad", "aba_derivatives_ns")):
    s = grid_gen_bench_summary("grid_atlas_floating", kernel)
    if s is None:
        continue
    p = pin_ns("grid_atlas_floating", pin_key)
    print(f"| grid_atlas, floating base (`grid-gen bench`) | {kernel} | {fmt(s[0])} | - | {fmt(p) if p else '-'} | - | - | {ratio(p, s[0])} | - |")

# Frames: the frame scenes' kernels (every frame of the scene per call, LOCAL_WORLD_ALIGNED)
# against Pinocchio's computeJointJacobians + getFrameJacobian and forwardKinematics(q, v, a)
# + getFrameClassicalAcceleration for the same frames.
print()
print("| scene | kernel | generated | Pinocchio | vs Pinocchio |")
print("|---|---|---|---|---|")
for group, pin_robot in [("grid_iiwa.iiwa_tool_frame", "grid_iiwa"), ("grid_hyq.hyq_feet_floating", "grid_hyq_floating")]:
    for kernel in ("frame_jacobian", "frame_acceleration"):
        try:
            g = ns(group, f"generated/{kernel}")
        except FileNotFoundError:
            continue
        p = pin_ns(pin_robot, f"{kernel}_ns")
        print(f"| {group} | {kernel} | {fmt(g)} | {fmt(p) if p else '-'} | {f'{p / g:.1f}x' if p else '-'} |")

# The discrete step (floating HyQ, semi-implicit Euler, 10 ms; examples/scenes/hyq_step_floating.toml):
# step_grad against Pinocchio's composition (computeABADerivatives, integrate, dIntegrate twice and
# the products; `step=DT@MODEL` in bench/pinocchio_bench.cpp), and against the module's own fd_grad.
try:
    g, f = ns("grid_hyq.hyq_step_floating", "generated/step_grad"), ns("grid_hyq.hyq_step_floating", "generated/fd_grad")
    p = pin_ns("grid_hyq_floating", "step_grad_ns")
    print()
    print("| scene | kernel | generated | its fd_grad | Pinocchio composition | vs fd_grad | vs Pinocchio |")
    print("|---|---|---|---|---|---|---|")
    print(f"| grid_hyq.hyq_step_floating | step_grad | {fmt(g)} | {fmt(f)} | {fmt(p) if p else '-'} | {g / f:.2f}x | {f'{p / g:.1f}x' if p else '-'} |")
except FileNotFoundError:
    pass

# Rigid-contact dynamics (floating HyQ on four point contacts; examples/scenes/hyq_standing_floating.toml):
# contact_fd and contact_fd_grad against Pinocchio's constraintDynamics and constraintDynamics +
# computeConstraintDynamicsDerivatives (CONTACT_3D, LOCAL_WORLD_ALIGNED; `contact@MODEL:LINKS`).
try:
    print()
    print("| scene | kernel | generated | Pinocchio | vs Pinocchio |")
    print("|---|---|---|---|---|")
    for kernel in ("contact_fd", "contact_fd_grad"):
        g = ns("grid_hyq.hyq_standing_floating", f"generated/{kernel}")
        p = pin_ns("grid_hyq_floating", f"{kernel}_ns")
        print(f"| grid_hyq.hyq_standing_floating | {kernel} | {fmt(g)} | {fmt(p) if p else '-'} | {f'{p / g:.1f}x' if p else '-'} |")
except FileNotFoundError:
    pass

# The placement protocol's spread: how far the processes' own medians lie apart, as a share of
# their median, for the headline rows (ours; Pinocchio's faster build; CppADCodeGen's faster route).


def spread(s):
    return f"{s[1] * 100:.0f} % ({s[2]})" if s else "-"


print()
print(f"Spread over processes, (slowest - fastest) / median (processes): {len(runs)} criterion processes.")
print()
print("| robot | kernel | spread, generated | spread, Pinocchio | spread, CppADCodeGen |")
print("|---|---|---|---|---|")
for robot, group, pin_robot, cg_robot in [
    ("grid_iiwa", "grid_iiwa", "grid_iiwa", "grid_iiwa"),
    ("grid_hyq", "grid_hyq", "grid_hyq", "grid_hyq"),
    ("grid_atlas", "grid_atlas", "grid_atlas", "grid_atlas"),
    ("grid_hyq.hyq_floating (floating base)", "grid_hyq.hyq_floating", "grid_hyq_floating", "grid_hyq_floating"),
    ("grid_hyq.hyq_round_angles", "grid_hyq.hyq_round_angles", "grid_hyq", "grid_hyq_round"),
    ("grid_hyq.hyq_floating_round_angles", "grid_hyq.hyq_floating_round_angles", "grid_hyq_floating", "grid_hyq_floating_round"),
]:
    for kernel, pin_key in (("rnea_grad", "rnea_derivatives_ns"), ("fd_grad", "aba_derivatives_ns")):
        try:
            g = criterion_summary(group, f"generated/{kernel}")
        except FileNotFoundError:
            continue  # a run from before the scene existed
        print(f"| {robot} | {kernel} | {spread(g)} | {spread(pin.get(pin_robot, {}).get(pin_key))} | {spread(codegen_summary(cg_robot, kernel))} |")
for kernel, pin_key in (("rnea_grad", "rnea_derivatives_ns"), ("fd_grad", "aba_derivatives_ns")):
    s = grid_gen_bench_summary("grid_atlas_floating", kernel)
    if s is not None:
        print(f"| grid_atlas, floating base (`grid-gen bench`) | {kernel} | {spread(s)} | {spread(pin.get('grid_atlas_floating', {}).get(pin_key))} | - |")
