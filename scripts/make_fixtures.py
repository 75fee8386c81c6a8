#!/usr/bin/env python3
"""Writes the reference fixtures under tests/fixtures/ from independent tools.

For each robot in robots/:
  <robot>.pinocchio.json  Pinocchio (the `pin` wheel) on random and extreme states:
                          RNEA, its derivatives, M, M^-1, ABA and its derivatives.
  <robot>.yourdfpy.json   yourdfpy's reading of the tree: joint names, types, parents,
                          origins, axes, and link poses at random configurations.
<robot>.floating.pinocchio.json: the same with a free-flyer base (Pinocchio's
                          JointModelFreeFlyer; grid-gen's --floating-base), for FLOATING.
<robot>.mimic.pinocchio.json: the same with mimic joints coupled (grid-gen's --mimic
                          coupled; Pinocchio's mimic=True), for the Panda and mimic_arm.urdf.
<robot>[.floating].frames.pinocchio.json: frame placements, Jacobians, velocities and
                          classical accelerations of chosen links (FRAMES), in the three
                          reference frames, and the classical acceleration's derivatives
                          in LOCAL (from getFrameAccelerationDerivatives).
ball_arm.urdf with ball_arm[.floating].pinocchio.json: spherical joints (a grid-gen
                          extension of URDF) against Pinocchio's JointModelSpherical.
<robot>.<scene>.pinocchio.json: the same, for a robot in a scene of examples/scenes/
                          (Pinocchio's buildReducedModel for locks, payload inertias added).
and chain100.urdf with chain100.pinocchio.json: a 100-link chain (cond(M) ~ 1e5) and
Pinocchio's ABA and ABA derivatives at two states, so the tests can measure both
against the double-double value and hold grid-gen to Pinocchio's accuracy.

Everything is stored in the tool's own joint order with joint names, so that the Rust
tests match by name and never borrow grid-gen's ordering. Seeded: rerunning gives the
same files (for the same pin/yourdfpy versions, recorded in each file).

Usage: python3 scripts/make_fixtures.py [--check] [ROBOT...]   (needs `pip install pin yourdfpy`)

--check recomputes every fixture and compares it with the checked-in file instead of
writing: strings exactly, numbers per array to 1e-12 relative in the max norm (the
same library on another CPU may round differently in the last bits).
"""
import json
import pathlib
import sys
import tomllib

import numpy as np
import pinocchio as pin
import yourdfpy

ROOT = pathlib.Path(__file__).resolve().parent.parent
ROBOTS = ROOT / "robots"
OUT = ROOT / "tests" / "fixtures"
RANDOM_STATES = 10


def movable_joints(model, first=1, mimic=True):
    """(name, idx_q, nq, idx_v, lower, upper) for every 1-DoF joint from joint `first` on
    (2: after a free-flyer), in Pinocchio order; `mimic=False` leaves out a mimic model's
    mimic joints (nv = 0)."""
    out = []
    for jid in range(first, model.njoints):
        j = model.joints[jid]
        if not mimic and j.nv == 0:
            continue
        assert j.nv == 1, f"{model.names[jid]}: nv={j.nv}"
        lo = model.lowerPositionLimit[j.idx_q] if j.nq == 1 else -np.pi
        hi = model.upperPositionLimit[j.idx_q] if j.nq == 1 else np.pi
        # Limits of +-1e5 (Atlas) or missing limits mean "unlimited": sample in [-pi, pi].
        if not np.isfinite(lo) or not np.isfinite(hi) or hi - lo > 100 or hi <= lo:
            lo, hi = -np.pi, np.pi
        out.append((model.names[jid], j.idx_q, j.nq, j.idx_v, lo, hi))
    return out


def to_pin_q(model, joints, angles):
    q = np.zeros(model.nq)
    for (name, iq, nq, iv, lo, hi), a in zip(joints, angles):
        if nq == 2:  # continuous joints are stored as (cos, sin)
            q[iq], q[iq + 1] = np.cos(a), np.sin(a)
        else:
            q[iq] = a
    return q


def states(joints, rng):
    n = len(joints)
    lo = np.array([j[4] for j in joints])
    hi = np.array([j[5] for j in joints])
    out = []
    for _ in range(RANDOM_STATES):
        out.append(("random", rng.uniform(lo, hi), rng.normal(size=n), rng.normal(size=n), rng.normal(size=n) * 10))
    out.append(("zero", np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)))
    out.append(("lower limits", lo.copy(), rng.normal(size=n), rng.normal(size=n), rng.normal(size=n)))
    out.append(("upper limits", hi.copy(), rng.normal(size=n), rng.normal(size=n), rng.normal(size=n)))
    for speed in (1e-8, 1e3):
        out.append((f"speed {speed:g}", rng.uniform(lo, hi), rng.normal(size=n) * speed, rng.normal(size=n) * speed, rng.normal(size=n) * speed))
    return out


def mat(m):
    return [[float(x) for x in row] for row in np.asarray(m)]


def pinocchio_record(model, data, q, perm, qd, qdd, tau):
    """Pinocchio's outputs at (q, qd, qdd) and (q, qd, tau), vectors and matrices in listing
    order (`perm[k]` is the idx_v of the k-th listed coordinate)."""
    sel = lambda v: np.asarray(v)[perm]
    selm = lambda m: np.asarray(m)[np.ix_(perm, perm)]
    v = np.zeros(model.nv); a = np.zeros(model.nv); t = np.zeros(model.nv)
    v[perm] = qd; a[perm] = qdd; t[perm] = tau
    rnea = pin.rnea(model, data, q, v, a).copy()
    dq, dv, _ = pin.computeRNEADerivatives(model, data, q, v, a)
    dq, dv = dq.copy(), dv.copy()
    M = pin.crba(model, data, q).copy()
    M = np.triu(M) + np.triu(M, 1).T
    Mi = pin.computeMinverse(model, data, q).copy()
    Mi = np.triu(Mi) + np.triu(Mi, 1).T
    fd = pin.aba(model, data, q, v, t).copy()
    pin.computeABADerivatives(model, data, q, v, t)
    return {
        "qd": [float(x) for x in qd], "qdd": [float(x) for x in qdd], "tau": [float(x) for x in tau],
        "rnea": [float(x) for x in sel(rnea)], "drnea_dq": mat(selm(dq)), "drnea_dqd": mat(selm(dv)),
        "M": mat(selm(M)), "Minv": mat(selm(Mi)), "fd": [float(x) for x in sel(fd)],
        "dfd_dq": mat(selm(data.ddq_dq)), "dfd_dqd": mat(selm(data.ddq_dv)),
    }


def pinocchio_fixture(path, rng):
    return pinocchio_fixture_of(pin.buildModelFromUrdf(str(path)), rng)


def pinocchio_fixture_of(model, rng, static=False):
    """`static`: every state at q̇ = 0 (a scene's `static = true`)."""
    data = model.createData()
    joints = movable_joints(model)
    perm = [j[3] for j in joints]  # idx_v of each joint in listing order
    records = []
    for kind, ang, qd, qdd, tau in states(joints, rng):
        if static:
            qd = np.zeros_like(qd)
        q = to_pin_q(model, joints, ang)
        records.append({"kind": kind, "q": [float(x) for x in ang], **pinocchio_record(model, data, q, perm, qd, qdd, tau)})
    return {
        "tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear],
        "joint_names": [j[0] for j in joints], "states": records,
    }


FLOATING = ["grid_hyq", "grid_atlas", "grid_iiwa", "ur5"]
# Two more legged robots, for the floating base only (test fixtures, not bundled robots):
# example-robot-data 6.0.0's solo12.urdf and go2.urdf (BSD-2, tests/fixtures/LICENSE.example-robot-data).
FLOATING_FIXTURE_ROBOTS = ["solo12", "go2"]
FREE_FLYER = ["vx", "vy", "vz", "wx", "wy", "wz"]


