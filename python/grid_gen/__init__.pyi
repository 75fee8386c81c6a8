"""Type stubs for grid_gen: the kernel methods exist when the robot was generated with them."""

import os
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

Array = np.ndarray
ArrayLike = Any

def cache_dir() -> Path: ...
def load(
    urdf: Union[str, os.PathLike],
    floating_base: bool = False,
    scene: Optional[Union[str, os.PathLike]] = None,
    frames: Optional[Sequence[str]] = None,
    precision: str = "f64",
    kernels: Optional[Sequence[str]] = None,
    verbose: bool = True,
    *,
    contacts: Union[None, Mapping[str, str], Sequence[Tuple[str, str]]] = None,
    step: Optional[str] = None,
    dt: Optional[float] = None,
    actuated: Optional[Sequence[str]] = None,
    external_forces: Optional[Sequence[str]] = None,
    contact_mask: Optional[bool] = None,
    baumgarte: Optional[bool] = None,
    gravity: Optional[Sequence[float]] = None,
    round_angles: Optional[float] = None,
    batch_lanes: str = "auto",
    calls: str = "auto",
) -> Robot: ...

class Kernel:
    name: str
    inputs: Tuple[Tuple[str, int], ...]
    outputs: Tuple[Tuple[str, Tuple[int, ...]], ...]
    arguments: Tuple[str, ...]
    def __call__(self, *args: ArrayLike, out: Union[None, Array, Sequence[Array]] = None, **kwargs: ArrayLike) -> Any: ...

class Robot:
    manifest: Dict[str, Any]
    library: str
    precision: str
    dtype: type
    name: str
    nq: int
    nv: int
    nu: int
    nlambda: int
    floating_base: bool
    joint_names: List[str]
    frames: List[str]
    contacts: List[Tuple[str, str]]
    gravity: Tuple[float, float, float]
    kernels: Tuple[str, ...]
    threads: int
    def rnea(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike, *, out: Optional[Array] = None) -> Array:
        """Inverse dynamics: tau = M(q) qdd + C(q, qd) qd + g(q); (B, nv)."""
    def rnea_grad(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike, *, out: Optional[Sequence[Array]] = None) -> Tuple[Array, Array]:
        """(dtau_dq, dtau_dqd), each (B, nv, nv), [i][j] = d tau_i / d u_j."""
    def mass_matrix(self, q: ArrayLike, *, out: Optional[Array] = None) -> Array:
        """M(q), (B, nv, nv)."""
    def minv(self, q: ArrayLike, *, out: Optional[Array] = None) -> Array:
        """M(q)^-1, (B, nv, nv)."""
    def fd(self, q: ArrayLike, qd: ArrayLike, tau: ArrayLike, *, out: Optional[Array] = None) -> Array:
        """Forward dynamics qdd, (B, nv)."""
    def fd_grad(self, q: ArrayLike, qd: ArrayLike, tau: ArrayLike, *, out: Optional[Sequence[Array]] = None) -> Tuple[Array, Array, Array]:
        """(qdd, dqdd_dq, dqdd_dqd): (B, nv), (B, nv, nv), (B, nv, nv)."""
    def integrate(self, q: ArrayLike, v: ArrayLike, *, out: Optional[Array] = None) -> Array:
        """q (+) v on the configuration manifold (Pinocchio's integrate), (B, nq)."""
    def dintegrate(self, q: ArrayLike, v: ArrayLike, *, out: Optional[Sequence[Array]] = None) -> Tuple[Array, Array]:
        """(dq, dv): integrate's Jacobians in the tangent space (dIntegrate ARG0, ARG1), each (B, nv, nv)."""
    def difference(self, q: ArrayLike, q1: ArrayLike, *, out: Optional[Array] = None) -> Array:
        """The tangent v with q (+) v = q1 (Pinocchio's difference(q0=q, q1)), (B, nv)."""
    def ddifference(self, q: ArrayLike, q1: ArrayLike, *, out: Optional[Sequence[Array]] = None) -> Tuple[Array, Array]:
        """(dq, dq1): difference's Jacobians in the tangent space (dDifference ARG0, ARG1), each (B, nv, nv)."""
    def __getattr__(self, kernel: str) -> Kernel:
        """The frame, force, contact and step kernels the robot was generated with."""
