"""The versions a measured figure or a bug report depends on: gflow, Python, the libraries, the OS.

``gflow --version`` prints them, ``gflow benchmark`` writes them beside its tables, so a figure
in the docs says what it ran on, and a recording keeps them (:mod:`pipeline.runtime.run_metadata`).
Looked up only when asked: reading the installed packages' metadata and importing OpenCV cost tens
of milliseconds at every start of ``gflow``.
"""

from __future__ import annotations

import platform
import sys

from pipeline.runtime.instruction_sets import described

__all__ = ["versions", "version_text"]

#: distribution names of the Python packages that decide the figures, in the order printed
PACKAGES = (("numpy", "numpy"), ("opencv", None), ("scipy", "scipy"), ("zenoh", "eclipse-zenoh"), ("mcap", "mcap"),
            ("msgspec", "msgspec"))


def _dist(name: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


def _opencv() -> str:
    """The version of the cv2 that is imported (a contrib build may shadow the project's), and its build."""
    try:
        import cv2
    except ImportError:
        return "not installed"
    contrib = hasattr(cv2, "TrackerCSRT") or hasattr(getattr(cv2, "legacy", None), "TrackerCSRT_create")
    return f"{cv2.__version__}{' contrib' if contrib else ''}"


def versions() -> dict[str, str]:
    """``{"gflow": ..., "python": ..., "numpy": ..., "opencv": ..., "scipy": ..., "zenoh": ..., "mcap": ...,
    "msgspec": ..., "os": ..., "simd": ...}``: ``simd`` says whether the libraries' SIMD kernels are held to
    x86-64-v3 (:mod:`pipeline.runtime.instruction_sets`), which decides their last bits as much as their versions."""
    out = {"gflow": _dist("gflow"), "python": ".".join(map(str, sys.version_info[:3]))}
    for key, dist in PACKAGES:
        out[key] = _opencv() if dist is None else _dist(dist)
    out["os"] = f"{platform.system()} {platform.release()} {platform.machine()}"
    out["simd"] = described()
    return out


def version_text(v: dict[str, str] | None = None) -> str:
    """``gflow 0.1.0 (python 3.11.7, numpy 2.4.6, opencv 5.0.0, ...; Linux 6.8 x86_64; SIMD held to x86-64-v3)``:
    one line (versions written before ``simd`` was recorded end at the system)."""
    v = versions() if v is None else v
    libs = ", ".join(f"{k} {v[k]}" for k in ["python", *(key for key, _ in PACKAGES)])
    simd = f"; {v['simd']}" if v.get("simd") else ""
    return f"gflow {v['gflow']} ({libs}; {v['os']}{simd})"