def floating_fixture(path, rng):
    """The robot on a free-flyer (`buildModelFromUrdf(path, JointModelFreeFlyer())`, grid-gen's
    `--floating-base`): `base` holds q's first seven entries [x, y, z, qx, qy, qz, qw]; `q` the
    joint angles after it, in listing order; velocities and every matrix list the free-flyer's
    six coordinates first as root_joint_vx ... root_joint_wz. Random base poses (uniform
    rotations), an upside-down base, and large base speeds."""
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    data = model.createData()
    assert model.names[1] == "root_joint" and model.joints[1].nv == 6
    joints = movable_joints(model, first=2)
    perm = list(range(6)) + [j[3] for j in joints]
    n = len(joints)
    lo = np.array([j[4] for j in joints])
    hi = np.array([j[5] for j in joints])
    cases = []
    for _ in range(RANDOM_STATES):
        cases.append(("random", pin.Quaternion(pin.SE3.Random().rotation).coeffs(), 1.0))
    cases.append(("upside down", np.array([1.0, 0.0, 0.0, 0.0]), 1.0))
    cases.append(("base speed 1e3", pin.Quaternion(pin.SE3.Random().rotation).coeffs(), 1e3))
    records = []
    for kind, quat, speed in cases:
        quat = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
        base = np.concatenate([rng.normal(size=3), quat])
        ang = rng.uniform(lo, hi)
        qd = rng.normal(size=6 + n); qd[:6] *= speed
        qdd = rng.normal(size=6 + n); qdd[:6] *= speed
        tau = rng.normal(size=6 + n) * 10
        q = np.zeros(model.nq)
        q[:7] = base
        q[7:] = to_pin_q(model, joints, ang)[7:]
        records.append({"kind": kind, "base": [float(x) for x in base], "q": [float(x) for x in ang], **pinocchio_record(model, data, q, perm, qd, qdd, tau)})
    return {
        "tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear],
        "joint_names": [f"root_joint_{c}" for c in FREE_FLYER] + [j[0] for j in joints], "states": records,
    }


def floating_fixtures(check):
    stale = False
    for robot in FLOATING + FLOATING_FIXTURE_ROBOTS:
        urdf = (ROBOTS if robot in FLOATING else OUT) / f"{robot}.urdf"
        # pin.SE3.Random draws from Eigen's generator: seed it too, so reruns are identical.
        pin.seed(sum(robot.encode()))
        data = floating_fixture(urdf, np.random.default_rng(sum(robot.encode()) + 1))
        # Pinocchio's own last-bit rounding differs across CPUs (glibc picks its sin/cos by
        # CPU features) and M's conditioning amplifies it: UR5 on a free-flyer (cond(M) 7.1e3
        # at state 7) recomputes M⁻¹ 2.4e-12 apart on an Intel Xeon from the file written on
        # an AMD EPYC. 1e-10 is still the bar every comparison with these files is held to.
        stale |= report(OUT / f"{robot}.floating.pinocchio.json", data, check, 1e-10)
    return stale


# --mimic coupled: the Panda's finger (finger_joint2 = finger_joint1) and
# mimic_arm, a synthetic arm written here with revolute and prismatic mimics whose
# multipliers are not 1 and offsets not 0, on two branches.
MIMIC = [("panda", ROBOTS / "panda.urdf"), ("mimic_arm", OUT / "mimic_arm.urdf")]


def mimic_arm_urdf():
    """A 7-joint tree: shoulder, elbow, elbow_follower (= -0.7 elbow + 0.3, another axis),
    wrist; slide (prismatic), slide_follower (= 1.5 slide - 0.02), shoulder_follower
    (= 2 shoulder - 0.1) on the slide's branch. Full inertias, rotated inertial frames."""
    inertia = (0.02, 0.03, 0.025, 0.001, -0.002, 0.0015)

    def link(name, m, com):
        ixx, iyy, izz, ixy, ixz, iyz = inertia
        return (f'  <link name="{name}">\n    <inertial>\n      <origin xyz="{com[0]} {com[1]} {com[2]}" rpy="0.1 -0.2 0.3"/>\n'
                f'      <mass value="{m}"/>\n      <inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="{ixy}" ixz="{ixz}" iyz="{iyz}"/>\n'
                f'    </inertial>\n  </link>\n')

    def joint(name, kind, parent, child, xyz, rpy, axis, mimic=None):
        s = (f'  <joint name="{name}" type="{kind}">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
             f'    <origin xyz="{xyz}" rpy="{rpy}"/>\n    <axis xyz="{axis}"/>\n'
             f'    <limit lower="-2" upper="2" effort="10" velocity="5"/>\n')
        if mimic:
            s += f'    <mimic joint="{mimic[0]}" multiplier="{mimic[1]}" offset="{mimic[2]}"/>\n'
        return s + "  </joint>\n"

    return "".join([
        '<?xml version="1.0"?>\n<robot name="mimic_arm">\n  <link name="base"/>\n',
        joint("shoulder", "revolute", "base", "l1", "0 0 0.1", "0 0 0", "0 0 1"), link("l1", 1.2, (0.01, 0.02, 0.1)),
        joint("elbow", "revolute", "l1", "l2", "0.05 0 0.3", "0.2 0 0", "0 1 0"), link("l2", 0.9, (0.1, 0.0, 0.02)),
        joint("elbow_follower", "revolute", "l2", "l3", "0.3 0 0", "0 0.3 0", "1 0 0", ("elbow", -0.7, 0.3)), link("l3", 0.6, (0.05, 0.01, 0.0)),
        joint("wrist", "revolute", "l3", "l4", "0.2 0 0", "0 0 0.4", "0 0.6 0.8"), link("l4", 0.4, (0.02, 0.02, 0.02)),
        joint("slide", "prismatic", "l1", "l5", "0 0.1 0.2", "0 0 0", "0 0 1"), link("l5", 0.5, (0.0, 0.03, 0.0)),
        joint("slide_follower", "prismatic", "l5", "l6", "0 0.1 0", "0 0 0", "1 0 0", ("slide", 1.5, -0.02)), link("l6", 0.3, (0.01, 0.0, 0.01)),
        joint("shoulder_follower", "revolute", "l5", "l7", "0 0 0.1", "0 0 0", "0 0 1", ("shoulder", 2.0, -0.1)), link("l7", 0.2, (0.01, 0.01, 0.01)),
        "</robot>\n",
    ])


def mimic_fixture(path, rng):
    """Coupled mimic joints (grid-gen's `--mimic coupled`) against Pinocchio's mimic support,
    `buildModelFromUrdf(path, mimic=True)`, whose coordinates leave the mimic joints out.
    Pinocchio 4.1 computes only RNEA and CRBA on such a model (its ABA, M⁻¹ and derivatives
    raise "does not support Joint Mimic"), so `rnea` and `M` are its mimic model's, and the
    rest come from its ordinary model of the same URDF through the coupling map G (joint
    velocities = G × coordinate velocities): ∂c/∂u = Gᵀ (∂c_full/∂u) G, M⁻¹ = (Gᵀ M_full G)⁻¹,
    q̈ = M⁻¹ (τ − Gᵀ c_full(q, G q̇, 0)) and ∂q̈/∂u = −M⁻¹ Gᵀ (∂c_full/∂u) G at G q̈, with numpy's
    inverse. The script asserts that the two models agree on RNEA and M first."""
    import xml.etree.ElementTree as ET
    red = pin.buildModelFromUrdf(str(path), mimic=True)
    full = pin.buildModelFromUrdf(str(path))
    fdata = full.createData()
    coords = movable_joints(red, mimic=False)
    mimics = {j.get("name"): (m.get("joint"), float(m.get("multiplier", 1)), float(m.get("offset", 0)))
              for j in ET.parse(path).getroot().iter("joint") for m in j.iter("mimic")}
    fjoints = {j[0]: j for j in movable_joints(full)}
    rv = {name: iv for name, iq, nq, iv, lo, hi in coords}
    G = np.zeros((full.nv, red.nv))
    for name, (_, iq, nq, iv, lo, hi) in fjoints.items():
        target, mult, off = mimics.get(name, (name, 1.0, 0.0))
        G[iv, rv[target]] = mult
    perm = [j[3] for j in coords]
    sel = lambda v: np.asarray(v)[perm]
    selm = lambda m: np.asarray(m)[np.ix_(perm, perm)]
    sym = lambda m: np.triu(m) + np.triu(m, 1).T
    records = []
    for kind, ang, qd, qdd, tau in states(coords, rng):
        q = to_pin_q(red, coords, ang)
        qf = np.zeros(full.nq)
        for name, (_, iq, nq, iv, lo, hi) in fjoints.items():
            target, mult, off = mimics.get(name, (name, 1.0, 0.0))
            assert nq == 1 and target not in mimics
            qf[iq] = mult * q[red.joints[red.getJointId(target)].idx_q] + off
        v = np.zeros(red.nv); a = np.zeros(red.nv); t = np.zeros(red.nv)
        v[perm] = qd; a[perm] = qdd; t[perm] = tau
        # A fresh Data for each call: Pinocchio 4.1's crba on a mimic model whose mimic joint
        # has children returns a different M when called twice on one Data (measured: 2.7e-2
        # apart on mimic_arm at the same q); a fresh one agrees with its RNEA columns to 1e-15.
        rnea = pin.rnea(red, red.createData(), q, v, a).copy()
        M = sym(pin.crba(red, red.createData(), q).copy())
        Mf = sym(pin.crba(full, fdata, qf).copy())
        Mr = G.T @ Mf @ G
        rnea_g = G.T @ pin.rnea(full, fdata, qf, G @ v, G @ a)
        assert np.abs(rnea - rnea_g).max() <= 1e-12 * max(1.0, np.abs(rnea).max()), f"{path.name}: mimic RNEA"
        assert np.abs(M - Mr).max() <= 1e-12 * np.abs(M).max(), f"{path.name}: mimic M"
        dq, dv, _ = pin.computeRNEADerivatives(full, fdata, qf, G @ v, G @ a)
        dq, dv = dq.copy(), dv.copy()  # views into fdata, which the next call overwrites
        Mi = np.linalg.inv(Mr)
        Mi = (Mi + Mi.T) / 2
        fd = np.linalg.solve(Mr, t - G.T @ pin.rnea(full, fdata, qf, G @ v, np.zeros(full.nv)))
        fq, fv, _ = pin.computeRNEADerivatives(full, fdata, qf, G @ v, G @ fd)
        records.append({
            "kind": kind, "q": [float(x) for x in ang],
            "qd": [float(x) for x in qd], "qdd": [float(x) for x in qdd], "tau": [float(x) for x in tau],
            "rnea": [float(x) for x in sel(rnea)], "drnea_dq": mat(selm(G.T @ dq @ G)), "drnea_dqd": mat(selm(G.T @ dv @ G)),
            "M": mat(selm(M)), "Minv": mat(selm(Mi)), "fd": [float(x) for x in sel(fd)],
            "dfd_dq": mat(selm(-Mi @ G.T @ fq @ G)), "dfd_dqd": mat(selm(-Mi @ G.T @ fv @ G)),
        })
    return {
        "tool": f"pinocchio {pin.__version__} (mimic=True for rnea and M; the rest from its ordinary model through G)",
        "gravity": [float(x) for x in red.gravity.linear],
        "joint_names": [j[0] for j in coords], "mimic": {k: list(v) for k, v in sorted(mimics.items())}, "states": records,
    }


