"""Variants of a sequence: every frame changed the same way, the truth carried along (pure functions).

A variant turns each frame of a sequence into the frame of another kind of footage with the same
target, so a benchmark can score the trackers on footage they were not tuned on
(``gflow benchmark DATA --variant NAME``; the files are written by
:mod:`pipeline.evaluation.variant_benchmark`). Each stands for a kind of video the trackers are
expected to hold without having been tuned on it:

* ``grey`` -- grey footage: every frame to its grey levels with OpenCV's BGR -> grey weights
  (``Y = 0.299 R + 0.587 G + 0.114 B``, rounded), one channel. A folder source decodes a
  one-channel image into three equal channels, which is how grey video in colour containers
  (the grey sequences of OTB, JPEG frames with three equal channels) reaches a tracker: the two
  are the same frames to every tracker. The truth is the original's.
* ``blur`` -- a shaking, blurring camera: every frame smeared by a line kernel (the stress cases'
  :func:`~gflow_core.evaluation.stress.motion_kernel`) of a length drawn from 4 to 16 px and a
  direction drawn from 0 to 180 degrees, both drawn afresh for each frame from a generator seeded
  by the frame's index, so a frame is blurred the same way whatever the run. The truth is the
  original's.
* ``fast`` -- fast motion: only every 3rd frame is kept, from the first frame tracked, and the
  kept frames are numbered on (original ``start + 3 k`` becomes ``start + k``), so the target moves
  three times as far between frames for the whole sequence. The truth is the kept frames' boxes
  (on a sequence labelled every 5th frame, every 15th original frame is scored).
* ``small`` -- a small target: every frame at half its width and height (OpenCV's area
  interpolation), every box halved with it (``x, y, w, h -> x/2, y/2, w/2, h/2``).
* ``noise`` -- a cheap camera in poor light, streamed: every pixel gets the noise of a camera's
  sensor, Gaussian with a variance that grows with the signal (the Poisson-Gaussian model of
  raw data, Foi et al., IEEE TIP 2008: ``var = a I + b``, :data:`NOISE_SHOT` and
  :data:`NOISE_READ`), drawn afresh for each frame from a generator seeded by the frame's index;
  then the frame is JPEG-compressed at quality :data:`JPEG_QUALITY` and decoded, as a camera or
  stream on a thin link does. A frame whose channels are equal (grey footage in a colour
  container) gets the same noise in each channel, as one grey sensor gives it. The truth is the
  original's. The codec is OpenCV's: the noise is the same bits everywhere, the compressed frame
  may differ in its last bits with another build's JPEG library.

The five are kept apart so a loss can be put down to one kind of change, and they combine with
``+`` where a kind of video is two of them at once: ``fast+blur`` is fast motion with blur (every 3rd
frame, each kept frame smeared as ``blur`` smears it). A combination applies the transforms in the
order named, keeps every ``step``-th frame of the product of the steps and scales by the product of
the scales (:func:`select_variant`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np  # cv2 (and the stress cases' kernel) imported where used: gflow benchmark's --help lists
# the variants without OpenCV

__all__ = ["Variant", "VARIANTS", "SUITE", "grey", "blur", "half", "noise", "same", "select_variant", "combine"]

Box = tuple[float, float, float, float]

#: the range of the ``blur`` variant's line kernel's length, px
BLUR_LENGTH = (4.0, 16.0)
#: the ``blur`` variant's generator is seeded by (this, the frame's index)
BLUR_SEED = 0xB1
#: the ``noise`` variant's sensor noise: var = NOISE_SHOT * I + NOISE_READ ** 2 (grey levels^2, I in 0..255)
NOISE_SHOT = 1.0
NOISE_READ = 5.0
#: the ``noise`` variant's JPEG quality (OpenCV's scale, 0-100; 75 is a camera's usual)
JPEG_QUALITY = 20
#: the ``noise`` variant's generator is seeded by (this, the frame's index)
NOISE_SEED = 0x7015E


def grey(image: np.ndarray, index: int = 0) -> np.ndarray:
    """The grey levels of a frame: (H, W) uint8 of (H, W, 3) BGR uint8 (or of (H, W), returned as is).
    ``index`` (the frame's) is not used."""
    import cv2

    if image.ndim == 2:
        return image
    _check_frame(image)
    # ITU-R BT.601 luma: Y = 0.299 R + 0.587 G + 0.114 B
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def blur(image: np.ndarray, index: int) -> np.ndarray:
    """Frame ``index`` smeared by a line kernel drawn for it: (H, W[, 3]) uint8 -> the same shape.

    The length is uniform on :data:`BLUR_LENGTH`, the direction uniform on [0, 180) degrees, both
    from ``np.random.default_rng((BLUR_SEED, index))``: the same frame is blurred the same way on
    every run. Edges are mirrored (OpenCV's ``BORDER_REFLECT101``)."""
    import cv2

    from gflow_core.evaluation.stress import motion_kernel

    if image.ndim != 2:
        _check_frame(image)
    if index < 0:
        raise ValueError(f"a frame's index is 0 or more, not {index}")
    rng = np.random.default_rng((BLUR_SEED, index))
    length = float(rng.uniform(*BLUR_LENGTH))
    angle = float(rng.uniform(0.0, 180.0))
    return cv2.filter2D(image, -1, motion_kernel(length, angle), borderType=cv2.BORDER_REFLECT101)


def half(image: np.ndarray, index: int = 0) -> np.ndarray:
    """A frame at half its width and height, (H, W[, 3]) -> (round(H/2), round(W/2)[, 3]), by area
    interpolation (each pixel the mean of the 2 x 2 it covers). ``index`` is not used."""
    import cv2

    if image.ndim != 2:
        _check_frame(image)
    h, w = image.shape[:2]
    if h < 2 or w < 2:
        raise ValueError(f"a frame of {w} x {h} px is too small to halve")
    return cv2.resize(image, (max(1, round(w / 2)), max(1, round(h / 2))), interpolation=cv2.INTER_AREA)


def noise(image: np.ndarray, index: int) -> np.ndarray:
    """Frame ``index`` through a noisy sensor and a JPEG codec: (H, W[, 3]) uint8 -> the same shape.

    The noise is N(0, NOISE_SHOT I + NOISE_READ^2) per pixel and channel (one draw for the three channels of a
    frame whose channels are equal), from ``np.random.default_rng((NOISE_SEED, index))``; the result, rounded and
    clipped to 0..255, is JPEG-encoded at :data:`JPEG_QUALITY` and decoded."""
    import cv2

    if image.ndim != 2:
        _check_frame(image)
    if index < 0:
        raise ValueError(f"a frame's index is 0 or more, not {index}")
    rng = np.random.default_rng((NOISE_SEED, index))
    equal = image.ndim == 3 and bool((image[..., 0] == image[..., 1]).all() and (image[..., 0] == image[..., 2]).all())
    plane = image[..., 0] if equal else image
    f = plane.astype(np.float64)
    # I' = I + sqrt(a I + b) n, n ~ N(0, 1): the Poisson-Gaussian sensor (Foi et al. 2008)
    noisy = f + np.sqrt(NOISE_SHOT * f + NOISE_READ ** 2) * rng.standard_normal(f.shape)
    out = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError(f"frame {index}: JPEG encoding failed")
    decoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if decoded is None:
        raise ValueError(f"frame {index}: JPEG decoding failed")
    if equal:
        return np.repeat(decoded[..., None], 3, axis=2)
    return decoded


def same(image: np.ndarray, index: int = 0) -> np.ndarray:
    """The frame as it is (the ``fast`` variant changes which frames are kept, not how they look)."""
    return image


def _check_frame(image: np.ndarray) -> None:
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"a frame is (H, W) or (H, W, 3), not {image.shape}")


