"""grid-gen from Python: a robot's generated dynamics kernels on NumPy batches, on every core.

    import grid_gen, numpy as np
    m = grid_gen.load("go2.urdf", floating_base=True)
    qdd, dqdd_dq, dqdd_dqd = m.fd_grad(q, qd, tau)   # q: (B, nq); qd, tau: (B, nv)

`load` generates the robot's Rust kernels and their C ABI, compiles them into a shared
library with the local Rust toolchain (cargo), caches the library by content, and loads
it. Every kernel is a method named like the kernel; the batch is axis 0, and a 1-D array
is one state.
"""

from __future__ import annotations

from ._loader import cache_dir, load
from ._robot import Robot

__all__ = ["load", "Robot", "cache_dir"]