def mimic_fixtures(check):
    stale = report(OUT / "mimic_arm.urdf", mimic_arm_urdf(), check, 0)
    for robot, urdf in MIMIC:
        if not urdf.exists():
            return True
        data = mimic_fixture(urdf, np.random.default_rng(sum(robot.encode()) + 2))
        stale |= report(OUT / f"{robot}.mimic.pinocchio.json", data, check, 1e-12)
    return stale


# Spherical joints: ball_arm, a synthetic tree written here (URDF has no
# spherical type; grid-gen reads `type="spherical"` as an extension), with a spherical joint
# on the root, one between moving bodies and one at a leaf. Pinocchio's model of it is built
# joint by joint from the same table with JointModelSpherical, not from the URDF.
# (name, type, parent link, child link, xyz, rpy, axis, mass, com)
BALL_ARM = [
    ("shoulder", "spherical", "base", "l1", (0, 0, 0.1), (0.1, 0.2, 0.3), None, 1.2, (0.01, 0.02, 0.1)),
    ("elbow", "revolute", "l1", "l2", (0.05, 0, 0.3), (0.2, 0, 0), (0, 1, 0), 0.9, (0.1, 0.0, 0.02)),
    ("wrist", "spherical", "l2", "l3", (0.3, 0, 0), (0, 0.3, 0), None, 0.6, (0.05, 0.01, 0.0)),
    ("hand", "revolute", "l3", "l4", (0.2, 0, 0), (0, 0, 0.4), (0, 0.6, 0.8), 0.4, (0.02, 0.02, 0.02)),
    ("slide", "prismatic", "l1", "l5", (0, 0.1, 0.2), (0, 0, 0), (0, 0, 1), 0.5, (0.0, 0.03, 0.0)),
    ("tip", "spherical", "l5", "l6", (0, 0.1, 0), (0.3, 0, 0), None, 0.3, (0.01, 0.0, 0.01)),
]
BALL_INERTIA = (0.02, 0.03, 0.025, 0.001, -0.002, 0.0015)  # ixx iyy izz ixy ixz iyz
BALL_INERTIAL_RPY = (0.1, -0.2, 0.3)
# The base link's mass and centre of mass: on a free-flyer, a massless base under a
# spherical joint would make M singular (two rotations of the same bodies about one point).
BALL_BASE = (2.0, (0.0, 0.0, 0.05))
SPHERICAL = ["wx", "wy", "wz"]


def ball_arm_urdf():
    ixx, iyy, izz, ixy, ixz, iyz = BALL_INERTIA
    out = ['<?xml version="1.0"?>\n<robot name="ball_arm">\n']
    links = [(name, child, m, com) for name, kind, parent, child, xyz, rpy, axis, m, com in BALL_ARM]
    for name, child, m, com in [(None, "base", *BALL_BASE)] + links:
        if name:
            _, kind, parent, _, xyz, rpy, axis, _, _ = next(j for j in BALL_ARM if j[0] == name)
            out.append(f'  <joint name="{name}" type="{kind}">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
                       f'    <origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/>\n')
            if axis:
                out.append(f'    <axis xyz="{axis[0]} {axis[1]} {axis[2]}"/>\n    <limit lower="-2" upper="2" effort="10" velocity="5"/>\n')
            out.append("  </joint>\n")
        r = BALL_INERTIAL_RPY
        out.append(f'  <link name="{child}">\n    <inertial>\n      <origin xyz="{com[0]} {com[1]} {com[2]}" rpy="{r[0]} {r[1]} {r[2]}"/>\n'
                   f'      <mass value="{m}"/>\n      <inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="{ixy}" ixz="{ixz}" iyz="{iyz}"/>\n'
                   f'    </inertial>\n  </link>\n')
    out.append("</robot>\n")
    return "".join(out)


def ball_arm_model(floating):
    """Pinocchio's model of BALL_ARM, joint by joint (optionally on a free-flyer, as
    grid-gen's --floating-base): the coordinate names in order, and the model."""
    model = pin.Model()
    ixx, iyy, izz, ixy, ixz, iyz = BALL_INERTIA
    ic = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    rc = pin.rpy.rpyToMatrix(*BALL_INERTIAL_RPY)
    joint_of = {"base": 0}
    names = []
    inertia = lambda m, com: pin.Inertia(m, np.array(com, dtype=float), rc @ ic @ rc.T)
    if floating:
        joint_of["base"] = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root_joint")
        model.appendBodyToJoint(joint_of["base"], inertia(*BALL_BASE), pin.SE3.Identity())
        names += [f"root_joint_{c}" for c in FREE_FLYER]
    for name, kind, parent, child, xyz, rpy, axis, m, com in BALL_ARM:
        placement = pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.array(xyz, dtype=float))
        if kind == "spherical":
            jm = pin.JointModelSpherical()
            names += [f"{name}_{c}" for c in SPHERICAL]
        else:
            a = np.array(axis, dtype=float) / np.linalg.norm(axis)
            jm = pin.JointModelRevoluteUnaligned(a) if kind == "revolute" else pin.JointModelPrismaticUnaligned(a)
            names.append(name)
        jid = model.addJoint(joint_of[parent], jm, placement, name)
        model.appendBodyToJoint(jid, inertia(m, com), pin.SE3.Identity())
        joint_of[child] = jid
    return names, model


