"""grid_gen's kernels as JAX functions: XLA FFI custom calls, with reverse-mode rules from the
generated gradients.

    import jax, grid_gen, grid_gen.jax
    jax.config.update("jax_enable_x64", True)      # f64 (or load with precision="f32")
    dyn = grid_gen.jax.wrap(grid_gen.load("robots/grid_iiwa.urdf"))
    qdd = dyn.fd(q, qd, tau)                        # jit, vmap and grad all work
    g = jax.grad(lambda q: cost(dyn.fd(q, qd, tau)))(q)

`rnea(q, qd, qdd)`, `fd(q, qd, tau)` and, for a robot loaded with a step (a scene's `[step]`),
`step(q, qd, tau) -> (q_next, qd_next)` are `jax.custom_vjp` functions: their values come
from the robot's kernels, their reverse-mode rules from its analytical gradients (`rnea_grad`
with M for rnea; `fd_grad` with M^-1 for fd; `step_grad`'s A and B for step), never from
differentiating through the kernels. A robot with contacts: `rnea` and `fd` take the contact
forces as a fourth argument, `lam` (their rules pull back through `dc_dlambda`,
`dqdd_dlambda`), and `step` returns `(q_next, qd_next, lam)`, the step's contact forces,
whose cotangent its rule pulls back through `dlambda_dx` and `dlambda_du`.

A robot loaded with a run-time dt or a contact mask (`load(..., contact_mask=True)`, a step
without `dt=`): `step(q, qd, tau, dt=None, active=None)`. `dt` is a scalar or one per state
(the leading axes of q), and its cotangent is exact: semi-implicit Euler's x+ moves with dt
by q̈ = (qd+ − qd)/dt in qd+ and by integrate's differential applied to qd+ + dt q̈ in q+
(a floating base needs the `dintegrate` kernel for it; fixed joints' is the identity). The
step's λ does not depend on dt. `active` is one bool per candidate contact (default: all
hold), the same for every state or one row per state; any nonzero entry holds. A mask is
discrete, so its cotangent is zero. Under `jit`, values cannot be checked: a dt that is
not positive is stepped as given (the plain kernels raise on it). External forces and
Baumgarte's inputs are not covered (a step that takes them is not wrapped: `step` is None).

Each call is an XLA FFI custom call (`jax.ffi.ffi_call`, `vmap_method="broadcast_all"`): one
small C++ handler, compiled once with the local C++ compiler against jaxlib's headers and
cached beside the robots, calls the robot library's C batch entry point on XLA's own buffers,
so a jitted program never returns to Python and a batch (any leading axes, vmap included) is
one call of the batch kernel on every core. `wrap(robot, via="callback")` uses
`jax.pure_callback` instead (a Python round trip per call) where no C++ compiler is at hand.

Floating base: q holds the free-flyer's position and unit quaternion (x, y, z, w), while the
kernels' derivatives are in the tangent space (Pinocchio's: the base's local twist). The rules
map them onto q's coordinates through `integrate`'s differential at q: the cotangent of the
position is R g_v, of the quaternion 2 U g_w with U = d(quat * exp(w/2))/dw (so no component
along the quaternion itself: a change of its norm changes nothing a unit quaternion means).
Spherical joints are not covered. Reverse mode (`grad`, `vjp`), not forward mode (`jvp`).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from importlib import resources
from pathlib import Path
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from ._loader import _library_name, cache_dir
from ._robot import Robot

_TARGET = "grid_gen_call"
_registered = False


def _handler_library() -> Path:
    """The compiled FFI handler, built on first use and cached by the source's hash, jaxlib's
    version and its headers' location."""
    source = resources.files("grid_gen").joinpath("_xla_ffi.cc").read_bytes()
    include = jax.ffi.include_dir()
    key = hashlib.sha256(source + jax.__version__.encode() + include.encode()).hexdigest()[:16]
    lib = cache_dir() / "jax" / key / _library_name("grid_gen_xla")
    if lib.exists():
        return lib
    cxx = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
    if not cxx:
        raise RuntimeError(
            "grid_gen.jax compiles a small XLA FFI handler once with a C++ compiler, and none is on PATH "
            "(nor $CXX): install one (Debian: apt-get install g++), or use wrap(robot, via='callback')"
        )
    lib.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        src = Path(tmp) / "grid_gen_xla.cc"
        src.write_bytes(source)
        out = Path(tmp) / lib.name
        # jaxlib's headers warn under -Wall (switches without a default); ours are clean.
        cmd = [cxx, "-O2", "-std=c++17", "-shared", "-fPIC", "-Wno-return-type", f"-I{include}", str(src), "-o", str(out)]
        run = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if run.returncode != 0:
            raise RuntimeError(f"grid_gen.jax could not compile its XLA FFI handler ({' '.join(cmd)}):\n{run.stdout}")
        # Rename into place: a concurrent first use sees the whole library or none.
        os.replace(out, lib)
    return lib


