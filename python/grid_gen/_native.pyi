"""grid-gen's generator, compiled into the package (see grid_gen.load)."""

from typing import List, Optional

def generate(
    urdf: str,
    out_dir: str,
    floating_base: bool = False,
    scene: Optional[str] = None,
    frames: Optional[List[str]] = None,
    kernels: Optional[List[str]] = None,
    precision: str = "f64",
) -> List[str]:
    """Writes the robot's Rust module and C ABI into out_dir; returns the file names.
    Raises ValueError (with the URDF's diagnostics) or FileNotFoundError."""

def runtime_source() -> str:
    """The grid-gen-runtime crate's source, which each robot library links."""

def version() -> str:
    """grid-gen's version."""
