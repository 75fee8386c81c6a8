"""A loaded robot: its kernels as methods over NumPy batches, through the library's C ABI."""

from __future__ import annotations

import collections
import ctypes
import json
import math
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native

Array = np.ndarray


def _field(output: str) -> str:
    """A result's field name from its output's: `lambda` is a Python keyword, so λ and its
    derivatives are `lam`, `dlam_dq`, ...; the step's `a`, `b` are `A`, `B`, as the docs
    write them."""
    return {"a": "A", "b": "B"}.get(output, output.replace("lambda", "lam"))


def _pointers(base: int, item: int, n: int, sizes: Sequence[int]) -> List[int]:
    """The addresses of arrays of n states each, `sizes` scalars per state, laid one after
    another from `base`."""
    out = []
    for size in sizes:
        out.append(base)
        base += n * size * item
    return out


class Kernel:
    """One generated kernel, called on one state (1-D arrays) or a batch (axis 0).

    Arguments are the kernel's inputs in order (or by name); `out=` takes arrays to write
    the results into (one array, or a tuple for several outputs), each of the exact shape
    and dtype, C-contiguous and sharing no memory with the inputs. The batch runs on every
    core with the GIL released (ctypes releases it for the call).
    """

    def __init__(self, robot: "Robot", spec: Dict[str, Any]):
        self._robot = robot
        self.name: str = spec["name"]
        self.inputs: Tuple[Tuple[str, int], ...] = tuple((i["name"], int(i["len"])) for i in spec["inputs"])
        self.outputs: Tuple[Tuple[str, Tuple[int, ...]], ...] = tuple((o["name"], tuple(int(d) for d in o["dims"])) for o in spec["outputs"])
        fn = getattr(robot._lib, f"{robot._prefix}_{self.name}_batch_{robot.precision}")
        fn.argtypes = [ctypes.c_size_t] + [ctypes.c_void_p] * (len(self.inputs) + len(self.outputs))
        fn.restype = ctypes.c_int32
        self._fn = fn
        # Per-state sizes, fixed for the robot: the call multiplies them by the batch.
        self._in_sizes = tuple(length for _, length in self.inputs)
        self._out_sizes = tuple(math.prod(dims) for _, dims in self.outputs)
        # The fast path: arrays of the kernel's dtype, C-contiguous, finite, shapes right,
        # no out=: checked and called in native code (a few microseconds less per call than
        # the path below, which handles everything else and names what is wrong).
        # The batch entry point's address, also what grid_gen.jax's FFI call is given.
        self._address: int = ctypes.cast(fn, ctypes.c_void_p).value
        # Where each input sits in the argument list.
        self._at: Dict[str, int] = {n: k for k, (n, _) in enumerate(self.inputs)}
        # Python's argument order: the inputs every call gives, in the kernel's order, then
        # those with a default (the mask, Baumgarte's gains and references), so that
        # `step(q, qd, tau, dt)` reads the same with or without them.
        optional = ("active", "gains", "contact_ref")
        self.arguments: Tuple[str, ...] = tuple(n for n, _ in self.inputs if n not in optional) + tuple(n for n, _ in self.inputs if n in optional)
        # Contact mask and Baumgarte gains: checked and shaped on the Python path.
        self._masked = "active" in self._at or "gains" in self._at
        # contact_ref's width per contact as given (7 where a contact is a wrench), and the
        # columns of its flattened (nc * width) rows that the kernel reads.
        kinds = [kind for _, kind in robot.contacts]
        self._ref_width = 7 if "wrench" in kinds else 3
        self._ref_columns = np.array([c * self._ref_width + i for c, kind in enumerate(kinds) for i in range(7 if kind == "wrench" else 3)], dtype=np.intp)
        # Several outputs come back as a named tuple (`qdd, lam = r` or `r.lam`).
        self._result = collections.namedtuple(f"{self.name}_result", [_field(n) for n, _ in self.outputs]) if len(self.outputs) > 1 else None
        # Where the configurations' unit quaternions start: q's (every kernel's first input)
        # and difference's q1.
        self._quats = list(robot._quaternions)
        self._configs = [k for k, (n, _) in enumerate(self.inputs) if n in ("q", "q1")]
        self._fast = _native.Caller(self._address, robot.precision == "f64", list(self._in_sizes), [list(d) for _, d in self.outputs], [at for _, at in self._quats], self._configs)
        args = ", ".join(self.arguments)
        outs = ", ".join(n for n, _ in self.outputs)
        shapes = "; ".join(f"{n}: (B, {l})" for n, l in self.inputs)
        out_shapes = "; ".join(f"{n}: (B, {', '.join(map(str, d))})" for n, d in self.outputs)
        self.__doc__ = f"{self.name}({args}) -> {outs}\n\n{spec['doc']}\n\nIn: {shapes}.\nOut: {out_shapes}.\nA 1-D input is one state (no batch axis in the outputs)."

    def __repr__(self) -> str:
        return f"<grid_gen kernel {self.name} of {self._robot.name}>"

    def _mask(self, a: Array, batch: Optional[int], nc: int) -> Array:
        """The contact mask as the kernel reads it, 1.0 or 0.0 per contact, (nc,) or (B, nc):
        from one bool for every contact, (nc,) for every state, or (B, nc); bools, or numbers
        that are exactly 0 or 1."""
        name = self.name
        if a.dtype.kind not in "biuf":
            raise ValueError(f"{name}: `active` has dtype {a.dtype}; expected bools (True where a contact holds)")
        if a.dtype.kind != "b" and not np.isin(a, (0, 1)).all():
            bad = a.ravel()[~np.isin(a.ravel(), (0, 1))][0]
            raise ValueError(f"{name}: `active` holds {float(bad)!r}; each entry is True/1 (the contact holds) or False/0 (it does not)")
        a = a.astype(np.float64)
        contacts = ", ".join(f for f, _ in self._robot.contacts)
        if a.ndim == 0:
            a = np.full((nc,) if batch is None else (batch, nc), a)
        elif a.ndim == 1 and a.shape == (nc,) and batch is not None:
            a = np.broadcast_to(a, (batch, nc))
        elif not ((a.ndim == 1 and batch is None and a.shape == (nc,)) or (a.ndim == 2 and a.shape == (batch, nc))):
            want = f"({nc},)" if batch is None else f"({nc},) or ({batch}, {nc})"
            raise ValueError(f"{name}: `active` has shape {a.shape}; expected {want}, one per contact ({contacts})")
        return a

    def _size_hint(self, arg: str, got: Optional[int]) -> str:
        """Why an input may have the wrong length: a state for the other kind of base, or the
        step's actuated τ mixed up with every coordinate's."""
        r = self._robot
        if got is None:
            return ""
        want = dict(self.inputs)[arg]
        if arg == "tau" and r.nu != r.nv:
            if got == r.nv and want == r.nu:
                return f"; {self.name} takes the {r.nu} actuated joints' forces (nu), not one per coordinate (nv = {r.nv}, as fd takes)"
            if got == r.nu and want == r.nv:
                return f"; {self.name} takes a force per coordinate (nv = {r.nv}, zero on unactuated ones), not the step's nu = {r.nu}"
        base = {"q": 7, "q1": 7, "qd": 6, "v": 6, "qdd": 6, "tau": 6}.get(arg)
        if base is not None and not r.floating_base and got == want + base:
            return f"; {got} entries is a floating base's: load the robot with floating_base=True"
        if base is not None and r.floating_base and got == want - base:
            return f"; this robot has a floating base, whose {arg} starts with the base's {base} entries" + (" [x, y, z, qx, qy, qz, qw]" if arg == "q" else "")
        return ""

    def _check_quaternions(self, q: Array, batch: Optional[int], arg: str = "q") -> None:
        """Each unit quaternion of the configuration `arg` has norm 1 within 1e-6 (a zero one
        included): the kernels read them as rotations without normalising."""
        for joint, at in self._quats:
            quat = np.asarray(q[..., at : at + 4], dtype=np.float64)
            norm = np.sqrt(np.sum(quat * quat, axis=-1))
            bad = np.argwhere(np.atleast_1d(np.abs(norm - 1.0) > 1e-6))
            if len(bad):
                i = int(bad[0][0])
                where = f" at state {i}" if batch is not None else ""
                value = float(np.atleast_1d(norm)[i])
                raise ValueError(
                    f"{self.name}: `{arg}`{where}: joint `{joint}`'s quaternion {arg}[{at}:{at + 4}] has norm {value:.9g}; "
                    "a rotation is a unit quaternion [qx, qy, qz, qw] (norm 1 within 1e-6; the identity is [0, 0, 0, 1])"
                )

    def _per_contact(self, arg: str, a: Array, batch: Optional[int], k: int, what: str) -> Array:
        """Baumgarte's `gains` (k = 2) or `contact_ref` (k = 3) as the kernel reads them,
        (nc * k,) or (B, nc * k): from a scalar (every entry), (nc, k) for every state or
        (B, nc, k); real and finite, gains non-negative."""
        name, nc = self.name, len(self._robot.contacts)
        if a.dtype.kind not in "fiu":
            raise ValueError(f"{name}: `{arg}` has dtype {a.dtype}; expected real numbers")
        if a.ndim == 0:
            a = np.full((nc, k), a, dtype=np.float64)
        if a.shape == (nc, k) and batch is not None:
            a = np.broadcast_to(a, (batch, nc, k))
        want = (nc, k) if batch is None else (batch, nc, k)
        if a.shape != want:
            alt = "" if batch is None else f" or ({nc}, {k}) for every state"
            contacts = ", ".join(f for f, _ in self._robot.contacts)
            raise ValueError(f"{name}: `{arg}` has shape {a.shape}; expected {want}{alt}: {what} per contact ({contacts})")
        if not np.isfinite(a).all():
            raise ValueError(f"{name}: `{arg}` holds a non-finite value")
        if arg == "gains" and (a < 0).any():
            raise ValueError(f"{name}: `gains` holds a negative gain; Kp and Kd are >= 0 (0: no correction)")
        return np.asarray(a, dtype=np.float64).reshape(want[:-2] + (nc * k,))

    def _references(self, a: Array, batch: Optional[int]) -> Array:
        """Baumgarte's `contact_ref` as the kernel reads it: 3 entries per point contact (a
        world position), 7 per wrench contact (a world placement, position and quaternion
        `[x, y, z, qx, qy, qz, qw]`). Given as (nc, 3) or (B, nc, 3) when every contact is a
        point, (nc, 7) or (B, nc, 7) when one is a wrench (a point's row reads its first
        three entries); a wrench's quaternion must have norm 1 within 1e-6."""
        width = self._ref_width
        what = "a world position [x, y, z]" if width == 3 else "a world position [x, y, z] for a point contact, a world placement [x, y, z, qx, qy, qz, qw] for a wrench contact"
        flat = self._per_contact("contact_ref", a, batch, width, what)
        if width == 3:
            return flat
        rows = flat.reshape(-1, len(self._robot.contacts), width)
        for c, (frame, kind) in enumerate(self._robot.contacts):
            if kind != "wrench":
                continue
            norm = np.linalg.norm(rows[:, c, 3:], axis=-1)
            bad = np.flatnonzero(np.abs(norm - 1.0) > 1e-6)
            if len(bad):
                state = "" if batch is None else f" of state {int(bad[0])}"
                raise ValueError(f"{self.name}: `contact_ref`{state}: the quaternion [qx, qy, qz, qw] of wrench contact `{frame}` has norm {norm[bad[0]]:.9g}, not 1 (within 1e-6)")
        return flat[..., self._ref_columns]

    def _time_steps(self, a: Array, batch: Optional[int]) -> Array:
        """A step's run-time `dt` as the kernel reads it, (1,) or (B, 1): from a scalar (every
        state's), a (B,) array (one per state) or (1,) for one state; each finite and
        positive."""
        name = self.name
        if a.dtype.kind not in "fiu":
            raise ValueError(f"{name}: `dt` has dtype {a.dtype}; expected seconds as real numbers")
        if a.ndim == 0:
            a = np.full((1,) if batch is None else (batch, 1), a, dtype=np.float64)
        elif a.ndim == 1 and batch is not None and a.shape[0] == batch:
            a = a.reshape(batch, 1)
        elif not (a.ndim == 1 and batch is None and a.shape == (1,)) and not (a.ndim == 2 and batch is not None and a.shape == (batch, 1)):
            want = "a scalar or (1,) for one state" if batch is None else f"a scalar or ({batch},), one per state"
            raise ValueError(f"{name}: `dt` has shape {a.shape}; expected {want}")
        bad = np.argwhere(~(np.isfinite(a) & (a > 0)))
        if len(bad):
            raise ValueError(f"{name}: `dt` is {a.ravel()[bad[0][0]]!r} at state {int(bad[0][0])}; a time step is a finite, positive number of seconds")
        return a

    def __call__(self, *args: Any, out: Union[None, Array, Sequence[Array]] = None, **kwargs: Any):
        name = self.name
        # A contact mask is checked (0 or 1 each) on the path below, never the fast one.
        if out is None and not kwargs and not self._masked:
            try:
                fast = self._fast(*args)
            except RuntimeError as e:
                raise RuntimeError(f"{name}: {e}") from None
            if fast is not None:
                return fast if self._result is None else self._result._make(fast)
        robot = self._robot
        dtype = robot.dtype
        if len(args) > len(self.inputs):
            raise TypeError(f"{name}() takes {len(self.inputs)} arguments ({', '.join(self.arguments)}), got {len(args)}")
        values = dict(zip(self.arguments, args))
        for k, v in kwargs.items():
            if k not in (n for n, _ in self.inputs):
                raise TypeError(f"{name}() has no argument {k!r}; its arguments: {', '.join(self.arguments)}")
            if k in values:
                raise TypeError(f"{name}() got {k!r} twice")
            values[k] = v
        if "active" in self._at and "active" not in values:
            # Every candidate contact holds unless said otherwise.
            values["active"] = True
        ref_given = "contact_ref" in values
        if "gains" in self._at:
            if "contact_ref" in values and "gains" not in values:
                raise TypeError(f"{name}() got `contact_ref` without `gains`: give both (Kp, Kd per contact, and each contact's reference)")
            # No gains: the rigid contact. A reference left out is the origin, and a
            # wrench's the identity rotation, whose logarithm is finite, so that Kp = 0 adds
            # nothing.
            values.setdefault("gains", 0.0)
            if "contact_ref" not in values:
                unset = np.zeros((len(self._robot.contacts), self._ref_width))
                unset[:, 6:] = 1.0
                values["contact_ref"] = unset
        batch: Optional[int] = None
        first: Optional[str] = None
        arrays: List[Array] = []
        for arg, length in self.inputs:
            if arg not in values:
                raise TypeError(f"{name}() is missing its argument {arg!r}")
            if arg in ("dt", "active", "gains", "contact_ref"):
                # A run-time time step (a scalar, or (B,)) and a contact mask (a bool, (nc,)
                # or (B, nc)), shaped below once the batch is known.
                arrays.append(np.asarray(values[arg]))
                continue
            a = np.asarray(values[arg])
            if a.dtype.kind not in "fiu":
                raise ValueError(f"{name}: `{arg}` has dtype {a.dtype}; expected real numbers (float64 or float32)")
            if a.ndim not in (1, 2) or a.shape[-1] != length:
                raise ValueError(f"{name}: `{arg}` has shape {a.shape}; expected ({length},) for one state or (B, {length}) for a batch{self._size_hint(arg, a.shape[-1] if a.ndim else None)}")
            b = a.shape[0] if a.ndim == 2 else None
            if first is None:
                batch, first = b, arg
            elif b != batch:
                want = f"(B, {length}) with B = {batch} as `{first}`" if batch is not None else f"({length},) as `{first}`"
                raise ValueError(f"{name}: `{arg}` has shape {a.shape}; expected {want}")
            arrays.append(a)
        n = 1 if batch is None else batch
        if self._quats:
            for k in self._configs:
                self._check_quaternions(arrays[k], batch, self.inputs[k][0])
        if "dt" in self._at:
            at = self._at["dt"]
            arrays[at] = self._time_steps(arrays[at], batch)
        if "active" in self._at:
            at = self._at["active"]
            arrays[at] = self._mask(arrays[at], batch, self.inputs[at][1])
        if "gains" in self._at:
            at, ref_at = self._at["gains"], self._at["contact_ref"]
            arrays[at] = self._per_contact("gains", arrays[at], batch, 2, "[Kp, Kd]")
            arrays[ref_at] = self._references(arrays[ref_at], batch)
            kp = arrays[at].reshape(n, -1, 2)[:, :, 0]
            if not ref_given and (kp != 0).any():
                raise ValueError(f"{name}: `gains` has a nonzero Kp and no `contact_ref`: Kp pulls each contact towards its reference position; give contact_ref=")
        # The inputs, copied into one buffer in the kernel's scalar, input after input (the
        # C ABI's layout): one finiteness check and one pointer instead of one per input,
        # which is most of a small call's cost.
        packed = np.concatenate([a.ravel() for a in arrays], dtype=dtype) if len(arrays) > 1 else np.ascontiguousarray(arrays[0], dtype=dtype).ravel()
        if not np.isfinite(packed).all():
            for (arg, _), a in zip(self.inputs, arrays):
                bad = np.argwhere(~np.isfinite(np.asarray(a, dtype=dtype)))
                if len(bad):
                    where = tuple(int(i) for i in bad[0])
                    raise ValueError(f"{name}: `{arg}` holds a non-finite value at index {where if len(where) > 1 else where[0]}")
        item = packed.itemsize
        in_ptrs = _pointers(packed.ctypes.data, item, n, self._in_sizes)
        lead = () if batch is None else (batch,)
        if out is None:
            # One allocation for every output, viewed per output.
            block = np.empty(n * sum(self._out_sizes), dtype=dtype)
            outs = []
            start = 0
            for (_, dims), size in zip(self.outputs, self._out_sizes):
                outs.append(block[start : start + n * size].reshape(lead + dims))
                start += n * size
            out_ptrs = _pointers(block.ctypes.data, item, n, self._out_sizes)
        else:
            given = [out] if isinstance(out, np.ndarray) else list(out)
            if len(given) != len(self.outputs):
                raise ValueError(f"{name}: out= needs {len(self.outputs)} arrays ({', '.join(n for n, _ in self.outputs)}), got {len(given)}")
            outs = []
            for (oname, dims), o in zip(self.outputs, given):
                want = lead + dims
                if not isinstance(o, np.ndarray) or o.dtype != dtype or o.shape != want:
                    what = f"{o.dtype} {o.shape}" if isinstance(o, np.ndarray) else type(o).__name__
                    raise ValueError(f"{name}: out `{oname}` is {what}; expected a {np.dtype(dtype)} array of shape {want}")
                if not o.flags.c_contiguous or not o.flags.writeable:
                    raise ValueError(f"{name}: out `{oname}` must be C-contiguous and writeable")
                if any(np.may_share_memory(o, x) for x in arrays + outs):
                    raise ValueError(f"{name}: out `{oname}` shares memory with another argument; pass separate arrays")
                outs.append(o)
            out_ptrs = [o.ctypes.data for o in outs]
        status = self._fn(n, *in_ptrs, *out_ptrs)
        if status == 3:
            # GRID_GEN_BAD_VALUE: the library's own check (the checks above come first).
            raise ValueError(f"{name}: `q` or `q1` at state {robot._bad_state()} holds a quaternion whose norm is off 1 by more than 1e-6 (the kernel library's check)" if "q1" in self._at else f"{name}: `q` at state {robot._bad_state()} holds a quaternion whose norm is off 1 by more than 1e-6 (the kernel library's check)")
        if status != 0:
            raise RuntimeError(f"{name}: the kernel library returned status {status}")
        return outs[0] if self._result is None else self._result._make(outs)


