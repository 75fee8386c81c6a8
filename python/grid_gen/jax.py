"""grid_gen's kernels as JAX functions, with their gradients from the generated kernels.

    import jax, grid_gen, grid_gen.jax
    jax.config.update("jax_enable_x64", True)      # the kernels are f64
    dyn = grid_gen.jax.wrap(grid_gen.load("robots/grid_iiwa.urdf"))
    qdd = dyn.fd(q, qd, tau)                        # jit, vmap and grad all work
    g = jax.grad(lambda q: cost(dyn.fd(q, qd, tau)))(q)

`rnea(q, qd, qdd)` and `fd(q, qd, tau)` are `jax.custom_vjp` functions: their values come
from the robot's kernels, their reverse-mode rules from its analytical gradients
(`rnea_grad` with M for rnea; `fd_grad` with M^-1 for fd), never from differentiating
through the kernels. They run on the CPU through `jax.pure_callback` with
`vmap_method="broadcast_all"` (a batch of states is one call of the batch kernel, on every
core), not as XLA FFI custom calls: the callback costs a Python round trip per call.

Covered: robots whose q has nv entries (no floating base, no spherical joints), since
JAX differentiates q in its own coordinates and the kernels' gradients are in the tangent
space; reverse mode (`grad`, `vjp`), not forward mode (`jvp`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._robot import Robot


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


class Functions:
    """`rnea` and `fd` of one robot as differentiable JAX functions (see the module doc)."""

    def __init__(self, robot: Robot):
        if robot.nq != robot.nv:
            raise ValueError(
                f"grid_gen.jax covers robots whose q has nv entries; {robot.name} has nq {robot.nq}, nv {robot.nv} "
                "(a floating base or spherical joints: the kernels' gradients are in the tangent space)"
            )
        missing = [k for k in ("rnea", "rnea_grad", "mass_matrix", "fd", "fd_grad", "minv") if k not in robot.kernels]
        if missing:
            raise ValueError(f"grid_gen.jax needs the kernels {', '.join(missing)}; load the robot with them")
        self.robot = robot

        def call(name, *args):
            kernel = getattr(robot, name)
            lead = jnp.shape(args[0])[:-1]
            dtype = jnp.result_type(*args)
            shapes = tuple(jax.ShapeDtypeStruct(lead + dims, dtype) for _, dims in kernel.outputs)
            return jax.pure_callback(_host(kernel, kernel.outputs), shapes, *args, vmap_method="broadcast_all")

        def vec_mat(g, m):
            # g: (..., n), m: (..., n, k) -> (..., k): the cotangent pulled back through m.
            return jnp.einsum("...i,...ij->...j", g, m)

        def differentiable(value, grad, matrix, grad_gives_value):
            """The kernel `value` as a custom_vjp function of three arrays: its rule pulls the
            cotangent back through `grad`'s two matrices (for the first two arguments) and
            through `matrix` of q (for the third). `grad_gives_value`: `grad` returns the value
            first (fd_grad's q̈), so it is not computed twice."""

            @jax.custom_vjp
            def f(q, x, y):
                return call(value, q, x, y)[0]

            def f_fwd(q, x, y):
                out = call(grad, q, x, y)
                val, dq, dx = out[:3] if grad_gives_value else (call(value, q, x, y)[0], *out[:2])
                (m,) = call(matrix, q)
                return val, (dq, dx, m)

            def f_bwd(res, g):
                return tuple(vec_mat(g, m) for m in res)

            f.defvjp(f_fwd, f_bwd)
            return f

        self.rnea = differentiable("rnea", "rnea_grad", "mass_matrix", grad_gives_value=False)
        self.fd = differentiable("fd", "fd_grad", "minv", grad_gives_value=True)


def wrap(robot: Robot) -> Functions:
    """The robot's `rnea` and `fd` as differentiable JAX functions."""
    return Functions(robot)
