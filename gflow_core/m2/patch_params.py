"""The parameters of M2 with a patch model (:class:`PatchParams`), the only place their defaults live.

The tracker is :mod:`gflow_core.m2.patch_protocol`; they are the m2 registration's parameters for a
patch model (a ``variant`` of its spec), named once in graph ``m2_patch``'s tracker block, whose
stage ``patch.filter`` is made of them; ``gflow track --tracker m2 --model PATCH.npz``'s options
(``--crop``, ``--blank-std``, and ``--particles`` read by name) and ``gflow info m2`` derive from
them, and the Python API's keywords are made into them
(:func:`gflow_core.m2.patch_protocol.patch_setup`).

This module imports no mathematics, so the command line reads it at no cost.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Mapping

from ..params import Memory, check_memory, param

__all__ = ["PatchParams", "crop_of", "CROPS"]

#: how the observed patch is cut from the frame
CROPS = ("frame", "box")


@dataclass(frozen=True)
class PatchParams:
    """The parameters of M2 with a patch model (the tracker's own; the model file gives ``crop``,
    :func:`gflow_core.m2.patch_protocol.patch_setup`)."""

    crop: Literal["frame", "box"] = param("frame", "how the observed patch is cut from the frame: frame (the whole "
                                                   "frame resized) or box (the initial box resampled)",
                                  option="--crop")
    # memory: the peak resident memory of `gflow track --tracker m2 --model M --inline --stop 4` with a whole-frame
    # shuffle model of 80x60 frames (as tests/test_m2_patch_cli.py learns it) grows by 443 bytes a particle
    # (--particles 5e5 to 1e6), 2026-12-05
    particles: int = param(500, "number of particles N", memory=Memory(440, "particle"))
    blank_std: float = param(1.0, "frames whose grey levels have a smaller standard deviation carry no evidence",
                             option="--blank-std")

    def __post_init__(self) -> None:
        if self.crop not in CROPS:
            raise ValueError(f"crop must be frame or box, got {self.crop!r}")
        if isinstance(self.particles, bool) or not isinstance(self.particles, int) or self.particles < 1:
            raise ValueError(f"particles must be an integer >= 1, got {self.particles!r}")
        if not self.blank_std >= 0:
            raise ValueError(f"blank_std must be >= 0, got {self.blank_std}")
        check_memory(self)


def crop_of(meta: Mapping[str, Any]) -> Literal["frame", "box"]:
    """How a patch model's training patches were cut, from its file's ``meta`` (``gflow learn m2
    --crop``): ``box`` or, by default, ``frame``; the tracker cuts the observed patch alike."""
    return "box" if meta.get("crop") == "box" else "frame"