@dataclass(frozen=True)
class Variant:
    """One variant: its ``name`` (``--variant NAME``), what it does, the frame transform
    ((H, W, 3) BGR uint8 and the frame's original index -> the frame to write, (H', W') or
    (H', W', 3) uint8), the frames it keeps (every ``step``-th from the first tracked, numbered on)
    and the factor ``scale`` the transform scales frames by, which the truth's boxes get too."""

    name: str
    describe: str
    transform: Callable[[np.ndarray, int], np.ndarray]
    step: int = 1
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.step < 1 or self.scale <= 0:
            raise ValueError(f"variant {self.name!r}: step is 1 or more and scale above 0")

    def index(self, frame: int, start: int) -> int | None:
        """The derived index of original frame ``frame`` of a run from ``start``: ``start + (frame -
        start) / step``, or None for a frame the variant leaves out (before ``start``, or between
        kept ones)."""
        if frame < start or (frame - start) % self.step:
            return None
        return start + (frame - start) // self.step

    def truth(self, boxes: dict[int, Box], start: int) -> dict[int, Box]:
        """The truth of the derived sequence: each kept frame's box by its derived index, scaled."""
        s = self.scale
        out: dict[int, Box] = {}
        for f, (x, y, w, h) in boxes.items():
            j = self.index(f, start)
            if j is not None:
                out[j] = (x * s, y * s, w * s, h * s)
        return out

    @property
    def keeps_truth(self) -> bool:
        """Whether the derived sequence's truth is the original's, file for file."""
        return self.step == 1 and self.scale == 1.0