def ball_fixture(floating, rng):
    """Spherical joints against JointModelSpherical: `q` is Pinocchio's whole q (each
    quaternion [qx, qy, qz, qw] at its joint's idx_q, which is grid-gen's layout too), the
    rest as in every fixture. Random rotations (uniform: normalised 4-d Gaussians),
    unrotated joints, half turns (w = 0), and speeds of 1e3."""
    names, model = ball_arm_model(floating)
    data = model.createData()
    cases = [("random", 1.0, None)] * RANDOM_STATES + [("unrotated", 1.0, (0, 0, 0, 1)), ("half turn", 1.0, (1, 0, 0, 0)), ("speed 1e3", 1e3, None)]
    records = []
    for kind, speed, quat in cases:
        q = np.zeros(model.nq)
        for jid in range(1, model.njoints):
            j = model.joints[jid]
            if j.nq == 4 or j.nq == 7:
                x = np.array(quat, dtype=float) if quat else rng.normal(size=4)
                q[j.idx_q + j.nq - 4:j.idx_q + j.nq] = x / np.linalg.norm(x)
                if j.nq == 7:
                    q[j.idx_q:j.idx_q + 3] = rng.normal(size=3)
            else:
                q[j.idx_q] = rng.uniform(-2, 2)
        qd, qdd, tau = rng.normal(size=model.nv) * speed, rng.normal(size=model.nv) * speed, rng.normal(size=model.nv) * 10
        records.append({"kind": kind, "q": [float(x) for x in q], **pinocchio_record(model, data, q, list(range(model.nv)), qd, qdd, tau)})
    return {"tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear], "joint_names": names, "states": records}


def ball_fixtures(check):
    stale = report(OUT / "ball_arm.urdf", ball_arm_urdf(), check, 0)
    for floating in (False, True):
        data = ball_fixture(floating, np.random.default_rng(3 + floating))
        stale |= report(OUT / f"ball_arm{'.floating' if floating else ''}.pinocchio.json", data, check, 1e-12)
    return stale


SCENES = [("grid_iiwa", "iiwa_wrist_locked"), ("grid_hyq", "hyq_knees_locked"), ("grid_iiwa", "iiwa_static")]


def scene_model(urdf, scene_file):
    """The robot in a grid-gen scene, built the Pinocchio way: buildReducedModel for
    [lock], payloads appended to the inertia of the joint that carries the link's frame."""
    model = pin.buildModelFromUrdf(str(urdf))
    scene = tomllib.loads(scene_file.read_text())
    assert not scene.get("keep") and not scene.get("drop"), "Pinocchio has no subtree removal; those scenes are tested against edited URDFs"
    q0 = pin.neutral(model)
    locked = []
    for name, value in scene.get("lock", {}).items():
        jid = model.getJointId(name)
        j = model.joints[jid]
        if j.nq == 2:
            q0[j.idx_q], q0[j.idx_q + 1] = np.cos(value), np.sin(value)
        else:
            q0[j.idx_q] = value
        locked.append(jid)
    reduced = pin.buildReducedModel(model, locked, q0)
    payloads = scene.get("payload", [])
    for p in [payloads] if isinstance(payloads, dict) else payloads:
        frame = reduced.frames[reduced.getFrameId(p["link"])]
        ixx, ixy, ixz, iyy, iyz, izz = p.get("inertia", [0.0] * 6)
        inertia = pin.Inertia(p["mass"], np.array(p.get("com", [0.0] * 3)), np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
        reduced.inertias[frame.parentJoint] = reduced.inertias[frame.parentJoint] + frame.placement.act(inertia)
    if "gravity" in scene:
        reduced.gravity.linear = np.array(scene["gravity"])
    return reduced


def scene_fixtures(check):
    stale = False
    for robot, scene in SCENES:
        scene_file = ROOT / "examples" / "scenes" / f"{scene}.toml"
        model = scene_model(ROBOTS / f"{robot}.urdf", scene_file)
        static = tomllib.loads(scene_file.read_text()).get("static", False)
        data = pinocchio_fixture_of(model, np.random.default_rng(sum(scene.encode())), static)
        stale |= report(OUT / f"{robot}.{scene}.pinocchio.json", data, check, 1e-12)
    return stale


def yourdfpy_fixture(path, rng):
    robot = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=True, build_collision_scene_graph=False)
    joints = []
    for j in robot.robot.joints:
        joints.append({
            "name": j.name, "type": j.type, "parent": j.parent, "child": j.child,
            "origin": mat(j.origin if j.origin is not None else np.eye(4)),
            "axis": [float(x) for x in (j.axis if j.axis is not None else [1, 0, 0])],
        })
    actuated = robot.actuated_joint_names
    poses = []
    for _ in range(5):
        cfg = rng.uniform(-1.5, 1.5, size=len(actuated))
        robot.update_cfg(dict(zip(actuated, cfg)))
        links = {link: mat(robot.get_transform(link, robot.base_link)) for link in robot.link_map}
        poses.append({"q": dict(zip(actuated, [float(x) for x in cfg])), "link_poses": links})
    return {"tool": f"yourdfpy {yourdfpy.__version__ if hasattr(yourdfpy, '__version__') else ''}".strip(),
            "robot": robot.robot.name, "base_link": robot.base_link, "joints": joints, "configurations": poses}


CHAIN_LINKS = 100
CHAIN_STATES = 2


def chain_urdf(n):
    """The same text as grid_gen_test_support::chain_urdf(n) (a Rust test checks it)."""
    s = '<robot name="chain"><link name="l0"/>'
    for i in range(1, n + 1):
        axis = ["1 0 0", "0 1 0", "0 0 1"][i % 3]
        s += (f'<link name="l{i}"><inertial><origin xyz="0 0 0.05"/><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>'
              f'<joint name="j{i}" type="revolute"><parent link="l{i - 1}"/><child link="l{i}"/><origin xyz="0 0 0.1"/><axis xyz="{axis}"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>')
    return s + "</robot>"


def chain_fixture(path, rng):
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    assert model.nq == model.nv == CHAIN_LINKS
    records = []
    for _ in range(CHAIN_STATES):
        q, v, tau = (rng.uniform(-3, 3, size=model.nv) for _ in range(3))
        fd = pin.aba(model, data, q, v, tau).copy()
        pin.computeABADerivatives(model, data, q, v, tau)
        records.append({"q": [float(x) for x in q], "qd": [float(x) for x in v], "tau": [float(x) for x in tau],
                        "fd": [float(x) for x in fd], "dfd_dq": mat(data.ddq_dq), "dfd_dqd": mat(data.ddq_dv)})
    return {"tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear],
            "joint_names": [model.names[j] for j in range(1, model.njoints)], "states": records}


def differences(new, old, where="", tol=1e-12):
    """Yields where two fixtures differ beyond round-off."""
    if isinstance(new, dict):
        if not isinstance(old, dict) or set(new) != set(old):
            yield f"{where}: keys differ"
            return
        for k in new:
            yield from differences(new[k], old[k], f"{where}.{k}", tol)
    elif isinstance(new, list) and new and all(isinstance(x, (int, float, list)) for x in new) and not any(isinstance(x, dict) for x in new):
        try:
            a, b = np.array(new, dtype=float), np.array(old, dtype=float)
        except (ValueError, TypeError):
            yield f"{where}: shapes differ"
            return
        if a.shape != b.shape:
            yield f"{where}: shapes differ"
        elif a.size and np.max(np.abs(a - b)) > tol * max(np.max(np.abs(b)), 1e-300):
            yield f"{where}: values differ by {np.max(np.abs(a - b)):.3e}"
    elif isinstance(new, list):
        if not isinstance(old, list) or len(new) != len(old):
            yield f"{where}: lengths differ"
            return
        for i, (x, y) in enumerate(zip(new, old)):
            yield from differences(x, y, f"{where}[{i}]", tol)
    elif new != old and not (isinstance(new, str) and where.endswith(".tool")):
        yield f"{where}: {new!r} != {old!r}"


def report(target, data, check, tol):
    """Writes `data` to `target`, or with `check` compares; returns whether it was stale."""
    if not check:
        target.write_text(data if isinstance(data, str) else json.dumps(data, indent=None) + "\n")
        print(f"wrote {target.name}")
        return False
    if not target.exists():
        diffs = ["missing"]
    elif isinstance(data, str):
        diffs = [] if target.read_text() == data else ["text differs"]
    else:
        diffs = list(differences(json.loads(json.dumps(data)), json.loads(target.read_text()), tol=tol))
    if diffs:
        print(f"{target.name}: stale: " + "; ".join(diffs[:5]), file=sys.stderr)
        return True
    print(f"{target.name}: up to date")
    return False


def chain_fixtures(check):
    urdf = OUT / f"chain{CHAIN_LINKS}.urdf"
    stale = report(urdf, chain_urdf(CHAIN_LINKS) + "\n", check, 0)
    # Pinocchio's own rounding, amplified by cond(M) ~ 3e5 on this chain, may move the last
    # ~5 digits on another CPU: compare to 1e-9 here, not 1e-12.
    if not urdf.exists():
        return True
    data = chain_fixture(urdf, np.random.default_rng(CHAIN_LINKS))
    return report(OUT / f"chain{CHAIN_LINKS}.pinocchio.json", data, check, 1e-9) or stale


# Frames: (robot, floating, link names). BODY frames of buildModelFromUrdf, named after the
# links; links merged by fixed joints (UR5's tool0, go2's feet, the Panda's TCP) included.
FRAMES = [
    ("grid_iiwa", False, ["iiwa_link_7", "iiwa_link_0", "base"]),
    ("grid_hyq", False, ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]),
    ("grid_hyq", True, ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg", "base_link_0"]),
    ("grid_atlas", False, ["l_hand", "r_hand", "l_foot", "r_foot"]),
    ("grid_atlas", True, ["l_hand", "r_hand", "l_foot", "r_foot"]),
    ("ur5", False, ["tool0", "ee_link", "world"]),
    ("panda", False, ["panda_hand_tcp", "panda_leftfinger"]),
    ("go2", True, ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]),
]
REFERENCE_FRAMES = {"local": pin.LOCAL, "world": pin.WORLD, "local_world_aligned": pin.LOCAL_WORLD_ALIGNED}