def _register() -> None:
    global _registered
    if not _registered:
        handler = ctypes.CDLL(str(_handler_library()))
        jax.ffi.register_ffi_target(_TARGET, jax.ffi.pycapsule(handler.GridGenCall), platform="cpu")
        _registered = True


def _host(kernel, outputs):
    """A host function for pure_callback: any leading batch axes, flattened into one batch
    call of the kernel, results cast to the inputs' dtype."""

    def run(*args):
        args = [np.asarray(a) for a in args]
        lead = args[0].shape[:-1]
        flat = [a.reshape((-1, a.shape[-1])) for a in args]
        res = kernel(*flat)
        res = res if isinstance(res, tuple) else (res,)
        dtype = args[0].dtype
        return tuple(np.asarray(r, dtype=dtype).reshape(lead + dims) for r, (_, dims) in zip(res, outputs))

    return run


def _quat_u(quat):
    """U = [quat * e_x, quat * e_y, quat * e_z] (4 x 3, rows x, y, z, w): quat * exp(w/2)
    moves by U w / 2 to first order (Pinocchio's quaternion integrate)."""
    x, y, z, w = (quat[..., i] for i in range(4))
    # w I + [v]x over -v^T.
    rows = [
        jnp.stack([w, -z, y], axis=-1),
        jnp.stack([z, w, -x], axis=-1),
        jnp.stack([-y, x, w], axis=-1),
        jnp.stack([-x, -y, -z], axis=-1),
    ]
    return jnp.stack(rows, axis=-2)