#: the variants by name
VARIANTS: dict[str, Variant] = {
    "grey": Variant("grey", "every frame to one channel of grey levels (OpenCV's BGR -> grey weights, written "
                            "losslessly); the tracker sees three equal channels, as in grey JPEG video", grey),
    "blur": Variant("blur", f"every frame smeared by a line kernel {BLUR_LENGTH[0]:g}-{BLUR_LENGTH[1]:g} px long in a "
                            "direction drawn afresh for each frame, as from a shaking camera", blur),
    "fast": Variant("fast", "only every 3rd frame kept, from the first tracked: the target moves three times as far "
                            "between frames", same, step=3),
    "small": Variant("small", "every frame and every box at half the width and height: a small target", half,
                     scale=0.5),
    "noise": Variant("noise", "every frame through a noisy sensor (variance growing with the signal, drawn afresh "
                              f"for each frame) and JPEG at quality {JPEG_QUALITY}: a cheap camera in poor light, "
                              "streamed", noise),
}

#: the kinds of footage ``--variant all`` runs, in order: the sequences as they are (``none``), each
#: variant, and fast motion with blur (the kinds the tuning is judged on together, docs/accuracy.md)
SUITE: tuple[str, ...] = ("none", *VARIANTS, "fast+blur")


def select_variant(name: str) -> Variant:
    """The variant called ``name``, or the combination ``A+B[+...]`` of known ones (each at most once);
    ValueError (one line naming the known ones) for any other."""
    parts = [p.strip() for p in name.split("+")]
    for p in parts:
        if p not in VARIANTS:
            raise ValueError(f"unknown variant {p!r} in --variant (known: {', '.join(VARIANTS)}, or several "
                             f"joined by '+')")
    if len(set(parts)) != len(parts):
        raise ValueError(f"--variant {name!r} names a variant twice")
    if len(parts) == 1:
        return VARIANTS[parts[0]]
    return combine([VARIANTS[p] for p in parts])


def combine(variants: list[Variant]) -> Variant:
    """The variants one after another: their transforms in order (each given the frame's original index),
    every product-of-steps-th frame kept, scaled by the product of the scales."""
    transforms = [v.transform for v in variants]

    def transform(image: np.ndarray, index: int) -> np.ndarray:
        for t in transforms:
            image = t(image, index)
        return image

    step, scale = 1, 1.0
    for v in variants:
        step, scale = step * v.step, scale * v.scale
    return Variant("+".join(v.name for v in variants), "; then ".join(v.describe for v in variants), transform,
                   step=step, scale=scale)