def frames_fixture(path, floating, names, rng):
    """Frame kinematics at random, limit, large-angle (±1e3 rad) and fast (1e3) states:
    per frame, framesForwardKinematics' translation and rotation, getFrameJacobian in the three
    reference frames (rows [linear; angular], columns in listing order), getFrameVelocity and
    getFrameClassicalAcceleration in the three. With `floating`, `base` holds q's first seven
    entries and the free-flyer's six coordinates are listed first, as in the floating fixtures."""
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(str(path))
    data = model.createData()
    joints = movable_joints(model, first=2 if floating else 1)
    perm = (list(range(6)) if floating else []) + [j[3] for j in joints]
    ids = [model.getFrameId(n, pin.BODY) for n in names]
    assert all(i < model.nframes for i in ids), names
    n = len(joints)
    cases = states(joints, rng)
    cases.append(("large angles", rng.uniform(-1e3, 1e3, size=n), rng.normal(size=n), rng.normal(size=n), None))
    records = []
    for kind, ang, qd, qdd, _ in cases:
        q = to_pin_q(model, joints, ang)
        record = {"kind": kind, "q": [float(x) for x in ang]}
        speed = 1e3 if kind == "speed 1000" else 1.0
        if floating:
            quat = pin.Quaternion(pin.SE3.Random().rotation).coeffs()
            base = np.concatenate([rng.normal(size=3), quat / np.linalg.norm(quat)])
            q[:7] = base
            record["base"] = [float(x) for x in base]
            qd = np.concatenate([rng.normal(size=6) * speed, qd])
            qdd = np.concatenate([rng.normal(size=6) * speed, qdd])
        v = np.zeros(model.nv); a = np.zeros(model.nv)
        v[perm] = qd; a[perm] = qdd
        record["qd"] = [float(x) for x in qd]
        record["qdd"] = [float(x) for x in qdd]
        pin.forwardKinematics(model, data, q, v, a)
        pin.updateFramePlacements(model, data)
        pin.computeJointJacobians(model, data, q)
        frames = {}
        for name, fid in zip(names, ids):
            oMf = data.oMf[fid]
            frames[name] = {
                "translation": [float(x) for x in oMf.translation],
                "rotation": mat(oMf.rotation),
                "jacobian": {k: mat(pin.getFrameJacobian(model, data, fid, rf)[:, perm]) for k, rf in REFERENCE_FRAMES.items()},
                "velocity": {k: [float(x) for x in pin.getFrameVelocity(model, data, fid, rf).vector] for k, rf in REFERENCE_FRAMES.items()},
                "classical_acceleration": {k: [float(x) for x in pin.getFrameClassicalAcceleration(model, data, fid, rf).linear] for k, rf in REFERENCE_FRAMES.items()},
            }
        # getFrameAccelerationDerivatives gives the spatial acceleration's derivatives (and
        # the velocity's in q); the classical acceleration a_lin + w x v_lin composes them:
        # d/dq = da_lin/dq + [w]x dv_lin/dq - [v_lin]x dw/dq, d/dv likewise with J = da/da.
        # In LOCAL only, where the quantity is the frame's own (no rotation of the axes).
        pin.computeForwardKinematicsDerivatives(model, data, q, v, a)
        for name, fid in zip(names, ids):
            v_dq, a_dq, a_dv, a_da = (np.asarray(m).copy() for m in pin.getFrameAccelerationDerivatives(model, data, fid, pin.LOCAL))
            vel = pin.getFrameVelocity(model, data, fid, pin.LOCAL)
            w, vl = vel.angular, vel.linear
            skew = lambda x: np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])
            dq = a_dq[:3] + skew(w) @ v_dq[:3] - skew(vl) @ v_dq[3:]
            dv = a_dv[:3] + skew(w) @ a_da[:3] - skew(vl) @ a_da[3:]
            frames[name]["classical_acceleration_derivatives_local"] = {
                "dq": mat(dq[:, perm]), "dqd": mat(dv[:, perm]), "dqdd": mat(a_da[:3][:, perm]),
            }
        record["frames"] = frames
        records.append(record)
    listed = ([f"root_joint_{c}" for c in FREE_FLYER] if floating else []) + [j[0] for j in joints]
    return {"tool": f"pinocchio {pin.__version__}", "joint_names": listed, "frames": names, "states": records}


def frames_fixtures(check):
    stale = False
    for robot, floating, names in FRAMES:
        urdf = (ROBOTS if (ROBOTS / f"{robot}.urdf").exists() else OUT) / f"{robot}.urdf"
        seed = sum(robot.encode()) + 7 + floating
        pin.seed(seed)
        data = frames_fixture(urdf, floating, names, np.random.default_rng(seed))
        stale |= report(OUT / f"{robot}{'.floating' if floating else ''}.frames.pinocchio.json", data, check, 1e-12)
    return stale


# The discrete step (Crocoddyl's schemes composed from Pinocchio's aba,
# computeABADerivatives, integrate and dIntegrate): (robot, floating, dt).
STEPS = [("grid_iiwa", False, 0.01), ("grid_hyq", True, 0.01), ("ball_arm", True, 0.02)]
SCHEMES = ["semi_implicit_euler", "explicit_euler", "rk4"]


def step_model(robot, floating):
    """The model, grid-gen's coordinate names, the idx_v of each listed coordinate, and the
    idx_q of each of grid-gen's q entries (its layout: the base's seven, then each listed
    coordinate's angle; spherical joints' quaternions where Pinocchio keeps them)."""
    if robot == "ball_arm":
        names, model = ball_arm_model(floating)
        return model, names, list(range(model.nv)), list(range(model.nq))
    urdf = (ROBOTS if (ROBOTS / f"{robot}.urdf").exists() else OUT) / f"{robot}.urdf"
    model = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(str(urdf))
    joints = movable_joints(model, first=2 if floating else 1)
    assert all(j[2] == 1 for j in joints), "one q entry per listed joint"
    names = ([f"root_joint_{c}" for c in FREE_FLYER] if floating else []) + [j[0] for j in joints]
    perm = (list(range(6)) if floating else []) + [j[3] for j in joints]
    qidx = (list(range(7)) if floating else []) + [j[1] for j in joints]
    return model, names, perm, qidx


def step_record(model, data, q, v, tau, dt, scheme, act, fext=None, contacts=()):
    """(q+, v+, A, B) in Pinocchio's own order; `act` the idx_v of the actuated coordinates.
    The dynamics are aba under `fext` (a StdVec_Force, held over the step) or, with
    `contacts`, constraintDynamics with them rigid (Crocoddyl's contact dynamics inside its
    integrated action models)."""
    nv = model.nv

    def f(q, v):
        if contacts:
            out = contact_record(model, data, q, v, tau, contacts)
            return out["qdd"], out["dqdd_dq"], out["dqdd_dqd"], np.asarray(out["dqdd_dtau"])[:, act].copy()
        args = (model, data, q, v, tau) + ((fext,) if fext is not None else ())
        a = pin.aba(*args).copy()
        pin.computeABADerivatives(*args)
        mi = np.triu(data.Minv) + np.triu(data.Minv, 1).T
        return a, data.ddq_dq.copy(), data.ddq_dv.copy(), mi[:, act].copy()

    def jint(q, dx):
        jx, jdx = np.eye(2 * nv), np.eye(2 * nv)
        jx[:nv, :nv] = pin.dIntegrate(model, q, dx[:nv], pin.ARG0)
        jdx[:nv, :nv] = pin.dIntegrate(model, q, dx[:nv], pin.ARG1)
        return jx, jdx

    nu = len(act)
    if scheme != "rk4":
        a, da_dq, da_dv, da_du = f(q, v)
        v1 = v + dt * a
        dq = dt * (v1 if scheme == "semi_implicit_euler" else v)
        jq = pin.dIntegrate(model, q, dq, pin.ARG0)
        jv = pin.dIntegrate(model, q, dq, pin.ARG1)
        avq, avv, bv = dt * da_dq, np.eye(nv) + dt * da_dv, dt * da_du
        if scheme == "semi_implicit_euler":
            aqq, aqv, bq = jq + dt * jv @ avq, dt * jv @ avv, dt * jv @ bv
        else:
            aqq, aqv, bq = jq, dt * jv, np.zeros((nv, nu))
        return pin.integrate(model, q, dq), v1, np.block([[aqq, aqv], [avq, avv]]), np.vstack([bq, bv])
    # Crocoddyl's IntegratedActionModelRK4 (calc and calcDiff).
    dx, dx_dx, dx_du = np.zeros(2 * nv), np.zeros((2 * nv, 2 * nv)), np.zeros((2 * nv, nu))
    k_prev = dk_dx_prev = dk_du_prev = None
    for i, (c, w) in enumerate([(0.0, 1.0), (0.5, 2.0), (0.5, 2.0), (1.0, 1.0)]):
        if i == 0:
            yq, yv, dy_dx, dy_du = q, v, np.eye(2 * nv), np.zeros((2 * nv, nu))
        else:
            d = c * dt * k_prev
            yq, yv = pin.integrate(model, q, d[:nv]), v + d[nv:]
            jx, jdx = jint(q, d)
            dy_dx, dy_du = jx + c * dt * jdx @ dk_dx_prev, c * dt * jdx @ dk_du_prev
        a, da_dq, da_dv, da_du = f(yq, yv)
        df = np.block([[np.zeros((nv, nv)), np.eye(nv)], [da_dq, da_dv]])
        dk_dx, dk_du = df @ dy_dx, df @ dy_du
        dk_du[nv:] += da_du
        k_prev = np.concatenate([yv, a])
        dx += w * dt / 6 * k_prev
        dx_dx += w * dt / 6 * dk_dx
        dx_du += w * dt / 6 * dk_du
        dk_dx_prev, dk_du_prev = dk_dx, dk_du
    jx, jdx = jint(q, dx)
    return pin.integrate(model, q, dx[:nv]), v + dx[nv:], jx + jdx @ dx_dx, jdx @ dx_du


