"""Variants of a sequence: every frame changed the same way, the truth untouched (pure functions).

A variant turns each frame of a sequence into the frame of another kind of footage with the same
target in the same place, so a benchmark can score the trackers on footage they were not tuned on
(``gflow benchmark DATA --variant NAME``; the files are written by
:mod:`pipeline.evaluation.variant_benchmark`).

* ``grey`` -- grey footage: every frame to its grey levels with OpenCV's BGR -> grey weights
  (``Y = 0.299 R + 0.587 G + 0.114 B``, rounded), one channel. A folder source decodes a
  one-channel image into three equal channels, which is how grey video in colour containers
  (the grey sequences of OTB, JPEG frames with three equal channels) reaches a tracker: the two
  are the same frames to every tracker.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

__all__ = ["Variant", "VARIANTS", "grey", "select_variant"]


def grey(image: np.ndarray) -> np.ndarray:
    """The grey levels of a frame: (H, W) uint8 of (H, W, 3) BGR uint8 (or of (H, W), returned as is)."""
    if image.ndim == 2:
        return image
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"a frame is (H, W) or (H, W, 3), not {image.shape}")
    # ITU-R BT.601 luma: Y = 0.299 R + 0.587 G + 0.114 B
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


@dataclass(frozen=True)
class Variant:
    """One variant: its ``name`` (``--variant NAME``), what it does, and the frame transform
    (BGR (H, W, 3) uint8 -> the frame to write, (H, W) or (H, W, 3) uint8)."""

    name: str
    describe: str
    transform: Callable[[np.ndarray], np.ndarray]


#: the variants by name
VARIANTS: dict[str, Variant] = {
    "grey": Variant("grey", "every frame to one channel of grey levels (OpenCV's BGR -> grey weights, written "
                            "losslessly); the tracker sees three equal channels, as in grey JPEG video", grey),
}


def select_variant(name: str) -> Variant:
    """The variant called ``name``; ValueError (one line naming the known ones) for any other."""
    v = VARIANTS.get(name.strip())
    if v is None:
        raise ValueError(f"unknown variant {name!r} in --variant (known: {', '.join(VARIANTS)})")
    return v