def _rotation(quat):
    """The rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = (quat[..., i] for i in range(4))
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            jnp.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            jnp.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


class Functions:
    """A robot's `rnea`, `fd` (and `step`, when loaded with one) as differentiable JAX
    functions (see the module doc)."""

    def __init__(self, robot: Robot, via: str = "ffi"):
        if via not in ("ffi", "callback"):
            raise ValueError(f"via must be 'ffi' or 'callback', not {via!r}")
        floating = robot.floating_base and robot.nq == robot.nv + 1
        if robot.nq != robot.nv and not floating:
            raise ValueError(
                f"grid_gen.jax covers fixed bases and a floating base; {robot.name} has spherical joints "
                f"(nq {robot.nq}, nv {robot.nv}), whose quaternions it does not map onto the tangent space"
            )
        missing = [k for k in ("rnea", "rnea_grad", "mass_matrix", "fd", "fd_grad", "minv") if k not in robot.kernels]
        stepped = "step" in robot.kernels and "step_grad" in robot.kernels
        if stepped and floating and "dt" in dict(robot.step.inputs) and "dintegrate" not in robot.kernels:
            # dt's cotangent moves q+ by integrate's differential (see the module doc).
            missing.append("dintegrate")
        if missing:
            raise ValueError(f"grid_gen.jax needs the kernels {', '.join(missing)}; load the robot with them")
        contacts = bool(robot.contacts)
        for k, names in (("rnea", ["q", "qd", "qdd"]), ("fd", ["q", "qd", "tau"])):
            names = names + ["lambda"] * contacts
            got = [n for n, _ in getattr(robot, k).inputs]
            if got != names:
                raise ValueError(
                    f"grid_gen.jax wraps {k}({', '.join(names)}); {robot.name}'s takes ({', '.join(got)}) "
                    "(external forces are not covered)"
                )
        self.robot = robot
        self.via = via
        self._floating = floating
        if via == "ffi":
            _register()

        def call(name, *args):
            kernel = getattr(robot, name)
            # The robot's scalar: the library holds the entry points of the precision it was
            # loaded with, and the arrays are cast to it.
            dtype = jnp.dtype(robot.dtype)
            if dtype == jnp.float64 and not jax.config.jax_enable_x64:
                raise ValueError(
                    f"{robot.name} was loaded with precision 'f64', which JAX computes only with "
                    "jax.config.update('jax_enable_x64', True); enable it, or load the robot with precision='f32'"
                )
            args = [jnp.asarray(a, dtype=dtype) for a in args]
            for a, (arg, length) in zip(args, kernel.inputs):
                if a.ndim < 1 or a.shape[-1] != length:
                    raise ValueError(f"{name}: `{arg}` has shape {a.shape}; expected (..., {length})")
            lead = jnp.broadcast_shapes(*(a.shape[:-1] for a in args))
            args = [jnp.broadcast_to(a, lead + a.shape[-1:]) for a in args]
            shapes = tuple(jax.ShapeDtypeStruct(lead + dims, dtype) for _, dims in kernel.outputs)
            if via == "callback":
                return jax.pure_callback(_host(kernel, kernel.outputs), shapes, *args, vmap_method="broadcast_all")
            ffi = jax.ffi.ffi_call(_TARGET, shapes, vmap_method="broadcast_all")
            out = ffi(
                *args,
                fn=np.int64(kernel._address),
                state_len=np.int64(kernel.inputs[0][1]),
                precision_bytes=np.int64(jnp.dtype(dtype).itemsize),
            )
            return tuple(out)

        def vec_mat(g, m):
            # g: (..., n), m: (..., n, k) -> (..., k): the cotangent pulled back through m.
            return jnp.einsum("...i,...ij->...j", g, m)

        def q_cotangent(q, g_v):
            """The cotangent of q's coordinates from the tangent-space one (see the module doc)."""
            if not floating:
                return g_v
            quat = q[..., 3:7]
            g_p = jnp.einsum("...ij,...j->...i", _rotation(quat), g_v[..., 0:3])
            g_quat = 2.0 * jnp.einsum("...ij,...j->...i", _quat_u(quat), g_v[..., 3:6])
            return jnp.concatenate([g_p, g_quat, g_v[..., 6:]], axis=-1)

        def v_cotangent(q, g_q):
            """The tangent-space cotangent from one of q's coordinates: the transpose of
            integrate's differential at q (dq = [R dv_lin, U dw / 2, dv_joints])."""
            if not floating:
                return g_q
            quat = q[..., 3:7]
            g_lin = jnp.einsum("...ji,...j->...i", _rotation(quat), g_q[..., 0:3])
            g_ang = 0.5 * jnp.einsum("...ji,...j->...i", _quat_u(quat), g_q[..., 3:7])
            return jnp.concatenate([g_lin, g_ang, g_q[..., 7:]], axis=-1)

        def differentiable(value, grad, matrix, grad_gives_value, by_lambda):
            """The kernel `value` as a custom_vjp function of three arrays (four with contacts:
            λ last): its rule pulls the cotangent back through `grad`'s two matrices (for the
            first two arguments), through `matrix` of q (for the third) and through `grad`'s
            output `by_lambda` (for λ). `grad_gives_value`: `grad` returns the value first
            (fd_grad's q̈), so it is not computed twice."""
            at = [n for n, _ in getattr(robot, grad).outputs].index(by_lambda) if contacts else None

            @jax.custom_vjp
            def f(q, x, y, *lam):
                return call(value, q, x, y, *lam)[0]

            def f_fwd(q, x, y, *lam):
                out = call(grad, q, x, y, *lam)
                val, dq, dx = out[:3] if grad_gives_value else (call(value, q, x, y, *lam)[0], *out[:2])
                (m,) = call(matrix, q)
                return val, (q, dq, dx, m, out[at] if contacts else None)

            def f_bwd(res, g):
                q, dq, dx, m, dl = res
                rest = (vec_mat(g, dl),) if contacts else ()
                return (q_cotangent(q, vec_mat(g, dq)), vec_mat(g, dx), vec_mat(g, m), *rest)

            f.defvjp(f_fwd, f_bwd)
            return f

        self.rnea: Callable = differentiable("rnea", "rnea_grad", "mass_matrix", False, "dc_dlambda")
        self.fd: Callable = differentiable("fd", "fd_grad", "minv", True, "dqdd_dlambda")
        self.step: Optional[Callable] = None
        names = [n for n, _ in robot.step.inputs] if stepped else []
        if names[:3] == ["q", "qd", "tau"] and set(names[3:]) <= {"active", "dt"}:
            nv = robot.nv
            # The kernel's inputs after τ, in its order (the C ABI's): the mask, then dt.
            extra = names[3:]
            takes_dt, masked = "dt" in extra, "active" in extra

            @jax.custom_vjp
            def step(q, qd, tau, *rest):
                # With contacts, the step's λ at the knot follows: (q_next, qd_next, lam).
                return tuple(call("step", q, qd, tau, *rest))

            def step_fwd(q, qd, tau, *rest):
                out = call("step_grad", q, qd, tau, *rest)
                # (q_next, qd_next, A, B) and with contacts (lam, dlam_dx, dlam_du).
                value = (out[0], out[1]) + ((out[4],) if contacts else ())
                return value, (q, qd, rest, out[0], out[1], out[2], out[3], out[5:] if contacts else None)

            def step_bwd(res, g):
                q, qd, rest, q_next, qd_next, a, b, dlam = res
                g_qn = v_cotangent(q_next, g[0])
                g_x = jnp.concatenate([g_qn, g[1]], axis=-1)
                g_in, g_tau = vec_mat(g_x, a), vec_mat(g_x, b)
                if contacts:
                    g_in = g_in + vec_mat(g[2], dlam[0])
                    g_tau = g_tau + vec_mat(g[2], dlam[1])
                g_rest = []
                for name, value in zip(extra, rest):
                    if name == "active":
                        g_rest.append(jnp.zeros_like(value))
                        continue
                    # qd+ = qd + dt q̈ and q+ = integrate(q, dt qd+): d qd+/d dt = q̈ and
                    # d q+/d dt = J_v (qd+ + dt q̈) with J_v integrate's differential in v
                    # (Pinocchio's dIntegrate ARG1, the identity on a fixed base's joints).
                    # λ does not depend on dt. q̈ from the step's own values: f64 round-off
                    # of |qd+| over dt, relative to |q̈|.
                    qdd = (qd_next - qd) / value
                    w = qd_next + value * qdd
                    if floating:
                        (_, j_v) = call("dintegrate", q, value * qd_next)
                        w = jnp.einsum("...ij,...j->...i", j_v, w)
                    g_dt = jnp.sum(g_qn * w, axis=-1) + jnp.sum(g[1] * qdd, axis=-1)
                    g_rest.append(g_dt[..., None])
                return (q_cotangent(q, g_in[..., :nv]), g_in[..., nv:], g_tau, *g_rest)

            step.defvjp(step_fwd, step_bwd)
            nc = len(robot.contacts)

            def stepped_fn(q, qd, tau, dt=None, active=None):
                dtype = jnp.dtype(robot.dtype)
                args = [jnp.asarray(q, dtype), jnp.asarray(qd, dtype), jnp.asarray(tau, dtype)]
                if takes_dt and dt is None:
                    raise TypeError(f"{robot.name}'s step takes dt at run time: step(q, qd, tau, dt)")
                if not takes_dt and dt is not None:
                    raise TypeError(f"{robot.name}'s step has its dt folded in at load; it takes no dt")
                if not masked and active is not None:
                    raise TypeError(f"{robot.name}'s step holds every contact; load with contact_mask=True to choose them with active=")
                rest = []
                for name in extra:
                    if name == "active":
                        mask = jnp.ones((nc,), bool) if active is None else jnp.asarray(active)
                        if mask.ndim < 1 or mask.shape[-1] != nc:
                            raise ValueError(f"step: `active` has shape {mask.shape}; expected (..., {nc}), one per contact")
                        # Any nonzero entry holds: the kernel reads exactly 1 or 0.
                        rest.append(jnp.where(mask != 0, 1.0, 0.0).astype(dtype))
                    else:
                        h = jnp.asarray(dt, dtype)
                        rest.append(h[..., None])
                lead = jnp.broadcast_shapes(*(x.shape[:-1] for x in args + rest))
                # Broadcast here, outside the custom_vjp, so that autodiff sums each
                # input's cotangent over the axes it was broadcast along.
                args = [jnp.broadcast_to(x, lead + x.shape[-1:]) for x in args + rest]
                return step(*args)

            self.step = stepped_fn if extra else step


def wrap(robot: Robot, via: str = "ffi") -> Functions:
    """The robot's `rnea`, `fd` (and `step`) as differentiable JAX functions; `via="ffi"`
    (XLA FFI custom calls, the default) or `"callback"` (`jax.pure_callback`)."""
    return Functions(robot, via=via)