def random_q(model, floating, rng):
    """Pinocchio's q with each one-dof joint uniform within its limits (±π where it has
    none, or limits wider than 100) and, on a floating base, a position N(0, 1) and a
    uniformly random unit quaternion."""
    q = pin.neutral(model)
    for jid in range(2 if floating else 1, model.njoints):
        j = model.joints[jid]
        lo, hi = model.lowerPositionLimit[j.idx_q], model.upperPositionLimit[j.idx_q]
        q[j.idx_q] = rng.uniform(lo, hi) if np.isfinite(lo) and np.isfinite(hi) and hi - lo < 100 else rng.uniform(-np.pi, np.pi)
    if floating:
        quat = rng.normal(size=4)
        q[:7] = np.concatenate([rng.normal(size=3), quat / np.linalg.norm(quat)])
    return q


def step_fixture(robot, floating, dt, rng, fext_joints=(), contacts=(), schemes=SCHEMES, randoms=6):
    """Random states (uniform base rotations and joint quaternions), a fast one (speeds of
    30 rad/s, so that dt q̇ turns the base by a few tenths of a radian) and a still one; τ on
    the actuated coordinates (all but the free-flyer's six). Per scheme: q+ in grid-gen's q
    layout, q̇+, A (2nv x 2nv) and B (2nv x nu), rows and columns [δq; δq̇] in listing order.
    With `fext_joints`, each state has a random fext on their bodies (N(0, 10), held over
    the step); with `contacts`, they are rigid. `randoms` random states, and `schemes`
    only (the humanoid's: one scheme and fewer states keep its fixture small)."""
    model, names, perm, qidx = step_model(robot, floating)
    data = model.createData()
    nv = model.nv
    actuated = [k for k in range(nv) if not (floating and k < 6)]
    records = []
    for kind, speed in [("random", 1.0)] * randoms + [("fast", 30.0), ("still", 0.0)]:
        q = pin.randomConfiguration(model, -np.ones(model.nq) * 2, np.ones(model.nq) * 2) if robot == "ball_arm" else None
        if q is None:
            q = random_q(model, floating, rng)
        listed_v = rng.normal(size=nv) * speed
        listed_tau = np.zeros(nv)
        listed_tau[actuated] = rng.normal(size=len(actuated)) * 10
        v, tau = np.zeros(nv), np.zeros(nv)
        v[perm], tau[perm] = listed_v, listed_tau
        act = [perm[k] for k in actuated]
        record = {"kind": kind, "q": [float(q[i]) for i in qidx], "qd": [float(x) for x in listed_v], "tau": [float(x) for x in listed_tau]}
        fext = None
        if fext_joints:
            fin = rng.normal(size=6 * len(fext_joints)) * 10
            fext = pin.StdVec_Force()
            for _ in range(model.njoints):
                fext.append(pin.Force.Zero())
            for k, name in enumerate(fext_joints):
                fext[model.getJointId(name)] = pin.Force(fin[6 * k:6 * k + 3], fin[6 * k + 3:6 * k + 6])
            record["fext"] = [float(x) for x in fin]
        for scheme in schemes:
            q1, v1, a, b = step_record(model, data, q, v, tau, dt, scheme, act, fext, contacts)
            record[scheme] = {
                "q_next": [float(q1[i]) for i in qidx], "qd_next": [float(x) for x in np.asarray(v1)[perm]],
                "A": mat(np.asarray(a)[np.ix_(perm + [nv + p for p in perm], perm + [nv + p for p in perm])]),
                "B": mat(np.asarray(b)[perm + [nv + p for p in perm], :]),
            }
        records.append(record)
    out = {
        "tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear], "dt": dt,
        "joint_names": names, "actuated": [names[k] for k in actuated], "states": records,
    }
    if fext_joints or contacts:
        out["fext"] = list(fext_joints)
        out["contacts"] = [{"frame": f, "type": k} for f, k in contacts]
    return out


def step_fixtures(check):
    stale = False
    for robot, floating, dt in STEPS:
        seed = sum(robot.encode()) + 31 + floating
        pin.seed(seed)
        np.random.seed(seed)
        data = step_fixture(robot, floating, dt, np.random.default_rng(seed))
        stale |= report(OUT / f"{robot}{'.floating' if floating else ''}.step.pinocchio.json", data, check, 1e-10)
    for label, robot, floating, dt, fext_joints, contacts, *rest in FORCED_STEPS:
        seed = sum(robot.encode()) + 37 + floating + len(label)
        pin.seed(seed)
        np.random.seed(seed)
        data = step_fixture(robot, floating, dt, np.random.default_rng(seed), fext_joints, contacts, *rest)
        stale |= report(OUT / f"{robot}{'.floating' if floating else ''}.{label}.step.pinocchio.json", data, check, 1e-10)
    return stale


# Steps under forces: fext held over the step (aba and computeABADerivatives with fext),
# and rigid contacts (constraintDynamics and its derivatives, as Crocoddyl's contact
# dynamics inside its integrated action models); Pinocchio's constraintDynamics takes no
# fext, so the two are separate. (label, robot, floating, dt, fext joints, contacts[,
# schemes, random states]). The humanoid (floating Atlas, 30 joints, both feet as 6-D
# contacts) is issue 56's: the semi-implicit step (Crocoddyl's default) on four states.
FORCED_STEPS = [
    ("fext", "grid_iiwa", False, 0.01, ["iiwa_joint_2", "iiwa_joint_5", "iiwa_joint_7"], []),
    ("contact", "grid_hyq", True, 0.01, [], [(f"{leg}_lowerleg", "point") for leg in ("lf", "rf", "lh", "rh")]),
    ("contact", "grid_iiwa", False, 0.01, [], [("iiwa_link_7", "wrench")]),
    ("contact", "grid_atlas", True, 0.01, [], [("l_foot", "wrench"), ("r_foot", "wrench")], ["semi_implicit_euler"], 2),
]


# External forces and contacts: (robot, floating, fext joints, contacts).
# fext is one Force per listed joint in its local frame (Pinocchio's fext); contacts are
# (frame, "point" | "wrench") with lambda in LOCAL_WORLD_ALIGNED axes at the frame.
FORCES = [
    ("grid_iiwa", False, ["iiwa_joint_2", "iiwa_joint_5", "iiwa_joint_7"], [("iiwa_link_7", "point")]),
    ("grid_hyq", True, "*", [(f"{leg}_lowerleg", "point") for leg in ("lf", "rf", "lh", "rh")]),
    ("go2", True, ["root_joint"], [(f"{leg}_foot", "point") for leg in ("FL", "FR", "RL", "RR")]),
    ("grid_atlas", True, ["root_joint", "l_arm_elx"], [("l_foot", "wrench"), ("r_foot", "wrench")]),
]