class Robot:
    """A robot's compiled kernels (from `grid_gen.load`). Each kernel is a method named like
    it (`rnea`, `rnea_grad`, `mass_matrix`, `minv`, `fd`, `fd_grad`, and the frame, force,
    contact and step kernels the robot was generated with); `kernels` lists them."""

    def __init__(self, library: str, prefix: str, precision: str):
        self._lib = ctypes.CDLL(library)
        self._prefix = prefix
        manifest_fn = getattr(self._lib, f"{prefix}_manifest")
        manifest_fn.restype = ctypes.c_char_p
        manifest_fn.argtypes = []
        m = json.loads(manifest_fn().decode())
        self.manifest: Dict[str, Any] = m
        self.library = library
        self.precision = precision
        self.dtype = np.float64 if precision == "f64" else np.float32
        self.name: str = m["robot"]
        self.nq: int = m["nq"]
        self.nv: int = m["nv"]
        self.nu: int = m["nu"]
        self.nlambda: int = m["nlambda"]
        self.floating_base: bool = m["floating_base"]
        self.joint_names: List[str] = list(m["joint_names"])
        self.frames: List[str] = list(m["frames"])
        self.contacts: List[Tuple[str, str]] = [tuple(c) for c in m["contacts"]]
        self._quaternions: List[Tuple[str, int]] = [(x["joint"], int(x["q"])) for x in m.get("quaternions", [])]
        self.gravity: Tuple[float, float, float] = tuple(m["gravity"])
        self.kernels: Tuple[str, ...] = tuple(k["name"] for k in m["kernels"])
        for spec in m["kernels"]:
            setattr(self, spec["name"], Kernel(self, spec))
        self._set_threads = getattr(self._lib, f"{prefix}_set_threads")
        self._set_threads.argtypes = [ctypes.c_size_t]
        self._set_threads.restype = None
        self._bad_state = getattr(self._lib, f"{prefix}_bad_state")
        self._bad_state.argtypes = []
        self._bad_state.restype = ctypes.c_int64
        self._threads = getattr(self._lib, f"{prefix}_threads")
        self._threads.argtypes = []
        self._threads.restype = ctypes.c_size_t

    def __getattr__(self, name: str):
        # Only for names that are not attributes: a kernel this robot was built without.
        adds = {
            "step": 'step="semi_implicit_euler" (and dt=, or dt at run time)',
            "step_grad": 'step="semi_implicit_euler" (and dt=, or dt at run time)',
            "contact_fd": 'contacts={"link": "point" | "wrench"}',
            "contact_fd_grad": 'contacts={"link": "point" | "wrench"}',
        }
        frame = ("frame_placement", "frame_jacobian", "frame_velocity", "frame_acceleration", "frame_acceleration_grad")
        adds.update({k: 'frames=["link", ...]' for k in frame})
        known = ("rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad") + tuple(adds)
        if name in known and "kernels" in self.__dict__:
            how = f"load it with {adds[name]}" if name in adds else "it was left out by load(kernels=...)"
            raise AttributeError(f"robot {self.name} has no kernel `{name}`: {how}; its kernels: {', '.join(self.kernels)}")
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def threads(self) -> int:
        """Threads a batch runs on (every core unless set); set 1 to stay on the caller's
        thread, 0 to go back to every core. Shared by every Robot of this library."""
        return int(self._threads())

    @threads.setter
    def threads(self, n: int) -> None:
        if not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"threads must be a non-negative integer, not {n!r}")
        self._set_threads(int(n))

    def __repr__(self) -> str:
        return f"<grid_gen robot {self.name}: nq {self.nq}, nv {self.nv}, {self.precision}, kernels {', '.join(self.kernels)}>"
