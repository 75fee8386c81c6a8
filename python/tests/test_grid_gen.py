"""grid_gen from Python against Pinocchio: bundled robots, a robot the project never saw,
batches and single states, f64 and f32, and every kind of bad argument.

Run by scripts/test.sh after `pip install ./python`; GRID_GEN_CACHE points the compiled
robots at target/grid-gen-cache there.
"""

from __future__ import annotations

import inspect
import math
import os
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import grid_gen

ROOT = Path(__file__).resolve().parents[2]
IIWA = ROOT / "robots" / "grid_iiwa.urdf"
GO2 = ROOT / "tests" / "fixtures" / "go2.urdf"
# What grid_gen.jax wraps, in the kernels' own order.
JAX_KERNELS = ["rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad"]


def rel(a, b) -> float:
    """max |a - b| / max |b|: the error measure of every grid-gen test."""
    scale = float(np.max(np.abs(b)))
    return float(np.max(np.abs(a - b))) / (scale if scale > 0 else 1.0)


class Pin:
    """Pinocchio's model of the same URDF, with grid-gen's coordinate order mapped onto it
    by joint name (both walk the tree depth-first, but nothing here assumes it)."""

    def __init__(self, urdf: Path, robot: grid_gen.Robot):
        if robot.floating_base:
            self.model = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
        else:
            self.model = pin.buildModelFromUrdf(str(urdf))
        self.data = self.model.createData()
        m = self.model
        base = 6 if robot.floating_base else 0
        self.v = list(range(base))
        self.q = list(range(7 if base else 0))
        for name in robot.joint_names[base:]:
            j = m.getJointId(name)
            assert j < m.njoints, f"Pinocchio has no joint {name}"
            assert m.joints[j].nv == 1, name
            self.v.append(m.joints[j].idx_v)
            self.q.append(m.joints[j].idx_q)
        assert sorted(self.v) == list(range(m.nv)) and sorted(self.q) == list(range(m.nq))

    def to_pin(self, q, v):
        qp, vp = np.empty(self.model.nq), np.empty(self.model.nv)
        qp[self.q] = q
        vp[self.v] = v
        return qp, vp

    def vec(self, x):
        """A Pinocchio vector in grid-gen's order."""
        return np.asarray(x)[self.v]

    def mat(self, x):
        return np.asarray(x)[np.ix_(self.v, self.v)]


def random_states(robot: grid_gen.Robot, n: int, seed: int):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.5, 1.5, (n, robot.nq))
    if robot.floating_base:
        quat = rng.normal(size=(n, 4))
        q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    qd = rng.uniform(-1.0, 1.0, (n, robot.nv))
    tau = rng.uniform(-10.0, 10.0, (n, robot.nv))
    return q, qd, tau


