"""grid_gen.jax's call cost: `jit(fd)` and `jit(vmap(grad))` of a cost through the XLA FFI
custom call and through `jax.pure_callback`, beside the NumPy call of the same batch kernel,
iiwa, f64, B = 1, 64, 1024 states (median of 300 calls, microseconds per call).

    GRID_GEN_CACHE=target/grid-gen-cache target/python/bin/python scripts/bench_jax.py

A benchmark, not a test: the numbers in docs/guide/c-cpp-python.md come from it.
"""

import time, numpy as np, jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
import grid_gen, grid_gen.jax as gj
from pathlib import Path
m = grid_gen.load(Path(__file__).resolve().parents[1] / "robots" / "grid_iiwa.urdf", verbose=False)
rng = np.random.default_rng(0)
def med(f, reps=300):
    f(); ts=[]
    for _ in range(reps):
        t=time.perf_counter(); f(); ts.append(time.perf_counter()-t)
    return np.median(ts)*1e6
for B in (1, 64, 1024):
    q, qd, tau = (jnp.asarray(rng.uniform(-1,1,(B,7))) for _ in range(3))
    row=[]
    for via in ("ffi","callback"):
        d=gj.wrap(m, via=via)
        f=jax.jit(d.fd); row.append(med(lambda: f(q,qd,tau).block_until_ready()))
        g=jax.jit(jax.vmap(jax.grad(lambda q,qd,t: jnp.sum(d.fd(q,qd,t)**2)))); row.append(med(lambda: g(q,qd,tau).block_until_ready()))
    qn,qdn,tn=(np.asarray(x) for x in (q,qd,tau))
    row.append(med(lambda: m.fd(qn,qdn,tn)))
    print(f"B={B}: jit fd ffi {row[0]:.1f} us, grad ffi {row[1]:.1f} us | callback {row[2]:.1f}, {row[3]:.1f} us | numpy call {row[4]:.1f} us")
