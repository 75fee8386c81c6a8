#!/usr/bin/env python3
"""Prints the book's speed table from one run of scripts/bench.sh: Pinocchio's times
(JSON lines from bench/pinocchio_bench.cpp and bench/pinocchio_cg_bench.cpp) and criterion's
estimates (median, ns)."""
import json
import pathlib
import sys

pin_file, criterion = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
# The faster of Pinocchio's default-target and -march=native builds, per algorithm.
pin = {}
for line in pin_file.read_text().splitlines():
    if line.strip():
        row = json.loads(line)
        best = pin.setdefault(pathlib.Path(row["robot"]).stem, {})
        for key, value in row.items():
            if key.endswith("_ns"):
                best[key] = min(best.get(key, value), value)


def ns(robot, name):
    est = json.loads((criterion / robot / name.replace("/", "_") / "new" / "estimates.json").read_text())
    return est["median"]["point_estimate"]


def fmt(t):
    return f"{t / 1000:.2f} µs" if t >= 1000 else f"{t:.0f} ns"


# Pinocchio's code-generation path (bench/pinocchio_cg_bench.cpp), its faster route per kernel:
# the recorded derivatives or the AD Jacobian of rnea / aba.
CODEGEN = {"rnea_grad": ("cg_rnea_derivatives_ns", "cg_rnea_jacobian_ns"), "fd_grad": ("cg_aba_derivatives_ns", "cg_aba_jacobian_ns")}


def codegen(robot, kernel):
    times = [pin.get(robot, {}).get(k) for k in CODEGEN.get(kernel, ())]
    times = [t for t in times if t]
    return min(times) if times else None


def ratio(p, g):
    return f"{p / g:.1f}x" if p else "-"


print("| robot | kernel | generated | reference | Pinocchio | CppADCodeGen | vs reference | vs Pinocchio | vs CppADCodeGen |")
print("|---|---|---|---|---|---|---|---|---|")
pairs = {"rnea": "rnea_ns", "rnea_grad": "rnea_derivatives_ns", "mass_matrix": None, "minv": None, "fd": "aba_ns", "fd_grad": "aba_derivatives_ns"}
for robot in ["grid_iiwa", "grid_hyq", "grid_atlas"]:
    for kernel, pin_key in pairs.items():
        g = ns(robot, f"generated/{kernel}")
        r = ns(robot, f"reference/{kernel}")
        p = pin[robot][pin_key] if pin_key else None
        c = codegen(robot, kernel)
        print(f"| {robot} | {kernel} | {fmt(g)} | {fmt(r)} | {fmt(p) if p else '-'} | {fmt(c) if c else '-'} | {r / g:.1f}x | {ratio(p, g)} | {ratio(c, g)} |")
        if kernel in ("rnea_grad", "fd_grad"):
            g = ns(robot, f"generated/portable/{kernel}")
            print(f"| {robot} | {kernel}, portable copy (no FMA) | {fmt(g)} | {fmt(r)} | {fmt(p)} | {fmt(c) if c else '-'} | {r / g:.1f}x | {ratio(p, g)} | {ratio(c, g)} |")
        if kernel in ("rnea_grad", "fd_grad") and robot != "grid_atlas":
            for lanes in (2, 4):
                g = ns(robot, f"generated/{kernel}_lanes{lanes}") / lanes
                print(
                    f"| {robot} | {kernel}, {lanes} states per call (per state) | {fmt(g)} | {fmt(r)} | {fmt(p)} | {fmt(c) if c else '-'} | {r / g:.1f}x | {ratio(p, g)} | {ratio(c, g)} |"
                )

# Floating base: HyQ on a free-flyer, the checked-in scene kernels against
# Pinocchio's computeRNEADerivatives / computeABADerivatives with JointModelFreeFlyer.
for group, pin_robot in [("grid_hyq.hyq_floating", "grid_hyq_floating")]:
    for kernel, pin_key in (("rnea_grad", "rnea_derivatives_ns"), ("fd_grad", "aba_derivatives_ns")):
        g = ns(group, f"generated/{kernel}")
        p = pin[pin_robot][pin_key]
        c = codegen(pin_robot, kernel)
        print(f"| {group} (floating base) | {kernel} | {fmt(g)} | - | {fmt(p)} | {fmt(c) if c else '-'} | - | {ratio(p, g)} | {ratio(c, g)} |")

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
        p = pin.get(pin_robot, {}).get(f"{kernel}_ns")
        print(f"| {group} | {kernel} | {fmt(g)} | {fmt(p) if p else '-'} | {f'{p / g:.1f}x' if p else '-'} |")

# The discrete step (floating HyQ, semi-implicit Euler, 10 ms; examples/scenes/hyq_step_floating.toml):
# step_grad against Pinocchio's composition (computeABADerivatives, integrate, dIntegrate twice and
# the products; `step=DT@MODEL` in bench/pinocchio_bench.cpp), and against the module's own fd_grad.
try:
    g, f = ns("grid_hyq.hyq_step_floating", "generated/step_grad"), ns("grid_hyq.hyq_step_floating", "generated/fd_grad")
    p = pin.get("grid_hyq_floating", {}).get("step_grad_ns")
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
        p = pin.get("grid_hyq_floating", {}).get(f"{kernel}_ns")
        print(f"| grid_hyq.hyq_standing_floating | {kernel} | {fmt(g)} | {fmt(p) if p else '-'} | {f'{p / g:.1f}x' if p else '-'} |")
except FileNotFoundError:
    pass