def check_against_pinocchio(urdf: Path, robot: grid_gen.Robot, n: int, tol: float) -> dict:
    """Every basic kernel on a batch of n states against Pinocchio; returns the worst errors."""
    p = Pin(urdf, robot)
    q, qd, tau = random_states(robot, n, seed=3)
    qdd, dq, dqd = robot.fd_grad(q, qd, tau)
    tau_back = robot.rnea(q, qd, qdd)
    drnea_dq, drnea_dqd = robot.rnea_grad(q, qd, qdd)
    mass = robot.mass_matrix(q)
    minv = robot.minv(q)
    fd = robot.fd(q, qd, tau)
    worst = dict.fromkeys(["fd_grad", "rnea_grad", "mass_matrix", "minv", "fd", "rnea"], 0.0)
    for i in range(n):
        qp, vp = p.to_pin(q[i], qd[i])
        _, taup = p.to_pin(q[i], tau[i])
        pin.computeABADerivatives(p.model, p.data, qp, vp, taup)
        ddq = p.data.ddq.copy()
        worst["fd_grad"] = max(worst["fd_grad"], rel(qdd[i], p.vec(ddq)), rel(dq[i], p.mat(p.data.ddq_dq)), rel(dqd[i], p.mat(p.data.ddq_dv)))
        worst["fd"] = max(worst["fd"], rel(fd[i], p.vec(ddq)))
        _, ap = p.to_pin(q[i], qdd[i])
        pin.computeRNEADerivatives(p.model, p.data, qp, vp, ap)
        worst["rnea_grad"] = max(worst["rnea_grad"], rel(drnea_dq[i], p.mat(p.data.dtau_dq)), rel(drnea_dqd[i], p.mat(p.data.dtau_dv)))
        worst["rnea"] = max(worst["rnea"], rel(tau_back[i], tau[i]))
        M = pin.crba(p.model, p.data, qp)
        M = np.triu(M) + np.triu(M, 1).T
        worst["mass_matrix"] = max(worst["mass_matrix"], rel(mass[i], p.mat(M)))
        Mi = pin.computeMinverse(p.model, p.data, qp)
        Mi = np.triu(Mi) + np.triu(Mi, 1).T
        worst["minv"] = max(worst["minv"], rel(minv[i], p.mat(Mi)))
    print(f"{robot.name}: worst relative error against Pinocchio over {n} states: " + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
    for k, v in worst.items():
        assert v < tol, f"{k}: {v:.2e} against Pinocchio (tolerance {tol:.0e})"
    return worst


@pytest.fixture(scope="module")
def iiwa():
    return grid_gen.load(IIWA)


def test_iiwa_batch_matches_pinocchio(iiwa):
    assert (iiwa.nq, iiwa.nv) == (7, 7)
    assert iiwa.joint_names == [f"iiwa_joint_{i}" for i in range(1, 8)]
    # f64 round-off through M^-1 at random states: measured 2e-13 (fd_grad), 6x below.
    check_against_pinocchio(IIWA, iiwa, 64, 1e-12)


# go2 on a floating base with a semi-implicit step: one library for the Pinocchio check of the
# basic kernels and the JAX test of the step (the cache's key is the scene's text), so that the
# test command compiles go2 once.
GO2_STEP_SCENE = 'floating_base = true\noutputs = ["rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad", "step", "step_grad"]\n\n[step]\nscheme = "semi_implicit_euler"\ndt = 0.01\n'


@pytest.fixture(scope="module")
def go2_stepping(tmp_path_factory):
    scene = tmp_path_factory.mktemp("go2") / "go2_step.toml"
    scene.write_text(GO2_STEP_SCENE)
    return grid_gen.load(GO2, scene=scene)


def test_go2_floating_batch_matches_pinocchio(go2_stepping):
    go2 = go2_stepping
    assert (go2.nq, go2.nv) == (19, 18) and go2.floating_base
    # Measured 4e-13: a floating base's M^-1 is worse conditioned than iiwa's (light feet
    # under a heavy trunk), so 1e-11.
    check_against_pinocchio(GO2, go2, 64, 1e-11)


def random_tree_urdf(seed: int) -> str:
    """A robot nobody bundled: a six-joint tree (revolute and prismatic, random axes,
    origins, masses and inertias that satisfy the triangle inequality)."""
    rng = np.random.default_rng(seed)
    parents = [None, 0, 1, 1, 3, 0]
    # The base has mass: a massless floating base on one revolute joint would leave its
    # rotation about that axis undetermined (M singular), here and in Pinocchio.
    links = ['<link name="base"><inertial><mass value="4"/><inertia ixx="0.05" ixy="0" ixz="0" iyy="0.06" iyz="0" izz="0.07"/></inertial></link>']
    joints = []
    for i, parent in enumerate(parents):
        m = rng.uniform(0.5, 3.0)
        d = rng.uniform(0.01, 0.1, 3)
        ixx, iyy, izz = d[1] + d[2], d[0] + d[2], d[0] + d[1]
        com = " ".join(f"{x:.6f}" for x in rng.uniform(-0.1, 0.1, 3))
        links.append(
            f'<link name="l{i}"><inertial><origin xyz="{com}" rpy="0 0 0"/><mass value="{m:.6f}"/>'
            f'<inertia ixx="{ixx:.6f}" ixy="0.001" ixz="0" iyy="{iyy:.6f}" iyz="0.002" izz="{izz:.6f}"/></inertial></link>'
        )
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        kind = "prismatic" if i == 4 else "revolute"
        xyz = " ".join(f"{x:.6f}" for x in rng.uniform(-0.3, 0.3, 3))
        rpy = " ".join(f"{x:.6f}" for x in rng.uniform(-math.pi, math.pi, 3))
        joints.append(
            f'<joint name="j{i}" type="{kind}"><parent link="{"base" if parent is None else f"l{parent}"}"/><child link="l{i}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis[0]:.6f} {axis[1]:.6f} {axis[2]:.6f}"/>'
            f'<limit lower="-3" upper="3" effort="100" velocity="10"/></joint>'
        )
    return '<robot name="unseen_tree">\n' + "\n".join(links + joints) + "\n</robot>\n"


def test_a_robot_nobody_bundled_loads_and_matches_pinocchio(tmp_path):
    urdf = tmp_path / "unseen_tree.urdf"
    urdf.write_text(random_tree_urdf(seed=2026))
    robot = grid_gen.load(urdf, floating_base=True)
    assert robot.name == "unseen_tree" and robot.nv == 12
    # Measured 9e-14 (seeded, so the same robot every run); as go2's.
    check_against_pinocchio(urdf, robot, 64, 1e-11)


def test_f32_kernels_follow_f64_within_single_precision(tmp_path, iiwa):
    # The kernels grid_gen.jax needs, so that its f32 check loads this same library.
    f32 = grid_gen.load(IIWA, precision="f32", kernels=JAX_KERNELS)
    assert f32.dtype == np.float32 and f32.kernels == tuple(JAX_KERNELS)
    q, qd, tau = random_states(iiwa, 64, seed=5)
    got = f32.fd_grad(q, qd, tau)
    want = iiwa.fd_grad(q, qd, tau)
    assert all(g.dtype == np.float32 for g in got)
    err = max(rel(g.astype(np.float64), w) for g, w in zip(got, want))
    print(f"iiwa f32 fd_grad against f64: {err:.1e}")
    # f32 rounding (6e-8) amplified by iiwa's M^-1 (condition number in the hundreds); the
    # Rust C ABI test measures ~2e-6.
    assert err < 1e-4


def test_one_state_batches_out_and_threads(iiwa):
    q, qd, tau = random_states(iiwa, 9, seed=8)
    qdd, dq, dqd = iiwa.fd_grad(q, qd, tau)
    one = iiwa.fd_grad(q[4], qd[4], tau[4])
    assert one[0].shape == (7,) and one[1].shape == (7, 7)
    assert np.array_equal(one[0], qdd[4]) and np.array_equal(one[1], dq[4]) and np.array_equal(one[2], dqd[4])
    # Any layout and any real dtype is accepted (copied to contiguous f64).
    assert np.array_equal(iiwa.fd_grad(np.asfortranarray(q), qd.astype(np.float64), tau)[0], qdd)
    assert np.array_equal(iiwa.fd(q=q, qd=qd, tau=tau), iiwa.fd(q, qd, tau))
    # out= writes in place and returns the same arrays.
    outs = (np.empty((9, 7)), np.empty((9, 7, 7)), np.empty((9, 7, 7)))
    res = iiwa.fd_grad(q, qd, tau, out=outs)
    assert all(r is o for r, o in zip(res, outs)) and np.array_equal(outs[1], dq)
    # One thread and every core give the same bits.
    iiwa.threads = 1
    assert iiwa.threads == 1
    single = iiwa.fd_grad(q, qd, tau)
    iiwa.threads = 0
    assert all(np.array_equal(a, b) for a, b in zip(single, (qdd, dq, dqd)))
    # An empty batch is fine.
    assert iiwa.fd(np.empty((0, 7)), np.empty((0, 7)), np.empty((0, 7))).shape == (0, 7)
    # The native fast path takes contiguous f64 arrays of the right shapes and gives the
    # Python path's bits; it declines (None) what the Python path must convert or report.
    fast = iiwa.fd_grad._fast
    got = fast(q, qd, tau)
    assert got is not None and all(np.array_equal(a, b) for a, b in zip(got, (qdd, dq, dqd)))
    assert fast(q[4], qd[4], tau[4]) is not None and np.array_equal(fast(q[4], qd[4], tau[4])[1], dq[4])
    for declined in (
        (np.asfortranarray(q), qd, tau),  # not C-contiguous
        (q.astype(np.float32), qd, tau),  # another dtype
        (q, qd[:3], tau),  # batches differ
        (q, qd[0], tau),  # one state against a batch
        (q[:, :6], qd, tau),  # wrong length
        (q, np.where(np.eye(9, 7) > 0, np.nan, qd), tau),  # non-finite
        (q, qd),  # too few
        (q.tolist(), qd, tau),  # not an array
    ):
        assert fast(*declined) is None


def test_bad_arguments_raise_value_errors_that_name_them(iiwa):
    q, qd, tau = random_states(iiwa, 4, seed=1)
    cases = [
        (lambda: iiwa.fd_grad(q[:, :6], qd, tau), "`q` has shape (4, 6); expected (7,) for one state or (B, 7)"),
        (lambda: iiwa.fd_grad(q, qd[:3], tau), "`qd` has shape (3, 7); expected (B, 7) with B = 4 as `q`"),
        (lambda: iiwa.fd_grad(q, qd[0], tau), "`qd` has shape (7,); expected (B, 7) with B = 4 as `q`"),
        (lambda: iiwa.fd_grad(q.astype(complex), qd, tau), "`q` has dtype complex128"),
        (lambda: iiwa.fd_grad(q, qd, np.full((4, 7), "x")), "`tau` has dtype <U1"),
        (lambda: iiwa.fd_grad(q, np.where(np.eye(4, 7) > 0, np.nan, qd), tau), "`qd` holds a non-finite value at index (0, 0)"),
        (lambda: iiwa.rnea(q, qd, np.full((4, 7), np.inf)), "`qdd` holds a non-finite value"),
        (lambda: iiwa.mass_matrix(q, out=np.empty((4, 7, 6))), "out `m` is float64 (4, 7, 6); expected a float64 array of shape (4, 7, 7)"),
        (lambda: iiwa.mass_matrix(q, out=np.empty((4, 7, 7), dtype=np.float32)), "expected a float64 array"),
        (lambda: iiwa.fd(q, qd, tau, out=q), "shares memory"),
        (lambda: iiwa.fd_grad(q, qd, tau, out=(np.empty((4, 7)),)), "out= needs 3 arrays"),
        (lambda: iiwa.minv(np.zeros((2, 3, 7))), "expected (7,) for one state or (B, 7)"),
    ]
    for call, message in cases:
        with pytest.raises(ValueError) as e:
            call()
        assert message in str(e.value), str(e.value)
    with pytest.raises(TypeError, match="missing its argument 'tau'"):
        iiwa.fd(q, qd)
    with pytest.raises(TypeError, match="no argument 'qdd'"):
        iiwa.fd(q, qd, qdd=tau)


def test_batches_without_lanes_give_the_same_bits(iiwa):
    # A lane runs a one-state call's operations, so a library without lanes (one state per
    # kernel call) returns the same bits as the default one, which runs iiwa's dynamics
    # kernels four states per call. 67 states: whole groups of four and a remainder.
    plain = grid_gen.load(IIWA, kernels=["fd", "fd_grad"], batch_lanes="none")
    q, qd, tau = random_states(iiwa, 67, seed=11)
    for name in ("fd", "fd_grad"):
        got, want = getattr(plain, name)(q, qd, tau), getattr(iiwa, name)(q, qd, tau)
        for g, w in zip(got if isinstance(got, tuple) else (got,), want if isinstance(want, tuple) else (want,)):
            assert np.array_equal(g, w), name


def y_tree_urdf() -> str:
    """Two arms of seven links on a base with mass: on a floating base, 8 joints deep (the
    free-flyer counting as one), so fd_grad takes q̈ from M's factorisation (the crba
    solve), where calls="all" and "rnea_grad" apply (since 2026-12-01; before, they
    counted the free-flyer's six coordinates, 13 deep, and took q̈ by ABA)."""
    links = ['<link name="base"><inertial><mass value="4"/><inertia ixx="0.05" ixy="0" ixz="0" iyy="0.06" iyz="0" izz="0.07"/></inertial></link>']
    joints = []
    for arm, side in (("a", "0.2"), ("b", "-0.2")):
        parent = "base"
        for i in range(7):
            axis = ("1 0 0", "0 1 0", "0 0 1")[i % 3]
            links.append(
                f'<link name="{arm}{i}"><inertial><origin xyz="0 0 0.05"/><mass value="1"/>'
                '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.012" iyz="0" izz="0.014"/></inertial></link>'
            )
            joints.append(
                f'<joint name="{arm}j{i}" type="revolute"><parent link="{parent}"/><child link="{arm}{i}"/>'
                f'<origin xyz="{side if i == 0 else 0} 0 0.1"/><axis xyz="{axis}"/>'
                '<limit lower="-3" upper="3" effort="100" velocity="10"/></joint>'
            )
            parent = f"{arm}{i}"
    return '<robot name="y_tree">\n' + "\n".join(links + joints) + "\n</robot>\n"


def test_calls_all_runs_fd_grad_through_its_callees(tmp_path):
    # calls="all" makes fd_grad call fd and rnea_grad, calls="rnea_grad" compute q̈ and
    # call rnea_grad there (less to compile, a little slower; the book, Compile time):
    # the module holds fd_grad's rest, or fd_grad calls rnea_grad between its parts, and
    # the values are the whole kernel's to round-off (calls="all" takes q̈ from `fd`, by
    # ABA, the others from M's factorisation: two accurate routes; the Rust tests measure
    # 5e-14 against the reference).
    urdf = tmp_path / "y_tree.urdf"
    urdf.write_text(y_tree_urdf())
    kernels = ["rnea_grad", "fd", "fd_grad"]
    for calls, rest in (("auto", False), ("all", True), ("rnea_grad", False)):
        out = tmp_path / calls
        files = grid_gen._native.generate(str(urdf), str(out), floating_base=True, kernels=kernels, calls=calls)
        module = next(f for f in files if f.endswith(".rs") and not f.endswith("_c.rs"))
        text = (out / module).read_text()
        assert ("fn fd_grad_rest<" in text) == rest, calls
        # rnea_grad's outputs bound in fd_grad (`rnea_grad_into` in the copy Python builds).
        assert ("rnea_grad_dc_dq" in text) == (calls != "auto"), calls
    whole = grid_gen.load(urdf, floating_base=True, kernels=kernels)
    q, qd, tau = random_states(whole, 33, seed=13)
    for calls in ("all", "rnea_grad"):
        called = grid_gen.load(urdf, floating_base=True, kernels=kernels, calls=calls)
        err = max(rel(g, w) for g, w in zip(called.fd_grad(q, qd, tau), whole.fd_grad(q, qd, tau)))
        print(f"y_tree fd_grad with calls={calls}: {err:.1e} from the whole kernel")
        assert err < 1e-12, calls


def test_a_large_robots_kernels_compile_as_crates_at_once(tmp_path, monkeypatch):
    """Above `SPLIT_MIN_WEIGHT` (here forced, on three cores) load compiles the
    kernels as one crate per core, each kernel with the kernels it calls, and links them
    into one library: every kernel gives the single crate's bits, and the C ABI's shared
    state (the bad quaternion's state) is one for every crate."""
    from grid_gen import _loader

    urdf = tmp_path / "unseen_tree.urdf"
    urdf.write_text(random_tree_urdf(seed=2029))
    kernels = ["rnea", "fd", "fd_grad", "contact_fd", "contact_fd_grad", "step", "step_grad", "integrate"]
    keywords = dict(floating_base=True, contacts={"l2": "point", "l4": "point"}, contact_mask=True, step="semi_implicit_euler")
    # The single crate's library (another key: the kernels listed in another order).
    monkeypatch.setattr(_loader, "SPLIT_MIN_WEIGHT", 10**12)
    whole = grid_gen.load(urdf, kernels=kernels[::-1], **keywords)
    assert not (_loader.cache_dir() / "build" / Path(whole.library).parent.name / "k0").exists()
    monkeypatch.setattr(_loader, "SPLIT_MIN_WEIGHT", 0)
    monkeypatch.setattr(_loader, "_cores", lambda: 3)
    split = grid_gen.load(urdf, kernels=kernels, **keywords)
    build = _loader.cache_dir() / "build" / Path(split.library).parent.name
    members = sorted(p.name for p in build.glob("k*") if (p / "Cargo.toml").exists())
    assert members == ["k0", "k1", "k2"], members
    # A kernel and its callee share a crate; only the first crate has the shared entry points.
    defaults = {m: (build / m / "Cargo.toml").read_text().split("default = ")[1].split("\n")[0] for m in members}
    assert sum('"common"' in d for d in defaults.values()) == 1 and '"common"' in defaults["k0"]
    for caller, callee in (("step", "contact_fd"), ("step_grad", "contact_fd_grad")):
        assert [m for m, d in defaults.items() if f'"{caller}"' in d] == [m for m, d in defaults.items() if f'"{callee}"' in d]
    q, qd, tau = random_states(split, 9, seed=15)
    u = tau[:, split.nv - split.nu :]
    mode = np.array([[True, False]] * 9)
    lam = np.random.default_rng(16).normal(size=(9, split.nlambda))
    for name, args in (
        ("rnea", (q, qd, tau, lam)),
        ("fd", (q, qd, tau, lam)),
        ("fd_grad", (q, qd, tau, lam)),
        ("contact_fd", (q, qd, tau)),
        ("contact_fd_grad", (q, qd, tau)),
        ("step", (q, qd, u, 0.01)),
        ("step_grad", (q, qd, u, 0.01)),
        ("integrate", (q, qd)),
    ):
        extra = {"active": mode} if name.startswith(("contact", "step")) else {}
        got, want = getattr(split, name)(*args, **extra), getattr(whole, name)(*args, **extra)
        for g, w in zip(got if isinstance(got, tuple) else (got,), want if isinstance(want, tuple) else (want,)):
            assert np.array_equal(g, w), name
    # A bad quaternion at state 2, passed straight to each crate's entry points: every
    # crate records it where the first crate's `bad_state` reads it.
    bad = q.copy()
    bad[2, 3:7] = 0.0
    for name in kernels:
        k = getattr(split, name)
        ins = {"q": bad, "qd": qd, "tau": u if name.startswith("step") else tau, "qdd": tau, "v": qd, "lambda": np.zeros((9, split.nlambda)), "active": mode.astype(np.float64), "dt": np.full(9, 0.01)}
        arrays = [np.ascontiguousarray(ins[n], dtype=np.float64) for n, _ in k.inputs]
        outs = [np.zeros((9,) + dims) for _, dims in k.outputs]
        status = k._fn(9, *[a.ctypes.data for a in arrays], *[o.ctypes.data for o in outs])
        assert status == 3 and split._bad_state() == 2, (name, status, split._bad_state())


def test_bad_robots_and_options_raise_before_compiling(tmp_path):
    with pytest.raises(FileNotFoundError):
        grid_gen.load(tmp_path / "missing.urdf")
    with pytest.raises(ValueError, match="closest"):
        grid_gen.load(IIWA, frames=["iiwa_link_77"])
    with pytest.raises(ValueError, match="unknown kernel"):
        grid_gen.load(IIWA, kernels=["fd_grad", "teleport"])
    with pytest.raises(ValueError, match="precision"):
        grid_gen.load(IIWA, precision="f16")
    with pytest.raises(ValueError, match="batch_lanes"):
        grid_gen.load(IIWA, batch_lanes="some")
    with pytest.raises(ValueError, match="calls"):
        grid_gen.load(IIWA, calls="some")
    broken = tmp_path / "broken.urdf"
    broken.write_text('<robot name="r">\n  <link name="a"/>\n  <joint name="j" type="revolute"><parent link="a"/><child link="nowhere"/></joint>\n</robot>\n')
    with pytest.raises(ValueError) as e:
        grid_gen.load(broken)
    assert "broken.urdf:3" in str(e.value) and "nowhere" in str(e.value), str(e.value)


def test_frames_are_methods_and_names(tmp_path):
    robot = grid_gen.load(IIWA, frames=["iiwa_link_7"], kernels=["frame_placement", "frame_jacobian"])
    assert robot.frames == ["iiwa_link_7"] and set(robot.kernels) == {"frame_placement", "frame_jacobian"}
    p = Pin(IIWA, robot)
    q, _, _ = random_states(robot, 8, seed=4)
    jac = robot.frame_jacobian(q)
    assert jac.shape == (8, 1, 6, 7)
    fid = p.model.getFrameId("iiwa_link_7")
    worst = 0.0
    for i in range(8):
        qp, _ = p.to_pin(q[i], np.zeros(7))
        J = pin.computeFrameJacobian(p.model, p.data, qp, fid, pin.LOCAL_WORLD_ALIGNED)
        worst = max(worst, rel(jac[i, 0], J[:, p.v]))
    print(f"iiwa frame_jacobian against Pinocchio: {worst:.1e}")
    assert worst < 1e-12


def test_without_cargo_load_says_what_to_install(tmp_path, monkeypatch):
    # A cache with nothing in it, and no cargo anywhere: PATH empty, $CARGO unset, a home
    # without ~/.cargo.
    monkeypatch.setenv("GRID_GEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("CARGO", raising=False)
    with pytest.raises(RuntimeError, match=r"Install Rust .*rustup"):
        grid_gen.load(IIWA)


SCENE = """
[frames]
names = ["iiwa_link_7"]

[external_forces]
joints = ["iiwa_joint_7"]

[[contact]]
frame = "iiwa_link_7"
type = "wrench"

[step]
scheme = "semi_implicit_euler"
dt = 0.01
"""


def test_every_kind_of_kernel_through_a_scene(tmp_path, iiwa):
    """A scene with frames, an external force, a contact wrench and the step: every kernel
    is a method whose outputs have the manifest's shapes; fd under fext matches Pinocchio's
    aba, contact_fd its constraintDynamics, and step the semi-implicit Euler step of contact_fd."""
    scene = tmp_path / "iiwa_everything.toml"
    scene.write_text(SCENE)
    robot = grid_gen.load(IIWA, scene=scene)
    assert robot.nlambda == 6 and robot.contacts == [("iiwa_link_7", "wrench")] and robot.frames == ["iiwa_link_7"]
    for name in ("rnea", "rnea_grad", "fd", "fd_grad", "frame_jacobian", "contact_fd", "contact_fd_grad", "step", "step_grad"):
        assert name in robot.kernels, robot.kernels
    rng = np.random.default_rng(9)
    n = 6
    sizes = {"q": 7, "qd": 7, "qdd": 7, "tau": 7, "fext": 6, "lambda": 6, "v": 7, "q1": 7}
    for name in robot.kernels:
        kernel = getattr(robot, name)
        args = [rng.uniform(-1, 1, (n, length)) for _, length in kernel.inputs]
        assert all(sizes[arg] == length or (arg == "tau" and length == robot.nu) for arg, length in kernel.inputs), kernel.inputs
        outs = kernel(*args)
        outs = outs if isinstance(outs, tuple) else (outs,)
        assert [o.shape for o in outs] == [(n,) + dims for _, dims in kernel.outputs], name
        assert all(np.isfinite(o).all() for o in outs), name

    p = Pin(IIWA, robot)
    q, qd, tau = random_states(robot, n, seed=10)
    fext = rng.uniform(-5, 5, (n, 6))
    qdd = robot.fd(q, qd, tau, fext, np.zeros((n, 6)))
    qdd_c, lam = robot.contact_fd(q, qd, tau, np.zeros((n, 6)))
    joint7 = p.model.getJointId("iiwa_joint_7")
    fid = p.model.getFrameId("iiwa_link_7", pin.BODY)
    frame = p.model.frames[fid]
    worst_fd = worst_c = 0.0
    for i in range(n):
        forces = pin.StdVec_Force()
        for j in range(p.model.njoints):
            forces.append(pin.Force(fext[i]) if j == joint7 else pin.Force.Zero())
        worst_fd = max(worst_fd, rel(qdd[i], pin.aba(p.model, p.data, q[i], qd[i], tau[i], forces)))
        cm = pin.RigidConstraintModel(pin.ContactType.CONTACT_6D, p.model, frame.parentJoint, frame.placement, pin.LOCAL_WORLD_ALIGNED)
        cms, cds = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
        cms.append(cm)
        cds.append(cm.createData())
        pin.initConstraintDynamics(p.model, p.data, cms, cds)
        want = pin.constraintDynamics(p.model, p.data, q[i], qd[i], tau[i], cms, cds)
        worst_c = max(worst_c, rel(qdd_c[i], want), rel(lam[i], p.data.lambda_c))
    print(f"iiwa scene: fd under fext {worst_fd:.1e}, contact_fd {worst_c:.1e} against Pinocchio")
    # f64 round-off; a 6-D contact on a 7-joint arm leaves K = J M^-1 J^T well conditioned
    # at these states (measured ~1e-13).
    assert worst_fd < 1e-11 and worst_c < 1e-10
    # The step: semi-implicit Euler on contact_fd (the wrench contact held rigid, fext held
    # over the step), q+ = q + dt qd+ on a fixed base; it takes fext and no lambda.
    assert [name for name, _ in robot.step.inputs] == ["q", "qd", "tau", "fext"]
    q_next, qd_next, lam_step = robot.step(q, qd, tau[:, : robot.nu], fext)
    a, lam_c = robot.contact_fd(q, qd, tau, fext)
    assert rel(qd_next, qd + 0.01 * a) < 1e-12 and rel(q_next, q + 0.01 * (qd + 0.01 * a)) < 1e-12
    # The step's λ is contact_fd's at the state (the same graph; f64 round-off).
    assert rel(lam_step, lam_c) < 1e-12
    r = robot.step_grad(q, qd, tau[:, : robot.nu], fext)
    assert r._fields == ("q_next", "qd_next", "A", "B", "lam", "dlam_dx", "dlam_du")
    assert r.dlam_dx.shape == (n, 6, 14) and r.dlam_du.shape == (n, 6, 7) and rel(r.lam, lam_c) < 1e-12
    assert robot.contact_fd_grad._result._fields == ("qdd", "lam", "dqdd_dq", "dqdd_dqd", "dqdd_dtau", "dlam_dq", "dlam_dqd", "dlam_dtau")


def test_a_step_without_dt_takes_it_per_state(tmp_path):
    """A scene's [step] without dt: step and step_grad take `dt` last, a scalar for every
    state or one per state, and give the semi-implicit Euler step of fd (and of fd_grad for
    A) at each state's dt; a bad dt is a ValueError that names it."""
    scene = tmp_path / "iiwa_runtime_dt.toml"
    scene.write_text('outputs = ["fd", "fd_grad", "step", "step_grad"]\n\n[step]\nscheme = "semi_implicit_euler"\n')
    robot = grid_gen.load(IIWA, scene=scene)
    assert [name for name, _ in robot.step.inputs] == ["q", "qd", "tau", "dt"]
    n, nv = 5, robot.nv
    q, qd, tau = random_states(robot, n, seed=12)
    dt = np.array([1e-3, 2e-3, 5e-3, 1e-2, 3e-2])
    a, da_dq, da_dqd = robot.fd_grad(q, qd, tau)
    for given in (dt, 0.01, dt[:, None]):
        h = np.broadcast_to(np.asarray(given).reshape(-1, 1), (n, 1))
        q_next, qd_next = robot.step(q, qd, tau, dt=given)
        # f64 round-off of a multiply and an add on each entry.
        assert rel(qd_next, qd + h * a) < 1e-13 and rel(q_next, q + h * (qd + h * a)) < 1e-13
        g_q, g_v, big_a, big_b = robot.step_grad(q, qd, tau, given)
        # step_grad's q̈ may come by another solve than step's (its doc says which).
        assert rel(g_q, q_next) < 1e-13 and rel(g_v, qd_next) < 1e-13
        # A's lower right block: d qd+ / d qd = I + dt d qdd / d qd.
        want = np.eye(nv) + h[:, :, None] * da_dqd
        assert rel(big_a[:, nv:, nv:], want) < 1e-13
    one = robot.step(q[0], qd[0], tau[0], 0.02)
    assert rel(one[1], qd[0] + 0.02 * a[0]) < 1e-13
    for bad, says in ((-0.01, "finite, positive"), (dt[:3], r"one per state"), (np.array([0.01, np.nan, 0.01, 0.01, 0.01]), "at state 1")):
        with pytest.raises(ValueError, match=f"`dt`.*{says}"):
            robot.step(q, qd, tau, bad)


def test_one_library_for_every_contact_mode(tmp_path):
    """A scene with contact_mask: contact_fd takes `active` (default every contact), and each
    of the four modes of two point contacts on the iiwa gives Pinocchio's constraintDynamics
    holding just the active contacts (none active: aba), with 0 for an inactive contact's
    lambda; one mask per state in a batch; a mask that is not 0 or 1 is a ValueError."""
    scene = tmp_path / "iiwa_two_points.toml"
    scene.write_text('outputs = ["contact_fd", "contact_fd_grad"]\ncontact_mask = true\n\n[[contact]]\nframe = "iiwa_link_7"\ntype = "point"\n\n[[contact]]\nframe = "iiwa_link_5"\ntype = "point"\n')
    robot = grid_gen.load(IIWA, scene=scene)
    assert [name for name, _ in robot.contact_fd.inputs] == ["q", "qd", "tau", "active"]
    p = Pin(IIWA, robot)
    n = 4
    q, qd, tau = random_states(robot, n, seed=14)
    modes = np.array([[False, False], [True, False], [False, True], [True, True]])
    qdd, lam = robot.contact_fd(q, qd, tau, active=modes)
    every, _ = robot.contact_fd(q, qd, tau)
    assert rel(every[3], qdd[3]) == 0.0, "no mask is every contact active"
    worst = 0.0
    for i, mode in enumerate(modes):
        cms, cds = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
        for c, frame_name in enumerate(("iiwa_link_7", "iiwa_link_5")):
            if mode[c]:
                frame = p.model.frames[p.model.getFrameId(frame_name, pin.BODY)]
                cm = pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, p.model, frame.parentJoint, frame.placement, pin.LOCAL_WORLD_ALIGNED)
                cms.append(cm)
                cds.append(cm.createData())
        if len(cms):
            pin.initConstraintDynamics(p.model, p.data, cms, cds)
            want = pin.constraintDynamics(p.model, p.data, q[i], qd[i], tau[i], cms, cds, pin.ProximalSettings(1e-14, 0.0, 1))
            want_lam = np.zeros(6)
            want_lam[np.repeat(mode, 3)] = p.data.lambda_c
        else:
            want, want_lam = pin.aba(p.model, p.data, q[i], qd[i], tau[i]), np.zeros(6)
        worst = max(worst, rel(qdd[i], want), rel(lam[i], want_lam) if mode.any() else 0.0)
        assert (lam[i][np.repeat(~mode, 3)] == 0.0).all(), f"mode {mode}: an inactive contact's lambda is 0"
    print(f"iiwa, four contact modes of one library: {worst:.1e} from Pinocchio")
    # f64 round-off through K, well conditioned for two points on the arm (measured 9.5e-15).
    assert worst < 1e-12
    one_qdd, _ = robot.contact_fd(q[1], qd[1], tau[1], active=[True, False])
    assert rel(one_qdd, qdd[1]) == 0.0
    for bad, says in (([0.5, 1.0], "holds 0.5"), ([True, True, False], r"shape \(3,\)")):
        with pytest.raises(ValueError, match=f"`active`.*{says}"):
            robot.contact_fd(q, qd, tau, active=bad)


def _jax():
    jax = pytest.importorskip("jax") if not os.environ.get("CI") else __import__("jax")
    jax.config.update("jax_enable_x64", True)
    return jax


def test_jax_functions_differentiate_with_the_generated_gradients(iiwa):
    jax = _jax()
    import jax.numpy as jnp

    import grid_gen.jax as gj

    dyn = gj.wrap(iiwa)
    assert dyn.via == "ffi"
    q, qd, tau = random_states(iiwa, 5, seed=12)
    # Values: jit and vmap give the batch kernel's numbers, bit for bit (the same entry point
    # on the same arrays), through the FFI call and through the callback alike.
    assert np.array_equal(jax.jit(dyn.fd)(q, qd, tau), iiwa.fd(q, qd, tau))
    assert np.array_equal(jax.vmap(dyn.rnea)(q, qd, iiwa.fd(q, qd, tau)), iiwa.rnea(q, qd, iiwa.fd(q, qd, tau)))
    slow = gj.wrap(iiwa, via="callback")
    assert np.array_equal(jax.jit(slow.fd)(q, qd, tau), iiwa.fd(q, qd, tau))
    # Leading axes of any rank broadcast: (2, 5, 7) against a single (7,) state.
    qdd2 = jax.jit(dyn.fd)(np.stack([q, q]), qd[0], tau[0])
    assert qdd2.shape == (2, 5, 7) and np.array_equal(qdd2[1, 3], iiwa.fd(q[3], qd[0], tau[0]))
    # A robot loaded in f32 computes in f32 (arrays cast to it), as its kernels do.
    iiwa32 = grid_gen.load(IIWA, precision="f32", kernels=JAX_KERNELS)
    q32, qd32, tau32 = (a.astype(np.float32) for a in (q, qd, tau))
    got = gj.wrap(iiwa32).fd(q, qd, tau)
    assert got.dtype == np.float32 and np.array_equal(got, iiwa32.fd(q32, qd32, tau32))
    with pytest.raises(ValueError, match=r"`qd` has shape \(6,\); expected \(\.\.\., 7\)"):
        dyn.fd(q[0], qd[0, :6], tau[0])
    # Gradients of a scalar cost against central differences of the kernels themselves.
    w = np.random.default_rng(1).normal(size=7)

    def cost_fd(q, qd, tau):
        return jnp.dot(dyn.fd(q, qd, tau), w)

    def cost_rnea(q, qd, qdd):
        return jnp.dot(dyn.rnea(q, qd, qdd), w)

    h = 1e-6
    worst = 0.0
    for cost, plain, args in ((cost_fd, iiwa.fd, (q[0], qd[0], tau[0])), (cost_rnea, iiwa.rnea, (q[1], qd[1], tau[1] / 10))):
        grads = jax.jit(jax.grad(cost, argnums=(0, 1, 2)))(*args)
        for k in range(3):
            num = np.zeros(7)
            for j in range(7):
                plus = [np.array(a, dtype=float) for a in args]
                minus = [np.array(a, dtype=float) for a in args]
                plus[k][j] += h
                minus[k][j] -= h
                num[j] = (plain(*plus) @ w - plain(*minus) @ w) / (2 * h)
            worst = max(worst, rel(np.asarray(grads[k]), num))
    print(f"grid_gen.jax: grad against central differences {worst:.1e}")
    # Central differences with h = 1e-6 carry O(h^2) truncation and O(eps/h) rounding: ~1e-9
    # relative for these magnitudes; an error in a rule would be O(1).
    assert worst < 1e-6
    # A batch under vmap of grad.
    batch = jax.vmap(jax.grad(cost_fd))(q, qd, tau)
    assert batch.shape == (5, 7) and np.allclose(batch[0], jax.grad(cost_fd)(q[0], qd[0], tau[0]), rtol=1e-14, atol=0)
    assert dyn.step is None


def test_jax_floating_base_and_step_on_the_manifold(go2_stepping):
    """go2 on a floating base with a semi-implicit step: jax.grad with respect to q's
    coordinates, checked along tangent directions (q moved by Pinocchio's integrate), for fd,
    rnea and the step's both outputs."""
    jax = _jax()
    import jax.numpy as jnp

    import grid_gen.jax as gj

    go2 = go2_stepping
    assert go2.floating_base and (go2.nq, go2.nv, go2.nu) == (19, 18, 12)
    dyn = gj.wrap(go2)
    p = Pin(GO2, go2)
    q, qd, tau = random_states(go2, 3, seed=21)
    u = tau[:, 6:]
    rng = np.random.default_rng(5)
    wq, wv = rng.normal(size=go2.nq), rng.normal(size=go2.nv)

    def cost_fd(q, qd, tau):
        return jnp.dot(dyn.fd(q, qd, tau), wv)

    def cost_rnea(q, qd, qdd):
        return jnp.dot(dyn.rnea(q, qd, qdd), wv)

    def cost_step(q, qd, u):
        q_next, qd_next = dyn.step(q, qd, u)
        return jnp.dot(q_next, wq) + jnp.dot(qd_next, wv)

    def plain_step(q, qd, u):
        q_next, qd_next = go2.step(q, qd, u)
        return q_next @ wq + qd_next @ wv

    def integrate(qi, dv):
        """grid-gen's q moved along dv by Pinocchio's integrate."""
        qp, vp = p.to_pin(qi, dv)
        return np.asarray(pin.integrate(p.model, qp, vp))[p.q]

    h = 1e-5
    worst = 0.0
    for cost, plain, args in ((cost_fd, go2.fd, (q[0], qd[0], tau[0])), (cost_rnea, go2.rnea, (q[1], qd[1], tau[1] / 10)), (cost_step, plain_step, (q[2], qd[2], u[2]))):
        g_q, g_qd, g_u = (np.asarray(g) for g in jax.jit(jax.grad(cost, argnums=(0, 1, 2)))(*args))
        value = (lambda *a: float(np.dot(plain(*a), wv))) if plain is not plain_step else plain_step
        # Along a tangent direction d: q(t) = integrate(q, t d), so d cost/dt = g_q . dq/dt.
        for _ in range(4):
            d = rng.normal(size=go2.nv)
            dq_dt = (integrate(args[0], h * d) - integrate(args[0], -h * d)) / (2 * h)
            num = (value(integrate(args[0], h * d), *args[1:]) - value(integrate(args[0], -h * d), *args[1:])) / (2 * h)
            worst = max(worst, abs(g_q @ dq_dt - num) / max(abs(num), np.linalg.norm(g_q)))
        # No component along the quaternion itself.
        quat = args[0][3:7]
        assert abs(g_q[3:7] @ quat) < 1e-12 * max(1.0, np.linalg.norm(g_q))
        for k, g in ((1, g_qd), (2, g_u)):
            num = np.zeros(len(g))
            for j in range(len(g)):
                plus = [np.array(a, dtype=float) for a in args]
                minus = [np.array(a, dtype=float) for a in args]
                plus[k][j] += h
                minus[k][j] -= h
                num[j] = (value(*plus) - value(*minus)) / (2 * h)
            worst = max(worst, rel(g, num))
    print(f"grid_gen.jax floating go2 (fd, rnea, step): grad against central differences on the manifold {worst:.1e}")
    # Central differences at h = 1e-5: truncation O(h^2) and rounding eps |cost| / h, the
    # latter largest against B's small entries (dt^2 M^-1): measured ~2e-8, along tangent
    # directions ~2e-10. A wrong map onto the quaternion's coordinates or a transposed A
    # would be O(1).
    assert worst < 1e-6
    with pytest.raises(ValueError, match="spherical"):
        gj.wrap(grid_gen.load(ROOT / "tests" / "fixtures" / "ball_arm.urdf", kernels=["rnea"]))


def _point_contacts(p: "Pin", frames, active=None, gains=None, refs=None):
    """Pinocchio's contacts (CONTACT_3D, or CONTACT_6D where `frames` is a dict that says
    "wrench"; LOCAL_WORLD_ALIGNED) at links, as grid-gen's; with `gains` ([Kp, Kd] per
    contact) and `refs` (world positions, or a wrench's [x, y, z, qx, qy, qz, qw]), its
    Baumgarte corrector towards the universe at each reference."""
    kinds = frames if isinstance(frames, dict) else dict.fromkeys(frames, "point")
    cms, cds = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
    for k, name in enumerate(kinds):
        if active is None or active[k]:
            frame = p.model.frames[p.model.getFrameId(name, pin.BODY)]
            kind = pin.ContactType.CONTACT_6D if kinds[name] == "wrench" else pin.ContactType.CONTACT_3D
            if gains is None:
                cm = pin.RigidConstraintModel(kind, p.model, frame.parentJoint, frame.placement, pin.LOCAL_WORLD_ALIGNED)
            else:
                r = np.asarray(refs[k], dtype=float)
                ref = pin.XYZQUATToSE3(r[:7]) if kinds[name] == "wrench" else pin.SE3(np.eye(3), r[:3])
                cm = pin.RigidConstraintModel(kind, p.model, frame.parentJoint, frame.placement, 0, ref, pin.LOCAL_WORLD_ALIGNED)
                bp = cm.m_baumgarte_parameters
                bp.Kp, bp.Kd = float(gains[k][0]), float(gains[k][1])
                cm.setBaumgarteCorrectorParameters(bp)
            cms.append(cm)
            cds.append(cm.createData())
    pin.initConstraintDynamics(p.model, p.data, cms, cds)
    return cms, cds


# A floating robot nobody bundled with two point feet, stabilised, and a semi-implicit step
# whose dt is given at run time, all from load's keywords (one library for the two tests).
KNOT = dict(floating_base=True, contacts={"l2": "point", "l4": "point"}, step="semi_implicit_euler", baumgarte=True, kernels=["step", "step_grad"])


def test_a_knot_from_load_keywords_with_the_steps_lambda(tmp_path):
    """No scene file (KNOT). The step returns λ (Pinocchio's constraintDynamics lambda_c at
    the state) and step_grad its derivatives, against central differences of Pinocchio's
    constraintDynamics on the manifold; A and B against central differences of Pinocchio's
    step (constraintDynamics, then integrate): rigid contacts (no gains), then with
    Baumgarte gains towards references (Pinocchio's corrector)."""
    urdf = tmp_path / "unseen_tree.urdf"
    urdf.write_text(random_tree_urdf(seed=2027))
    feet = KNOT["contacts"]
    robot = grid_gen.load(urdf, **KNOT)
    assert robot.contacts == [("l2", "point"), ("l4", "point")] and robot.kernels == ("step", "step_grad")
    # The kernel's inputs (what C and the header list), and Python's order: given ones first.
    assert [n for n, _ in robot.step_grad.inputs] == ["q", "qd", "tau", "gains", "contact_ref", "dt"]
    assert robot.step_grad.arguments == ("q", "qd", "tau", "dt", "gains", "contact_ref")
    p = Pin(urdf, robot)
    n, nv, nu = 3, robot.nv, robot.nu
    q, qd, tau = random_states(robot, n, seed=21)
    u = tau[:, 6:]
    dt = np.array([1e-3, 5e-3, 2e-2])
    rng = np.random.default_rng(24)
    gains = np.stack([rng.uniform(0, 200, (n, 2)), rng.uniform(0, 30, (n, 2))], axis=-1)
    refs = rng.uniform(-0.5, 0.5, (n, 2, 3))
    for stabilised in (False, True):
        corr = (gains, refs) if stabilised else None
        _check_knot(robot, p, feet, q, qd, u, dt, corr)


def _check_knot(robot, p, feet, q, qd, u, dt, corr):
    n, nv, nu = len(q), robot.nv, robot.nu
    extra = {} if corr is None else dict(gains=corr[0], contact_ref=corr[1])
    r = robot.step_grad(q, qd, u, dt, **extra)
    q1, v1, lam1 = robot.step(q, qd, u, dt, **extra)
    assert rel(lam1, r.lam) < 1e-13 and rel(v1, r.qd_next) < 1e-13

    def pin_state(qg, vg):
        return p.to_pin(qg, vg)

    def pin_lambda(qp, vp, up):
        taup = np.zeros(nv)
        taup[p.v[6:]] = up
        cms, cds = _point_contacts(p, dict(feet), gains=None if corr is None else corr[0][i], refs=None if corr is None else corr[1][i])
        a = pin.constraintDynamics(p.model, p.data, qp, vp, taup, cms, cds, pin.ProximalSettings(1e-14, 0.0, 1))
        return a.copy(), p.data.lambda_c.copy()

    def pin_step(qp, vp, up, h):
        a, lam = pin_lambda(qp, vp, up)
        v_next = vp + h * a
        return pin.integrate(p.model, qp, h * v_next), v_next, lam

    worst_lam = worst_dlam = worst_ab = 0.0
    # Central differences' step: their round-off, ε_mach times the contact forces' large
    # intermediate terms over eps, dominates at 1e-6 (measured 5.8e-8 with gains) and falls
    # to 8.6e-9 at 1e-5, where the O(eps^2) truncation is still below it.
    eps = 1e-5
    for i in range(n):
        qp, vp = pin_state(q[i], qd[i])
        _, lam = pin_lambda(qp, vp, u[i])
        q_want, v_want, _ = pin_step(qp, vp, u[i], dt[i])
        worst_lam = max(worst_lam, rel(r.lam[i], lam), rel(r.qd_next[i], p.vec(v_want)))
        # Central differences along each tangent direction of x = (q, qd) (grid-gen's
        # order, mapped to Pinocchio's) and of u.
        nl = r.lam.shape[-1]
        dlam_dx, dlam_du = np.empty((nl, 2 * nv)), np.empty((nl, nu))
        a_fd, b_fd = np.empty((2 * nv, 2 * nv)), np.empty((2 * nv, nu))
        q_next0, v_next0, _ = pin_step(qp, vp, u[i], dt[i])

        def tangent(qa, va, qb, vb):
            """x_b ⊖ x_a in grid-gen's tangent order."""
            dq = pin.difference(p.model, qa, qb)
            return np.concatenate([np.asarray(dq)[p.v], np.asarray(vb - va)[p.v]])

        for c in range(2 * nv + nu):
            outs = []
            for sign in (1.0, -1.0):
                dv = np.zeros(nv)
                qs, vs, us = qp, vp.copy(), u[i].copy()
                if c < nv:
                    dv[p.v[c]] = sign * eps
                    qs = pin.integrate(p.model, qp, dv)
                elif c < 2 * nv:
                    vs[p.v[c - nv]] += sign * eps
                else:
                    us[c - 2 * nv] += sign * eps
                outs.append(pin_step(qs, vs, us, dt[i]))
            dl = (outs[0][2] - outs[1][2]) / (2 * eps)
            dxn = (tangent(q_next0, v_next0, outs[0][0], outs[0][1]) - tangent(q_next0, v_next0, outs[1][0], outs[1][1])) / (2 * eps)
            if c < 2 * nv:
                dlam_dx[:, c], a_fd[:, c] = dl, dxn
            else:
                dlam_du[:, c - 2 * nv], b_fd[:, c - 2 * nv] = dl, dxn
        worst_dlam = max(worst_dlam, rel(r.dlam_dx[i], dlam_dx), rel(r.dlam_du[i], dlam_du))
        worst_ab = max(worst_ab, rel(r.A[i], a_fd), rel(r.B[i], b_fd))
    what = ("Baumgarte gains" if corr is not None else "rigid") + ", " + " and ".join(f"{f} {k}" for f, k in feet.items())
    print(f"unseen floating tree, two feet ({what}), step from load keywords: lambda and qd_next {worst_lam:.1e} from Pinocchio; dlam {worst_dlam:.1e}, A/B {worst_ab:.1e} from central differences")
    # λ and q̇⁺: f64 round-off through K = J M^-1 J^T (two points on a 12-dof tree, well
    # conditioned at these states). Derivatives: the central differences' own error (above)
    # with a 10x margin; a wrong term (a missing Kp J, a sign) would be O(1).
    assert worst_lam < 1e-11
    assert worst_dlam < 1e-7 and worst_ab < 1e-7


def test_a_stabilised_wrench_contact_against_pinocchio(tmp_path):
    """A wrench foot beside a point foot on the unseen floating tree, stabilised towards
    references turned by up to 0.6 rad from the feet's placements (Pinocchio's CONTACT_6D
    corrector, whose error is log6): λ and q̇⁺ against constraintDynamics, and the
    derivatives against central differences, as the point feet's test; then contact_ref's
    checks (its shape, a wrench's quaternion)."""
    urdf = tmp_path / "unseen_tree.urdf"
    urdf.write_text(random_tree_urdf(seed=2027))
    feet = {"l2": "wrench", "l4": "point"}
    robot = grid_gen.load(urdf, **{**KNOT, "contacts": feet})
    p = Pin(urdf, robot)
    n = 3
    q, qd, tau = random_states(robot, n, seed=31)
    u = tau[:, 6:]
    dt = np.array([1e-3, 5e-3, 2e-2])
    rng = np.random.default_rng(34)
    gains = np.stack([rng.uniform(0, 200, (n, 2)), rng.uniform(0, 30, (n, 2))], axis=-1)
    refs = np.zeros((n, 2, 7))
    for i in range(n):
        qp, _ = p.to_pin(q[i], qd[i])
        pin.framesForwardKinematics(p.model, p.data, qp)
        for k, foot in enumerate(feet):
            here = p.data.oMf[p.model.getFrameId(foot, pin.BODY)]
            turn = pin.exp3(rng.uniform(-0.35, 0.35, 3))
            placed = pin.SE3(turn @ here.rotation, here.translation + rng.uniform(-0.05, 0.05, 3))
            refs[i, k] = pin.SE3ToXYZQUAT(placed)
    refs[:, 1, 3:] = 0.0  # the point foot's row reads its first three entries only
    _check_knot(robot, p, feet, q, qd, u, dt, (gains, refs))
    with pytest.raises(ValueError, match=r"expected \(3, 2, 7\) or \(2, 7\) for every state"):
        robot.step(q, qd, u, dt, gains=gains, contact_ref=refs[:, :, :3])
    bad = refs.copy()
    bad[1, 0, 3:] = 0.0
    with pytest.raises(ValueError, match="contact_ref` of state 1: the quaternion .* of wrench contact `l2` has norm 0, not 1"):
        robot.step(q, qd, u, dt, gains=gains, contact_ref=bad)
    # The C ABI checks the wrench's reference quaternion as q's: a zero one at state 1,
    # passed straight to the entry point, is GRID_GEN_BAD_VALUE naming the state.
    k = robot.step
    flat_ref = np.concatenate([bad[:, 0, :], bad[:, 1, :3]], axis=1)
    ins = {"q": q, "qd": qd, "tau": u, "dt": dt, "gains": gains.reshape(n, 4), "contact_ref": flat_ref}
    arrays = [np.ascontiguousarray(ins[name], dtype=np.float64) for name, _ in k.inputs]
    outs = [np.full((n,) + dims, 7.0) for _, dims in k.outputs]
    status = k._fn(n, *[a.ctypes.data for a in arrays], *[o.ctypes.data for o in outs])
    assert status == 3 and robot._bad_state() == 1, (status, robot._bad_state())
    assert all((o == 7.0).all() for o in outs), "nothing written"
    # No contact_ref and no Kp: the wrench's reference is the identity, and the step is the
    # rigid one to rounding (Kp · log6 is 0 · a finite value).
    rigid = robot.step(q, qd, u, dt)
    assert np.isfinite(rigid.lam).all()


def test_every_setting_is_a_load_keyword():
    """The settings table, which the CLI's flags, the Builder's methods and the scene's keys
    are also held to (crates' tests), names load's keywords: each is one, with a default of
    None or False (the scene's value, or nothing, when left out)."""
    from grid_gen import _native
    parameters = inspect.signature(grid_gen.load).parameters
    for key, toml, flag, builder in _native.settings():
        assert key in parameters, f"load has no keyword `{key}` (scene {toml}, {flag}, {builder})"
        assert parameters[key].default in (None, False), key


def test_load_keywords_and_state_checks_say_what_is_wrong(tmp_path):
    """Every load keyword error names the keyword (and the scene file where both set a
    thing), and a failed load leaves nothing in the cache; a bad quaternion, a state of the
    other kind of base, τ of nv where nu is expected and a kernel the robot lacks each say
    what is wrong. Uses the robot the previous test compiled (the same keywords)."""
    urdf = tmp_path / "unseen_tree.urdf"
    urdf.write_text(random_tree_urdf(seed=2027))
    scene = tmp_path / "step.toml"
    scene.write_text('[step]\nscheme = "rk4"\ndt = 0.01\n')
    build = grid_gen.cache_dir() / "build"
    before = set(build.iterdir()) if build.exists() else set()
    cases = [
        (dict(scene=scene, step="rk4"), "load(step=...) and the scene file `" + str(scene) + "` both set the step"),
        (dict(scene=scene, dt=0.02), "both set the step's dt"),
        (dict(dt=0.01), "load(dt=...) times a step, and none is asked for"),
        (dict(dt=-1.0, step="rk4"), "load(dt=-1.0): a time step is a finite, positive number"),
        (dict(step="leapfrog"), 'load(step="leapfrog"): no such scheme; schemes: semi_implicit_euler, explicit_euler, rk4'),
        (dict(round_angles=-1.0), "load(round_angles=...): round_angles = -1 rad: give a tolerance above 0"),
        (dict(contacts={"l2": "line"}), 'contact `l2` has type "line"'),
        (dict(contacts="l2"), "load(contacts=...) takes"),
        (dict(contacts={"l9": "point"}), "load(contacts=...) names `l9`"),
        (dict(frames=["l9"]), "load(frames=...) names `l9`"),
        (dict(external_forces=["j9"]), "load(external_forces=...) names `j9`"),
    ]
    for kwargs, says in cases:
        with pytest.raises(ValueError) as e:
            grid_gen.load(urdf, floating_base=True, **kwargs)
        assert says in str(e.value), str(e.value)
    after = set(build.iterdir()) if build.exists() else set()
    assert after == before, f"failed loads left {sorted(after - before)} in the cache"

    robot = grid_gen.load(urdf, **KNOT)
    q, qd, tau = random_states(robot, 3, seed=22)
    u = tau[:, 6:]
    for bad_q, says in ((np.zeros(robot.nq), "`q`: joint `root_joint`'s quaternion q[3:7] has norm 0; a rotation is a unit quaternion"),
                        (np.concatenate([q[:, :3], 2 * q[:, 3:7], q[:, 7:]], axis=1), "`q` at state 0: joint `root_joint`'s quaternion q[3:7] has norm 2")):
        for call in (robot.step, robot.step_grad):
            with pytest.raises(ValueError) as e:
                call(bad_q, qd[0] if bad_q.ndim == 1 else qd, u[0] if bad_q.ndim == 1 else u, 0.01)
            assert says in str(e.value), str(e.value)
    # The C ABI checks too: a zero quaternion at state 1 passed straight to the entry point
    # (past Python's checks) is GRID_GEN_BAD_VALUE, and the library names the state.
    bad = q.copy()
    bad[1, 3:7] = 0.0
    k = robot.step
    ins = {"q": bad, "qd": qd, "tau": u, "dt": np.full(3, 0.01), "gains": np.zeros((3, 4)), "contact_ref": np.zeros((3, 6))}
    arrays = [np.ascontiguousarray(ins[name], dtype=np.float64) for name, _ in k.inputs]
    outs = [np.full((3,) + dims, 7.0) for _, dims in k.outputs]
    status = k._fn(3, *[a.ctypes.data for a in arrays], *[o.ctypes.data for o in outs])
    assert status == 3 and robot._bad_state() == 1, (status, robot._bad_state())
    assert all((o == 7.0).all() for o in outs), "nothing written"
    hints = [
        (lambda: robot.step(q[:, 7:], qd, u, 0.01), "this robot has a floating base, whose q starts with the base's 7 entries"),
        (lambda: robot.step(q, qd, tau, 0.01), f"step takes the {robot.nu} actuated joints' forces (nu), not one per coordinate (nv = {robot.nv}"),
    ]
    for call, says in hints:
        with pytest.raises(ValueError) as e:
            call()
        assert says in str(e.value), str(e.value)
    gain_errors = [
        (dict(gains=[[100.0, 10.0]] * 2), "`gains` has a nonzero Kp and no `contact_ref`"),
        (dict(gains=[[1.0, -1.0]] * 2, contact_ref=np.zeros((2, 3))), "negative gain"),
        (dict(gains=np.zeros((2, 3)), contact_ref=np.zeros((2, 3))), "`gains` has shape (2, 3); expected (3, 2, 2) or (2, 2) for every state: [Kp, Kd] per contact (l2, l4)"),
    ]
    for kwargs, says in gain_errors:
        with pytest.raises(ValueError) as e:
            robot.step(q, qd, u, 0.01, **kwargs)
        assert says in str(e.value), str(e.value)
    with pytest.raises(AttributeError, match="has no kernel `fd_grad`: it was left out by load\\(kernels=...\\)"):
        robot.fd_grad
    iiwa = grid_gen.load(IIWA)
    q7, qd7, tau7 = random_states(iiwa, 2, seed=23)
    with pytest.raises(ValueError, match="14 entries is a floating base's: load the robot with floating_base=True"):
        iiwa.fd(np.zeros((2, 14)), qd7, tau7)
    with pytest.raises(AttributeError, match='has no kernel `contact_fd`: load it with contacts='):
        iiwa.contact_fd


LIE_URDF = """<robot name="lie_chain">
<link name="base"><inertial><mass value="2"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
<link name="l1"><inertial><mass value="1"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"/></inertial></link>
<link name="l2"><inertial><mass value="1"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"/></inertial></link>
<link name="l3"><inertial><mass value="1"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"/></inertial></link>
<link name="l4"><inertial><mass value="1"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.04"/></inertial></link>
<joint name="shoulder" type="spherical"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/></joint>
<joint name="elbow" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.3 0 0"/><axis xyz="0.6 0 0.8"/><limit lower="-3" upper="3" effort="10" velocity="10"/></joint>
<joint name="slide" type="prismatic"><parent link="l2"/><child link="l3"/><origin xyz="0.2 0 0"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="10" velocity="10"/></joint>
<joint name="wrist" type="spherical"><parent link="l3"/><child link="l4"/><origin xyz="0 0.1 0"/></joint>
</robot>
"""


def _lie_pin_model():
    """Pinocchio's model of LIE_URDF's joints, in its order (URDF has no spherical type, so
    Pinocchio's parser cannot read it; the Lie-group operations read only the joint types)."""
    m = pin.Model()
    parent = m.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root_joint")
    for name, joint in [
        ("shoulder", pin.JointModelSpherical()),
        ("elbow", pin.JointModelRevoluteUnaligned(np.array([0.6, 0.0, 0.8]))),
        ("slide", pin.JointModelPrismaticUnaligned(np.array([0.0, 1.0, 0.0]))),
        ("wrist", pin.JointModelSpherical()),
    ]:
        parent = m.addJoint(parent, joint, pin.SE3.Identity(), name)
    return m


def test_lie_group_kernels_match_pinocchio(tmp_path):
    """integrate, dintegrate, difference and ddifference on a free-flyer, two spherical
    joints, a revolute and a prismatic one, against Pinocchio 4.1's functions, batched, at
    the logarithm's delicate angles: none, tiny, near a half turn, and q1's quaternions of
    the other sign."""
    urdf = tmp_path / "lie_chain.urdf"
    urdf.write_text(LIE_URDF)
    robot = grid_gen.load(urdf, floating_base=True, kernels=["integrate", "dintegrate", "difference", "ddifference"])
    m = _lie_pin_model()
    assert (robot.nq, robot.nv) == (m.nq, m.nv) == (17, 14)
    assert [at for _, at in robot._quaternions] == [3, 7, 13]
    rng = np.random.default_rng(57)
    quats = [3, 7, 13]
    rotations = [(3, 6), (6, 9), (11, 14)]

    def random_q():
        q = pin.randomConfiguration(m, -np.ones(m.nq), np.ones(m.nq))
        for at in quats:
            x = rng.normal(size=4)
            q[at : at + 4] = x / np.linalg.norm(x)
        return q

    states = []
    for theta in [0.0, 1e-9, 0.7, 3.1, math.pi - 1e-6, None, None]:
        q, v = random_q(), rng.uniform(-2, 2, m.nv)
        if theta is not None:
            for a, b in rotations:
                n = np.linalg.norm(v[a:b])
                v[a:b] *= theta / n if theta > 0 else 0.0
        q1 = pin.integrate(m, q, v)
        if theta is None:
            q1 = random_q()
        if len(states) == 6:
            for at in quats:
                q1[at : at + 4] *= -1.0
        states.append((q, v, q1))
    Q = np.array([s[0] for s in states])
    V = np.array([s[1] for s in states])
    Q1 = np.array([s[2] for s in states])
    got = {
        "integrate": robot.integrate(Q, V),
        "dintegrate": robot.dintegrate(Q, V),
        "difference": robot.difference(Q, Q1),
        "ddifference": robot.ddifference(Q, Q1),
    }
    worst = 0.0
    for i, (q, v, q1) in enumerate(states):
        want = {
            "integrate": [pin.integrate(m, q, v)],
            "dintegrate": [pin.dIntegrate(m, q, v, pin.ARG0), pin.dIntegrate(m, q, v, pin.ARG1)],
            "difference": [pin.difference(m, q, q1)],
            "ddifference": [pin.dDifference(m, q, q1, pin.ARG0), pin.dDifference(m, q, q1, pin.ARG1)],
        }
        for name, w in want.items():
            g = got[name]
            g = [g[i]] if isinstance(g, np.ndarray) else [x[i] for x in g]
            for a, b in zip(g, w):
                # At v = 0 the entries are zeros (and Pinocchio's rounding): absolute there.
                e = float(np.max(np.abs(a - b))) if i == 0 and name == "difference" else rel(a, b)
                worst = max(worst, e)
                # Pinocchio reaches the same values by atan2, Taylor branches and closed-form
                # Jacobians: agreement to round-off of entries of order 1 (measured below).
                assert e < 1e-12, f"{name} state {i}: {e:.2e}"
    print(f"Lie-group kernels against Pinocchio on a free-flyer, two spherical, a revolute and a prismatic joint: worst {worst:.1e}")
    r = robot.dintegrate(Q[0], V[0])
    assert r.dq.shape == r.dv.shape == (14, 14)
    bad = Q1[1].copy()
    bad[7:11] *= 1.01
    with pytest.raises(ValueError, match=r"`q1`: joint `shoulder`'s quaternion q1\[7:11\] has norm 1.01"):
        robot.difference(Q[1], bad)
    with pytest.raises(ValueError, match=r"`v` has shape \(17,\).*\(14,\)"):
        robot.integrate(Q[1], Q1[1])


def test_jax_contact_forces_through_rnea_fd_and_the_step(tmp_path):
    """A floating robot nobody bundled on two point contacts with a semi-implicit step:
    grid_gen.jax's rnea and fd take λ, its step returns the step's λ, and jax.grad of a cost
    of all their outputs (λ's included) matches central differences on the manifold, q moved
    by the robot's own integrate (held to Pinocchio in test_lie_group_kernels_match_pinocchio)."""
    jax = _jax()
    import jax.numpy as jnp

    import grid_gen.jax as gj

    urdf = tmp_path / "unseen_tree.urdf"
    urdf.write_text(random_tree_urdf(seed=2027))
    kernels = ["rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad", "step", "step_grad", "integrate"]
    robot = grid_gen.load(urdf, floating_base=True, contacts={"l2": "point", "l4": "point"}, step="semi_implicit_euler", dt=0.01, kernels=kernels)
    dyn = gj.wrap(robot)
    nl = robot.nlambda
    assert nl == 6 and [n for n, _ in robot.fd.inputs] == ["q", "qd", "tau", "lambda"]
    rng = np.random.default_rng(9)
    q = np.concatenate([[0.1, -0.2, 0.3], np.array([0.1, 0.2, -0.3, 0.9]) / np.linalg.norm([0.1, 0.2, -0.3, 0.9]), rng.uniform(-1, 1, robot.nv - 6)])
    qd, tau, lam = rng.uniform(-1, 1, robot.nv), rng.uniform(-2, 2, robot.nv), rng.uniform(-5, 5, nl)
    u = tau[6:]
    wq, wv, wl = rng.normal(size=robot.nq), rng.normal(size=robot.nv), rng.normal(size=nl)

    def jax_cost(kind):
        if kind == "step":
            def cost(q, qd, u):
                q_next, qd_next, lam_next = dyn.step(q, qd, u)
                return jnp.dot(q_next, wq) + jnp.dot(qd_next, wv) + jnp.dot(lam_next, wl)
            return cost
        f = dyn.fd if kind == "fd" else dyn.rnea
        return lambda q, qd, y, lam: jnp.dot(f(q, qd, y, lam), wv)

    def plain(kind):
        if kind == "step":
            def value(q, qd, u):
                r = robot.step(q, qd, u)
                return r.q_next @ wq + r.qd_next @ wv + r.lam @ wl
            return value
        f = robot.fd if kind == "fd" else robot.rnea
        return lambda q, qd, y, lam: float(f(q, qd, y, lam) @ wv)

    h = 1e-5
    worst = 0.0
    for kind, args in (("fd", (q, qd, tau, lam)), ("rnea", (q, qd, tau / 10, lam)), ("step", (q, qd, u))):
        n = len(args)
        grads = [np.asarray(g) for g in jax.jit(jax.grad(jax_cost(kind), argnums=tuple(range(n))))(*args)]
        value = plain(kind)
        for _ in range(4):
            d = rng.normal(size=robot.nv)
            qp, qm = robot.integrate(args[0], h * d), robot.integrate(args[0], -h * d)
            num = (value(qp, *args[1:]) - value(qm, *args[1:])) / (2 * h)
            worst = max(worst, abs(grads[0] @ ((qp - qm) / (2 * h)) - num) / max(abs(num), np.linalg.norm(grads[0])))
        for k in range(1, n):
            num = np.zeros(len(grads[k]))
            for j in range(len(num)):
                plus = [np.array(a, dtype=float) for a in args]
                minus = [np.array(a, dtype=float) for a in args]
                plus[k][j] += h
                minus[k][j] -= h
                num[j] = (value(*plus) - value(*minus)) / (2 * h)
            worst = max(worst, rel(grads[k], num))
    print(f"grid_gen.jax with contacts (fd, rnea with lambda, step's lambda): grad against central differences {worst:.1e}")
    # As the floating go2 test: central differences at h = 1e-5 are good to ~1e-8 here; a
    # missing or transposed dlambda term would be O(1).
    assert worst < 1e-6


def test_jax_step_with_a_run_time_dt_and_a_contact_mask(tmp_path):
    """A step whose dt is chosen at run time and whose contacts are chosen per state
    (`contact_mask`), on a floating and a fixed robot nobody bundled: grid_gen.jax's step
    gives the plain kernel's values to the bit, and jax.grad of a cost of all its outputs
    with respect to q, qd, u and dt matches central differences (q moved by the robot's own
    integrate), in every contact mode; a batch takes one dt and one mask per state."""
    jax = _jax()
    import jax.numpy as jnp

    import grid_gen.jax as gj

    urdf = tmp_path / "unseen_tree.urdf"
    urdf.write_text(random_tree_urdf(seed=2028))
    kernels = ["rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad", "step", "step_grad", "integrate", "dintegrate"]
    h = 1e-5
    worst = 0.0
    for floating, contacts, modes in (
        (True, {"l2": "point", "l4": "point"}, ([True, True], [True, False], [False, False])),
        (False, {"l4": "point"}, ([True], [False])),
    ):
        robot = grid_gen.load(urdf, floating_base=floating, contacts=contacts, contact_mask=True, step="semi_implicit_euler", kernels=kernels)
        assert [n for n, _ in robot.step.inputs] == ["q", "qd", "tau", "active", "dt"]
        dyn = gj.wrap(robot)
        rng = np.random.default_rng(10)
        q = rng.uniform(-1, 1, robot.nq)
        if floating:
            q[:3] = [0.1, -0.2, 0.3]
            q[3:7] = np.array([0.1, 0.2, -0.3, 0.9]) / np.linalg.norm([0.1, 0.2, -0.3, 0.9])
        qd, u, dt = rng.uniform(-1, 1, robot.nv), rng.uniform(-2, 2, robot.nu), 0.02
        nl = robot.nlambda
        wq, wv, wl = rng.normal(size=robot.nq), rng.normal(size=robot.nv), rng.normal(size=nl)
        for mode in modes:
            def value(q, qd, u, dt):
                r = robot.step(q, qd, u, float(dt), active=mode)
                return r.q_next @ wq + r.qd_next @ wv + r.lam @ wl

            def cost(q, qd, u, dt):
                q_next, qd_next, lam = dyn.step(q, qd, u, dt, active=jnp.array(mode))
                return jnp.dot(q_next, wq) + jnp.dot(qd_next, wv) + jnp.dot(lam, wl)

            got = dyn.step(q, qd, u, dt, active=jnp.array(mode))
            want = robot.step(q, qd, u, dt, active=mode)
            assert all((np.asarray(a) == b).all() for a, b in zip(got, want)), "the FFI call is the kernel"
            args = (q, qd, u, np.array(dt))
            grads = [np.asarray(g) for g in jax.jit(jax.grad(cost, argnums=(0, 1, 2, 3)))(*args)]
            for _ in range(4):
                d = rng.normal(size=robot.nv)
                qp, qm = robot.integrate(q, h * d), robot.integrate(q, -h * d)
                num = (value(qp, qd, u, dt) - value(qm, qd, u, dt)) / (2 * h)
                worst = max(worst, abs(grads[0] @ ((qp - qm) / (2 * h)) - num) / max(abs(num), np.linalg.norm(grads[0])))
            for k in (1, 2, 3):
                num = np.zeros(np.size(grads[k]))
                for j in range(len(num)):
                    plus = [np.array(a, dtype=float) for a in args]
                    minus = [np.array(a, dtype=float) for a in args]
                    plus[k].reshape(-1)[j] += h
                    minus[k].reshape(-1)[j] -= h
                    num[j] = (value(*plus) - value(*minus)) / (2 * h)
                worst = max(worst, rel(np.reshape(grads[k], -1), num))
        # A batch: one dt and one mask per state, as leading axes.
        n = 3
        qs = np.stack([robot.integrate(q, 0.1 * rng.normal(size=robot.nv)) for _ in range(n)])
        qds, us, dts = np.tile(qd, (n, 1)), np.tile(u, (n, 1)), np.array([0.01, 0.02, 0.005])
        masks = np.array([modes[k % len(modes)] for k in range(n)])
        got = dyn.step(qs, qds, us, dts, active=masks)
        want = robot.step(qs, qds, us, dts, active=masks)
        assert all((np.asarray(a) == b).all() for a, b in zip(got, want)), "per-state dt and masks"
        with pytest.raises(TypeError, match="takes dt at run time"):
            dyn.step(q, qd, u)
    print(f"grid_gen.jax step with run-time dt and contact masks: grad against central differences {worst:.1e}")
    # As the tests above: central differences at h = 1e-5 are good to ~1e-8 here; a missing
    # dt term (q̈ in qd+, integrate's differential in q+) would be O(1).
    assert worst < 1e-6