def contact_fext(model, data, contacts, lam):
    """The contact forces as Pinocchio fext (one Force per joint, local frames): lambda in
    LOCAL_WORLD_ALIGNED axes at each frame's origin, moved into the parent joint's frame.
    Needs data.oMi and data.oMf at q. Also (joint, p, force) per contact: p the frame's
    origin in the joint frame, force the contact's Force there."""
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    parts, at = [], 0
    for name, kind in contacts:
        fid = model.getFrameId(name, pin.BODY)
        jid = model.frames[fid].parentJoint
        n = 3 if kind == "point" else 6
        lw = np.concatenate([lam[at:at + n], np.zeros(6 - n)])
        at += n
        lwa = pin.SE3(np.eye(3), data.oMf[fid].translation)
        f = data.oMi[jid].actInv(lwa.act(pin.Force(lw[:3], lw[3:])))
        fext[jid] = fext[jid] + f
        parts.append((jid, model.frames[fid].placement.translation.copy(), f, fid, n))
    return fext, parts


def forces_record(model, data, q, v, a, tau, fext_joints, fext_in, contacts, lam):
    """rnea and aba under fext (local, as given) and contact forces (world-aligned), their
    derivatives: q and v with fext fixed in the joint frames and lambda fixed in world axes;
    and d/dfext = -J_local^T, d/dlambda = -J_LWA^T (the qdd ones through M^-1)."""
    nv = model.nv
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    pin.computeJointJacobians(model, data, q)
    cf, parts = contact_fext(model, data, contacts, lam)
    fext = pin.StdVec_Force()
    for f in cf:
        fext.append(f)
    for k, name in enumerate(fext_joints):
        jid = model.getJointId(name)
        fext[jid] = fext[jid] + pin.Force(fext_in[6 * k:6 * k + 3], fext_in[6 * k + 3:6 * k + 6])
    jloc = {jid: pin.getJointJacobian(model, data, jid, pin.LOCAL).copy() for jid in range(1, model.njoints)}

    def world_terms():
        # Holding lambda in world axes: moving joint u turns the body under the contact's
        # world-aligned frame, by w (u's axis in the body frame) about the contact point p:
        # m = Motion(p x w, w), the body-frame force changes by -m x* f, so dtau/dq_u
        # gains J^T (m x* f) (checked against central differences below).
        out = np.zeros((nv, nv))
        for jid, p, f, _, _ in parts:
            j = jloc[jid]
            for u in range(nv):
                w = j[3:, u]
                if not w.any():
                    continue
                out[:, u] += j.T @ pin.Motion(np.cross(p, w), w).cross(f).vector
        return out

    def rnea_dq(acc):
        dq, dv, _ = pin.computeRNEADerivatives(model, data, q, v, acc, fext)
        dq = dq.copy() + world_terms()
        return dq, dv.copy()

    rnea = pin.rnea(model, data, q, v, a, fext).copy()
    dq, dv = rnea_dq(a)
    fd = pin.aba(model, data, q, v, tau, fext).copy()
    pin.computeABADerivatives(model, data, q, v, tau, fext)
    abadq, abadv = data.ddq_dq.copy(), data.ddq_dv.copy()
    mi = pin.computeMinverse(model, data, q).copy()
    mi = np.triu(mi) + np.triu(mi, 1).T
    fdq, fdv = rnea_dq(fd)
    fdq, fdv = -mi @ fdq, -mi @ fdv
    if not contacts:
        assert np.allclose(fdq, abadq, rtol=1e-9, atol=1e-9) and np.allclose(fdv, abadv, rtol=1e-9, atol=1e-9)
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    pin.computeJointJacobians(model, data, q)
    dfext = np.hstack([-jloc[model.getJointId(n)].T for n in fext_joints]) if fext_joints else np.zeros((nv, 0))
    dlam = np.hstack([-pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:n].T for _, _, _, fid, n in parts]) if parts else np.zeros((nv, 0))
    return {"rnea": rnea, "drnea_dq": dq, "drnea_dqd": dv, "drnea_dfext": dfext, "drnea_dlambda": dlam,
            "fd": fd, "dfd_dq": fdq, "dfd_dqd": fdv, "dfd_dfext": mi @ -dfext, "dfd_dlambda": mi @ -dlam}


def forces_fixture(robot, floating, fext_joints, contacts, rng):
    """Random states (uniform base rotations), a still one and a fast one (30 rad/s), each
    with random fext on the listed joints' bodies (N(0, 10) N and N m) and contact forces
    (N(0, 50)); q in grid-gen's layout, every vector and matrix in listing order, the
    columns of the fext and lambda derivatives in the inputs' order."""
    model, names, perm, qidx = step_model(robot, floating)
    data = model.createData()
    nv = model.nv
    if fext_joints == "*":
        fext_joints = [model.names[j] for j in range(1, model.njoints)]
    nlam = sum(3 if k == "point" else 6 for _, k in contacts)
    records = []
    for kind, speed in [("random", 1.0)] * 6 + [("still", 0.0), ("fast", 30.0)]:
        q = random_q(model, floating, rng)
        lv, la, lt = (rng.normal(size=nv) * speed, rng.normal(size=nv) * max(speed, 1.0), rng.normal(size=nv) * 10)
        fin, lam = rng.normal(size=6 * len(fext_joints)) * 10, rng.normal(size=nlam) * 50
        v, a, t = np.zeros(nv), np.zeros(nv), np.zeros(nv)
        v[perm], a[perm], t[perm] = lv, la, lt
        out = forces_record(model, data, q, v, a, t, fext_joints, fin, contacts, lam)
        if kind == "random" and not records:
            check_world_terms(model, data, q, v, a, fext_joints, fin, contacts, lam, out["drnea_dq"])
        sel = lambda x: [float(y) for y in np.asarray(x)[perm]]
        selm = lambda m: mat(np.asarray(m)[np.ix_(perm, perm)])
        selr = lambda m: mat(np.asarray(m)[perm, :])
        record = {"kind": kind, "q": [float(q[i]) for i in qidx], "qd": [float(x) for x in lv], "qdd": [float(x) for x in la],
                  "tau": [float(x) for x in lt], "fext": [float(x) for x in fin], "lambda": [float(x) for x in lam]}
        for key in ("rnea", "fd"):
            record[key] = sel(out[key])
        for key in ("drnea_dq", "drnea_dqd", "dfd_dq", "dfd_dqd"):
            record[key] = selm(out[key])
        for key in ("drnea_dfext", "drnea_dlambda", "dfd_dfext", "dfd_dlambda"):
            record[key] = selr(out[key])
        records.append(record)
    return {"tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear], "joint_names": names,
            "fext": fext_joints, "contacts": [{"frame": f, "type": k} for f, k in contacts], "states": records}


def check_world_terms(model, data, q, v, a, fext_joints, fin, contacts, lam, dq):
    """The lambda-fixed-in-world dtau/dq against central differences on the manifold."""
    def tau_at(qq):
        pin.forwardKinematics(model, data, qq)
        pin.updateFramePlacements(model, data)
        cf, _ = contact_fext(model, data, contacts, lam)
        for k, name in enumerate(fext_joints):
            jid = model.getJointId(name)
            # fext stays fixed in the joint frame: it is given there.
            cf[jid] = cf[jid] + pin.Force(fin[6 * k:6 * k + 3], fin[6 * k + 3:6 * k + 6])
        return pin.rnea(model, data, qq, v, a, cf).copy()
    h = 1e-6
    num = np.zeros((model.nv, model.nv))
    for u in range(model.nv):
        e = np.zeros(model.nv)
        e[u] = h
        num[:, u] = (tau_at(pin.integrate(model, q, e)) - tau_at(pin.integrate(model, q, -e))) / (2 * h)
    err = np.abs(num - dq).max() / max(1.0, np.abs(dq).max())
    assert err < 1e-6, f"world-fixed contact derivative off by {err:g}"


def forces_fixtures(check):
    stale = False
    for robot, floating, fext_joints, contacts in FORCES:
        seed = sum(robot.encode()) + 53 + floating
        pin.seed(seed)
        data = forces_fixture(robot, floating, fext_joints, contacts, np.random.default_rng(seed))
        stale |= report(OUT / f"{robot}{'.floating' if floating else ''}.forces.pinocchio.json", data, check, 1e-10)
    return stale


# Rigid-contact forward dynamics (Pinocchio's constraintDynamics and
# computeConstraintDynamicsDerivatives, LOCAL_WORLD_ALIGNED, no Baumgarte correction):
# (robot, floating, contacts). A quadruped's four feet, a humanoid's two foot wrenches, an
# arm's tool.
CONTACTS = [
    ("grid_hyq", True, [(f"{leg}_lowerleg", "point") for leg in ("lf", "rf", "lh", "rh")]),
    ("go2", True, [(f"{leg}_foot", "point") for leg in ("FL", "FR", "RL", "RR")]),
    ("grid_atlas", True, [("l_foot", "wrench"), ("r_foot", "wrench")]),
    ("grid_iiwa", False, [("iiwa_link_7", "wrench")]),
]


