"""grid-gen's generator, compiled into the package (see grid_gen.load)."""

from typing import Any, Dict, List, Optional, Tuple

def generate(
    urdf: str,
    out_dir: str,
    floating_base: bool = False,
    scene: Optional[str] = None,
    frames: Optional[List[str]] = None,
    kernels: Optional[List[str]] = None,
    precision: str = "f64",
    keywords: Optional[Dict[str, Any]] = None,
    batch_lanes: str = "auto",
    calls: str = "auto",
    kernel_features: bool = False,
) -> List[str]:
    """Writes the robot's Rust module and C ABI into out_dir; returns the file names.
    Raises ValueError (with the URDF's diagnostics) or FileNotFoundError."""

def runtime_source() -> str:
    """The grid-gen-runtime crate's source, which each robot library links."""

def version() -> str:
    """grid-gen's version."""

def host_copies() -> str:
    """The one copy of the kernels generate compiles here: "fma" or "portable"."""

def settings() -> List[Tuple[str, str, str, str]]:
    """Each setting's load keyword, scene key, CLI flag and Builder method."""

class Caller:
    """One kernel's C batch entry point called on NumPy arrays in native code: the fast path
    of the kernel methods. Returns None where it does not apply (a dtype, contiguity, shape
    or non-finite value the Python path must convert or report)."""

    def __init__(self, addr: int, f64: bool, in_lens: List[int], out_dims: List[List[int]], quats: List[int] = ..., configs: List[int] = ...) -> None: ...
    def __call__(self, *args: object) -> object: ...
