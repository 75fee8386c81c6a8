"""From a URDF to a loaded robot library: generate, compile with cargo, cache by content."""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

from . import _native
from ._robot import Robot

_PRECISIONS = ("f64", "f32")
_BATCH_LANES = ("auto", "all", "none")
_CALLS = ("auto", "all", "rnea_grad")


def cache_dir() -> Path:
    """Where compiled robots are kept: $GRID_GEN_CACHE, else $XDG_CACHE_HOME/grid-gen,
    else ~/.cache/grid-gen. Deleting it is always safe."""
    if os.environ.get("GRID_GEN_CACHE"):
        return Path(os.environ["GRID_GEN_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "grid-gen"


_build_id: Optional[str] = None


def _generator_id() -> str:
    """A hash of this package's native generator, so that a new grid-gen never reuses a
    library an older one compiled (the version number alone does not change with every
    fix)."""
    global _build_id
    if _build_id is None:
        h = hashlib.sha256(_native.version().encode())
        with open(_native.__file__, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        _build_id = h.hexdigest()
    return _build_id


def _cargo() -> str:
    """The cargo to build with, or a RuntimeError that says what to install."""
    for candidate in (os.environ.get("CARGO"), shutil.which("cargo"), os.path.expanduser("~/.cargo/bin/cargo")):
        if candidate and os.path.isfile(candidate) and os.access(candidate, os.X_OK):
            return candidate
    raise RuntimeError(
        "grid_gen.load compiles each robot once with Rust's cargo, which is not on PATH (nor $CARGO, "
        "nor ~/.cargo/bin). Install Rust with `curl https://sh.rustup.rs -sSf | sh` (https://rustup.rs), "
        f"then load again; compiled robots are cached in {cache_dir()}."
    )


def _write_if_changed(path: Path, text: str) -> None:
    if not path.exists() or path.read_text() != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def _runtime_crate(cache: Path) -> Path:
    """The grid-gen-runtime crate, written from the source this package carries."""
    root = cache / "runtime"
    _write_if_changed(
        root / "Cargo.toml",
        '[package]\nname = "grid-gen-runtime"\nversion = "0.1.0"\nedition = "2021"\n\n[dependencies]\nrayon = "1"\n',
    )
    _write_if_changed(root / "src" / "lib.rs", _native.runtime_source())
    return root


def load(
    urdf: str | os.PathLike,
    floating_base: bool = False,
    scene: Optional[str | os.PathLike] = None,
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
) -> Robot:
    """Loads a robot's kernels, compiling them on the first load.

    urdf: the robot description. floating_base: put a free-flyer under the root link
    (Pinocchio's JointModelFreeFlyer; q = [x, y, z, qx, qy, qz, qw, joints]). scene: a
    grid-gen scene file (TOML: locked joints, payloads, contacts, step, ...). frames: link
    names for the frame kernels. precision: "f64" or "f32", the scalar of every array the
    kernels read and write. kernels: which kernels to compile (default all the robot has;
    fewer compile faster). verbose: say on stderr when a robot is being compiled.

    The scene's settings as keywords, each the scene key of the same name (a keyword and a
    scene file that both set a thing is a ValueError naming both):
    contacts: rigid contacts at links, `{"FL_foot": "point", ...}` or a list of
    `(link, "point" | "wrench")` pairs; adds `contact_fd`, `contact_fd_grad`, and makes the
    step hold them. step: a scheme, "semi_implicit_euler", "explicit_euler" or "rk4"; adds
    `step` and `step_grad`. dt: the step's seconds, folded into the kernels; None (the
    default) leaves it to run time (`step(q, qd, tau, dt)`). actuated: the joints with a
    motor (the step's tau). external_forces: the joints whose bodies take `fext`.
    contact_mask: the contacts are candidates, chosen per state by `active=`. baumgarte:
    the contacts are stabilised as Pinocchio's Baumgarte corrector, the contact kernels
    and the step taking `gains=` ([Kp, Kd] per contact) and `contact_ref=` (each contact's
    reference in the world: a point's position, a wrench's [x, y, z, qx, qy, qz, qw]).
    gravity: (x, y, z) in m/s^2. round_angles: a tolerance in rad; `<origin rpy>` angles
    within it of a multiple of pi/2 are read as that multiple (axis-aligned joints cost
    fewer operations).

    batch_lanes: which kernels' batches evaluate four f64 (eight f32) states per call in
    SIMD lanes where the CPU has AVX2 and FMA: "auto" (where lanes were measured to pay:
    kernels of at most 150,000 operations and 6 per output entry), "all" or "none". Each
    kernel with lanes is compiled twice: "none" halves a humanoid's compile time, and its
    mid-sized kernels' batches run 1.4x to 3x slower per state (the book, Compile time).
    calls: which kernels call other kernels of the library instead of holding their work:
    "auto" (where it costs no speed: the step calls its contact kernel; and where the
    library holds a contact_fd_grad of 150,000 operations or more, a humanoid on its feet,
    what "rnea_grad" does, so that it loads in 30 s or so), "rnea_grad" (also
    fd_grad and contact_fd_grad call rnea_grad at their own q-ddot where they factorise M,
    and read the transforms it computes first: a floating humanoid loads in 0.57x to 0.81x
    the time, fd_grad up to 1.06x slower, contact_fd_grad and step_grad up to 1.02x) or
    "all" (they call fd or contact_fd for q-ddot too: less still to compile, fd_grad 1.13x
    and the contact gradients 1.1x slower; the book, Compile time).

    A compiled robot is cached (see `cache_dir`) under a hash of the URDF, the scene, the
    options and this grid-gen, and loads again in milliseconds. Raises ValueError for a
    robot grid-gen cannot use (with the URDF's line and what is wrong), FileNotFoundError
    for a missing file, RuntimeError when cargo is missing or the build fails.
    """
    if precision not in _PRECISIONS:
        raise ValueError(f"precision must be one of {_PRECISIONS}, not {precision!r}")
    if batch_lanes not in _BATCH_LANES:
        raise ValueError(f"batch_lanes must be one of {_BATCH_LANES}, not {batch_lanes!r}")
    if calls not in _CALLS:
        raise ValueError(f"calls must be one of {_CALLS}, not {calls!r}")
    urdf_path = Path(urdf)
    if not urdf_path.is_file():
        raise FileNotFoundError(f"no URDF at {urdf_path}")
    scene_path = Path(scene) if scene is not None else None
    if scene_path is not None and not scene_path.is_file():
        raise FileNotFoundError(f"no scene file at {scene_path}")
    frames = list(frames) if frames is not None else None
    kernels = list(kernels) if kernels is not None else None
    for what, names in (("frames", frames), ("kernels", kernels)):
        if names is not None and not all(isinstance(n, str) for n in names):
            raise ValueError(f"{what} must be a list of strings")
    keywords = _scene_keywords(contacts, step, dt, actuated, external_forces, contact_mask, baumgarte, gravity, round_angles)

    key_source = {
        "generator": _generator_id(),
        "urdf": hashlib.sha256(urdf_path.read_bytes()).hexdigest(),
        "scene": hashlib.sha256(scene_path.read_bytes()).hexdigest() if scene_path else None,
        "floating_base": bool(floating_base),
        "frames": frames,
        "kernels": kernels,
        "precision": precision,
        "keywords": keywords,
        "batch_lanes": batch_lanes,
        "calls": calls,
        # The one copy of the kernels compiled (this CPU's): a shared cache never hands a
        # machine a library built for features it lacks.
        "copies": _native.host_copies(),
    }
    key = hashlib.sha256(json.dumps(key_source, sort_keys=True).encode()).hexdigest()[:24]
    cache = cache_dir()
    lib = cache / "robots" / key / _library_name("robot")
    if not lib.exists():
        _compile(cache, key, lib, urdf_path, scene_path, floating_base, frames, kernels, precision, verbose, keywords, batch_lanes, calls)
    prefix = json.loads((lib.parent / "source.json").read_text())["prefix"]
    return Robot(str(lib), prefix, precision)


def _scene_keywords(contacts, step, dt, actuated, external_forces, contact_mask, baumgarte, gravity, round_angles=None) -> Dict[str, Any]:
    """load's scene keywords, checked for their Python types and put as the native generator
    takes them (every key present; None where not given)."""

    def names(what: str, value) -> Optional[list]:
        if value is None:
            return None
        if isinstance(value, str) or not all(isinstance(n, str) for n in value):
            raise ValueError(f"load({what}=...) takes a list of joint names, not {value!r}")
        return list(value)

    pairs = None
    if contacts is not None:
        items = list(contacts.items()) if isinstance(contacts, Mapping) else list(contacts)
        if not all(isinstance(p, (tuple, list)) and len(p) == 2 and all(isinstance(x, str) for x in p) for p in items):
            raise ValueError(f"load(contacts=...) takes {{link: \"point\" | \"wrench\"}} or a list of (link, type) pairs, not {contacts!r}")
        pairs = [(str(f), str(k)) for f, k in items]
    if step is not None and not isinstance(step, str):
        raise ValueError(f"load(step=...) takes a scheme's name (\"semi_implicit_euler\", \"explicit_euler\", \"rk4\"), not {step!r}")
    if dt is not None:
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt <= 0:
            raise ValueError(f"load(dt={dt!r}): a time step is a finite, positive number of seconds (or None: given at run time)")
        dt = float(dt)
    for what, flag in (("contact_mask", contact_mask), ("baumgarte", baumgarte)):
        if flag is not None and not isinstance(flag, bool):
            raise ValueError(f"load({what}=...) takes True or False, not {flag!r}")
    if gravity is not None:
        g = [float(x) for x in gravity] if not isinstance(gravity, str) else []
        if len(g) != 3 or not all(math.isfinite(x) for x in g):
            raise ValueError(f"load(gravity=...) takes three finite numbers (m/s^2), not {gravity!r}")
        gravity = g
    if round_angles is not None:
        if isinstance(round_angles, bool) or not isinstance(round_angles, (int, float)) or not math.isfinite(round_angles):
            raise ValueError(f"load(round_angles=...) takes a tolerance in rad, not {round_angles!r}")
        round_angles = float(round_angles)
    return {
        "contacts": pairs,
        "step": step,
        "dt": dt,
        "actuated": names("actuated", actuated),
        "external_forces": names("external_forces", external_forces),
        "contact_mask": contact_mask,
        "baumgarte": baumgarte,
        "gravity": gravity,
        "round_angles": round_angles,
    }


def _library_name(stem: str) -> str:
    if sys.platform == "darwin":
        return f"lib{stem}.dylib"
    if sys.platform == "win32":
        return f"{stem}.dll"
    return f"lib{stem}.so"


# The kernels' weight (statements compiled, `<robot>_features.json`) from which a robot's
# library compiles as one crate per core. On this project's 2-core machine two crates
# loaded the humanoid (499,493) in 0.80x to 0.82x the time of one (three alternated pairs);
# iiwa (26,830) and the quadruped's gait library (84,012) within the machine's spread (2.5
# against 3.0 s; 0.67x and 1.06x); the book, Compile time. A smaller module (a few joints)
# stays one crate, where a second crate's fixed cost (parsing the module again, linking)
# would be most of the build.
SPLIT_MIN_WEIGHT = 20_000
# Most crates: past four, each crate's share of rustc's front end is small.
SPLIT_MAX_CRATES = 4


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _crate_groups(features) -> List[List[str]]:
    """The kernels' features per crate: one crate for a small robot or a one-core machine,
    else up to one per core ($GRID_GEN_CRATES, if set, instead of the cores: 1 builds one
    crate, as before 2026-11-30), each kernel with the kernels it calls (they must share a
    crate), the heaviest first into the lightest crate. The first crate also takes the
    shared entry points (`common`)."""
    kernels = features["kernels"]
    names = [k["name"] for k in kernels]
    weight = {k["name"]: k["weight"] for k in kernels}
    parent = {n: n for n in names}

    def root(n):
        while parent[n] != n:
            n = parent[n]
        return n

    for k in kernels:
        for callee in k["calls"]:
            if callee in parent:
                parent[root(callee)] = root(k["name"])
    parts: Dict[str, List[str]] = {}
    for n in names:
        parts.setdefault(root(n), []).append(n)
    most = os.environ.get("GRID_GEN_CRATES", "")
    if most and not (most.isdigit() and int(most) >= 1):
        raise ValueError(f"GRID_GEN_CRATES={most!r}: the most crates a load compiles at once is a whole number, 1 or more")
    count = min(int(most) if most else min(_cores(), SPLIT_MAX_CRATES), len(parts))
    if sum(weight.values()) < SPLIT_MIN_WEIGHT or count < 2:
        return [names + [features["common"]]]
    groups: List[List[str]] = [[] for _ in range(count)]
    loads = [0] * count
    for part in sorted(parts.values(), key=lambda p: (-sum(weight[n] for n in p), p[0])):
        i = loads.index(min(loads))
        groups[i].extend(part)
        loads[i] += sum(weight[n] for n in part)
    groups[0].append(features["common"])
    return [g for g in groups if g]


def _compile(cache, key, lib, urdf_path, scene_path, floating_base, frames, kernels, precision, verbose, keywords, batch_lanes, calls) -> None:
    cargo = _cargo()
    crate = cache / "build" / key
    try:
        _build(cache, crate, lib, cargo, urdf_path, scene_path, floating_base, frames, kernels, precision, verbose, keywords, batch_lanes, calls)
    except BaseException:
        # A failed load leaves nothing behind: the next load starts afresh, and the cache
        # holds only robots that load.
        shutil.rmtree(crate, ignore_errors=True)
        shutil.rmtree(lib.parent, ignore_errors=True)
        raise


def _build(cache, crate, lib, cargo, urdf_path, scene_path, floating_base, frames, kernels, precision, verbose, keywords, batch_lanes, calls) -> None:
    src = crate / "src"
    # The generator's errors (a bad URDF, an unknown frame) come before any compiling, and
    # before anything is written.
    with tempfile.TemporaryDirectory() as scratch:
        files = _native.generate(
            str(urdf_path),
            scratch,
            floating_base=bool(floating_base),
            scene=str(scene_path) if scene_path else None,
            frames=frames,
            kernels=kernels,
            precision=precision,
            keywords=keywords,
            batch_lanes=batch_lanes,
            calls=calls,
            kernel_features=True,
        )
        src.mkdir(parents=True, exist_ok=True)
        for f in files:
            _write_if_changed(src / f, (Path(scratch) / f).read_text())
    module = next(f for f in files if f.endswith(".rs") and not f.endswith("_c.rs"))
    stem = module[: -len(".rs")]
    features = json.loads((src / f"{stem}_features.json").read_text())
    groups = _crate_groups(features)
    runtime = _runtime_crate(cache)
    name = f"grid_gen_robot_{crate.name}"
    # Every kernel's items sit behind a Cargo feature of its name (the shared entry points
    # behind `common`); each crate that compiles the module declares them all.
    declared = "".join(
        f"{k['name']} = {json.dumps(k['calls'])}\n" for k in features["kernels"]
    ) + f"{features['common']} = []\n"
    runtime_dep = f'[dependencies]\ngrid-gen-runtime = {{ path = {json.dumps(str(runtime))} }}\n\n'
    profile = "[profile.release]\npanic = \"abort\"\n\n"
    if len(groups) == 1:
        _write_if_changed(
            src / "lib.rs",
            f'mod {stem} {{\n    include!("{stem}.rs");\n}}\ninclude!("{stem}_c.rs");\n',
        )
        _write_if_changed(
            crate / "Cargo.toml",
            f'[package]\nname = "{name}"\nversion = "0.1.0"\nedition = "2021"\n\n[lib]\ncrate-type = ["cdylib"]\n\n'
            f"[features]\ndefault = {json.dumps(groups[0])}\n{declared}\n{runtime_dep}{profile}[workspace]\n",
        )
    else:
        # rustc's front end (parsing, type and borrow checking: a third of a humanoid's
        # compile) runs on one thread per crate, so a large robot's kernels compile as
        # several crates at once, one per core, which the library links (their
        # `#[no_mangle]` entry points are its exports). The book, Compile time.
        members = [f"k{i}" for i in range(len(groups))]
        for member, group in zip(members, groups):
            _write_if_changed(
                crate / member / "src" / "lib.rs",
                f'mod {stem} {{\n    include!("../../src/{stem}.rs");\n}}\ninclude!("../../src/{stem}_c.rs");\n',
            )
            _write_if_changed(
                crate / member / "Cargo.toml",
                f'[package]\nname = "{name}_{member}"\nversion = "0.1.0"\nedition = "2021"\n\n'
                f"[features]\ndefault = {json.dumps(group)}\n{declared}\n{runtime_dep}",
            )
        _write_if_changed(src / "lib.rs", "".join(f"extern crate {name}_{m};\n" for m in members))
        deps = "".join(f'{name}_{m} = {{ path = "{m}" }}\n' for m in members)
        _write_if_changed(
            crate / "Cargo.toml",
            f'[package]\nname = "{name}"\nversion = "0.1.0"\nedition = "2021"\n\n[lib]\ncrate-type = ["cdylib"]\n\n'
            f"[dependencies]\n{deps}\n{profile}[workspace]\nmembers = {json.dumps(members)}\n",
        )
    if verbose:
        print(f"grid_gen: compiling {urdf_path.name} (first load of this robot; cached in {cache})", file=sys.stderr, flush=True)
    # Every robot's crate has the same dependencies: the first build's lock file serves the
    # others, so that cargo does not consult the registry again (and works offline).
    lock = cache / "Cargo.lock"
    if lock.exists() and not (crate / "Cargo.lock").exists():
        shutil.copyfile(lock, crate / "Cargo.lock")
    # One target folder for every robot, so that rayon and the runtime compile once.
    cmd = [cargo, "build", "--release", "--manifest-path", str(crate / "Cargo.toml"), "--target-dir", str(cache / "target")]
    if not verbose:
        cmd.append("--quiet")
    run = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=None if verbose else subprocess.PIPE, text=True)
    if run.returncode != 0:
        raise RuntimeError(f"cargo could not build {urdf_path.name}'s kernels (nothing was cached):\n{run.stderr or ''}{run.stdout}")
    if not lock.exists():
        shutil.copyfile(crate / "Cargo.lock", lock)
    built = cache / "target" / "release" / _library_name(name)
    lib.parent.mkdir(parents=True, exist_ok=True)
    # The C names' prefix (`<prefix>_fd_grad_f64`), and where the library came from.
    prefix = ("robot" + stem) if stem.startswith("_") else stem
    source = {"prefix": prefix, "urdf": str(urdf_path.resolve()), "scene": str(scene_path.resolve()) if scene_path else None}
    source.update(floating_base=bool(floating_base), frames=frames, kernels=kernels, precision=precision, keywords=keywords, batch_lanes=batch_lanes, calls=calls)
    (lib.parent / "source.json").write_text(json.dumps(source, indent=1))
    # Copy, then rename: a concurrent load sees the whole library or none.
    fd, tmp = tempfile.mkstemp(dir=lib.parent, suffix=".tmp")
    os.close(fd)
    shutil.copyfile(built, tmp)
    os.replace(tmp, lib)