def contact_record(model, data, q, v, tau, contacts):
    """(qdd, lambda and their derivatives) in Pinocchio's order, lambda stacked per contact
    as lambda_c."""
    cms, cds = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
    for name, kind in contacts:
        fid = model.getFrameId(name, pin.BODY)
        frame = model.frames[fid]
        ct = pin.ContactType.CONTACT_3D if kind == "point" else pin.ContactType.CONTACT_6D
        cm = pin.RigidConstraintModel(ct, model, frame.parentJoint, frame.placement, pin.LOCAL_WORLD_ALIGNED)
        cms.append(cm)
        cds.append(cm.createData())
    pin.initConstraintDynamics(model, data, cms, cds)
    qdd = pin.constraintDynamics(model, data, q, v, tau, cms, cds).copy()
    lam = data.lambda_c.copy()
    pin.computeConstraintDynamicsDerivatives(model, data, cms, cds)
    return {"qdd": qdd, "lambda": lam, "dqdd_dq": data.ddq_dq.copy(), "dqdd_dqd": data.ddq_dv.copy(),
            "dqdd_dtau": data.ddq_dtau.copy(), "dlambda_dq": data.dlambda_dq.copy(),
            "dlambda_dqd": data.dlambda_dv.copy(), "dlambda_dtau": data.dlambda_dtau.copy()}


def check_contact_derivatives(model, data, q, v, tau, contacts, out):
    """Every derivative against central differences on the manifold (Pinocchio's integrate)."""
    nv, h = model.nv, 1e-6
    for key, move in (("dq", lambda e: (pin.integrate(model, q, e), v, tau)), ("dqd", lambda e: (q, v + e, tau)),
                      ("dtau", lambda e: (q, v, tau + e))):
        num_a, num_l = np.zeros((nv, nv)), np.zeros((len(out["lambda"]), nv))
        for u in range(nv):
            e = np.zeros(nv)
            e[u] = h
            p, m = contact_record(model, data, *move(e), contacts), contact_record(model, data, *move(-e), contacts)
            num_a[:, u] = (p["qdd"] - m["qdd"]) / (2 * h)
            num_l[:, u] = (p["lambda"] - m["lambda"]) / (2 * h)
        for name, num in ((f"dqdd_{key}", num_a), (f"dlambda_{key}", num_l)):
            err = np.abs(num - out[name]).max() / max(1.0, np.abs(out[name]).max())
            assert err < 1e-6, f"{name} off central differences by {err:g}"


def contact_fixture(robot, floating, contacts, rng):
    """Random states (uniform base rotations), a still one and a fast one (30 rad/s); q in
    grid-gen's layout, vectors and matrices in listing order, lambda's rows in the
    contacts' order."""
    model, names, perm, qidx = step_model(robot, floating)
    data = model.createData()
    nv = model.nv
    records = []
    for kind, speed in [("random", 1.0)] * 6 + [("still", 0.0), ("fast", 30.0)]:
        q = random_q(model, floating, rng)
        lv, lt = rng.normal(size=nv) * speed, rng.normal(size=nv) * 10
        v, t = np.zeros(nv), np.zeros(nv)
        v[perm], t[perm] = lv, lt
        out = contact_record(model, data, q, v, t, contacts)
        if kind == "random" and not records:
            check_contact_derivatives(model, data, q, v, t, contacts, out)
        record = {"kind": kind, "q": [float(q[i]) for i in qidx], "qd": [float(x) for x in lv], "tau": [float(x) for x in lt],
                  "qdd": [float(x) for x in np.asarray(out["qdd"])[perm]], "lambda": [float(x) for x in out["lambda"]]}
        for key in ("dqdd_dq", "dqdd_dqd", "dqdd_dtau"):
            record[key] = mat(np.asarray(out[key])[np.ix_(perm, perm)])
        for key in ("dlambda_dq", "dlambda_dqd", "dlambda_dtau"):
            record[key] = mat(np.asarray(out[key])[:, perm])
        records.append(record)
    return {"tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear], "joint_names": names,
            "contacts": [{"frame": f, "type": k} for f, k in contacts], "states": records}


def mask_fixture(robot, floating, contacts, rng):
    """Every mode of `contacts` (2^n subsets, bit c for contact c), one random state each:
    Pinocchio holding just the active contacts (no contact at all: constraintDynamics with
    none, which is aba). lambda and its derivatives have a row per candidate contact's
    component, zero where the contact is inactive, as a masked kernel returns them."""
    model, names, perm, qidx = step_model(robot, floating)
    data = model.createData()
    nv = model.nv
    dims = [3 if k == "point" else 6 for _, k in contacts]
    starts = [sum(dims[:c]) for c in range(len(contacts))]
    records = []
    for bits in range(2 ** len(contacts)):
        active = [bits >> c & 1 for c in range(len(contacts))]
        held = [contacts[c] for c in range(len(contacts)) if active[c]]
        q = random_q(model, floating, rng)
        lv, lt = rng.normal(size=nv), rng.normal(size=nv) * 10
        v, t = np.zeros(nv), np.zeros(nv)
        v[perm], t[perm] = lv, lt
        out = contact_record(model, data, q, v, t, held)
        rows = [r for c in range(len(contacts)) if active[c] for r in range(starts[c], starts[c] + dims[c])]
        lam = np.zeros(sum(dims))
        lam[rows] = np.asarray(out["lambda"])
        record = {"kind": "random", "active": active, "q": [float(q[i]) for i in qidx], "qd": [float(x) for x in lv],
                  "tau": [float(x) for x in lt], "qdd": [float(x) for x in np.asarray(out["qdd"])[perm]],
                  "lambda": [float(x) for x in lam]}
        for key in ("dqdd_dq", "dqdd_dqd", "dqdd_dtau"):
            record[key] = mat(np.asarray(out[key])[np.ix_(perm, perm)])
        for key in ("dlambda_dq", "dlambda_dqd", "dlambda_dtau"):
            full = np.zeros((sum(dims), nv))
            if rows:
                full[rows, :] = np.asarray(out[key])[:, perm]
            record[key] = mat(full)
        records.append(record)
    return {"tool": f"pinocchio {pin.__version__}", "gravity": [float(x) for x in model.gravity.linear], "joint_names": names,
            "contacts": [{"frame": f, "type": k} for f, k in contacts], "states": records}


def contact_fixtures(check):
    stale = False
    for robot, floating, contacts in CONTACTS:
        seed = sum(robot.encode()) + 71 + floating
        pin.seed(seed)
        data = contact_fixture(robot, floating, contacts, np.random.default_rng(seed))
        stale |= report(OUT / f"{robot}{'.floating' if floating else ''}.contact.pinocchio.json", data, check, 1e-10)
    # Issue 56: every contact mode of a quadruped's four feet, for the masked kernels.
    robot, floating, contacts = CONTACTS[0]
    seed = sum(robot.encode()) + 73 + floating
    pin.seed(seed)
    data = mask_fixture(robot, floating, contacts, np.random.default_rng(seed))
    stale |= report(OUT / f"{robot}.floating.contact_masks.pinocchio.json", data, check, 1e-10)
    return stale


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    args = sys.argv[1:]
    check = "--check" in args
    only = set(a for a in args if a != "--check")
    failed = False
    for path in sorted(ROBOTS.glob("*.urdf")):
        if only and path.stem not in only:
            continue
        rng = np.random.default_rng(sum(path.stem.encode()))  # stable seed per robot
        for suffix, make in (("pinocchio", pinocchio_fixture), ("yourdfpy", yourdfpy_fixture)):
            data = make(path, rng)
            failed |= report(OUT / f"{path.stem}.{suffix}.json", data, check, 1e-12)
    if not only or "chain100" in only:
        failed |= chain_fixtures(check)
    if not only or "scenes" in only:
        failed |= scene_fixtures(check)
    if not only or "floating" in only:
        failed |= floating_fixtures(check)
    if not only or "mimic" in only:
        failed |= mimic_fixtures(check)
    if not only or "spherical" in only:
        failed |= ball_fixtures(check)
    if not only or "frames" in only:
        failed |= frames_fixtures(check)
    if not only or "step" in only:
        failed |= step_fixtures(check)
    if not only or "forces" in only:
        failed |= forces_fixtures(check)
    if not only or "contact" in only:
        failed |= contact_fixtures(check)
    if failed:
        sys.exit("fixtures differ from what Pinocchio/yourdfpy compute now: rerun scripts/make_fixtures.py and review")


if __name__ == "__main__":
    main()
