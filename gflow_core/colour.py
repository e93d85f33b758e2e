"""Colour histograms of boxes: the appearance tracker's second cue.

The edge-orientation channels of :mod:`gflow_core.appearance.filter` say little about a face that
turns to profile or walks into new light: after such a change the target matches the
exemplars it trusted no better than the background does. Its colour often still does. This
module measures colour as the colour-based particle filter of Perez, Hue, Vermaak & Gangnet
(ECCV 2002) does:

* **Bins.** HSV, 10 hue x 10 saturation bins for pixels with S > 0.1 and V > 0.2, and 10
  value bins for the rest, whose hue is noise. A grey frame puts
  every pixel in the value bins: the cue is then a grey-level histogram.
* **Distance.** rho_c = 1 - BC(p, q), with BC = sum_b sqrt(p_b q_b) the Bhattacharyya
  coefficient of the normalised histograms (the square of their Bhattacharyya distance D),
  in [0, 1].
* **Sampling.** A histogram counts the pixels of a grid of ``stride`` pixels (about 12 x 12
  samples a box), and every box of one size on that grid is counted at once by a box filter of
  the bins' one-hot planes (what an integral histogram, Porikli, CVPR 2005, gives).

The tracker keeps distributions of rho_c for the target and for clutter, as it does for the
edge distance (:mod:`gflow_core.visibility`), and searches a hidden target by colour as well as
by edges. No I/O here.

Coordinates are image (x, y) pixels with the origin at the top-left pixel centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .features import to_uint8
from .remap import remap_points

__all__ = ["N_BINS", "Scan", "bins", "is_grey", "stride_for", "histogram", "bhattacharyya", "scan", "SAMPLES_PER_BOX"]

#: hue x saturation bins of the coloured pixels, and value bins of the rest (Perez et al. 2002)
N_H, N_S, N_V = 10, 10, 10
N_BINS = N_H * N_S + N_V
#: a box's histogram counts about this many samples
SAMPLES_PER_BOX = 144
# S > 0.1 and V > 0.2 of 255 (Perez et al. 2002)
_S_MIN, _V_MIN = 26, 52


def bins(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8: the bin of every pixel of a ``(H, W, 3)`` BGR (``(H, W, 4)`` BGRA) or ``(H, W)``
    grey image, uint8 or float in [0, 1] (:func:`gflow_core.features.to_uint8`)."""
    image = to_uint8(image)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if image.ndim == 2:
        v = image.astype(np.int32)
        return (N_H * N_S + v * N_V // 256).astype(np.uint8)
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV).astype(np.int32)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    coloured = (s >= _S_MIN) & (v >= _V_MIN)
    # hue 0..179 (OpenCV's), saturation and value 0..255
    hs = (h * N_H // 180) * N_S + s * N_S // 256
    return np.where(coloured, hs, N_H * N_S + v * N_V // 256).astype(np.uint8)


def is_grey(image: np.ndarray) -> bool:
    """Whether ``image`` has no colour: ``(H, W)`` or one channel, or its channels all equal (a grey
    video stored as colour)."""
    if image.ndim == 2 or image.shape[2] == 1:
        return True
    return bool(np.array_equal(image[..., 0], image[..., 1]) and np.array_equal(image[..., 1], image[..., 2]))


def stride_for(size: tuple[float, float]) -> int:
    """The sampling step (px) that puts about SAMPLES_PER_BOX samples in a box of ``size`` (w, h)."""
    return max(1, int(math.ceil(math.sqrt(size[0] * size[1] / SAMPLES_PER_BOX))))


def histogram(b: np.ndarray, centre: np.ndarray, size: tuple[float, float], stride: int) -> np.ndarray | None:
    """(N_BINS,) float64 normalised histogram of the box of ``size`` (w, h) centred at ``centre``,
    sampled every ``stride`` px and clipped to the frame; None when no sample lies in the frame."""
    Hh, Ww = b.shape
    x0 = max(0, int(round(centre[0] - (size[0] - 1) / 2.0)))
    y0 = max(0, int(round(centre[1] - (size[1] - 1) / 2.0)))
    x1 = min(Ww, int(round(centre[0] + (size[0] - 1) / 2.0)) + 1)
    y1 = min(Hh, int(round(centre[1] + (size[1] - 1) / 2.0)) + 1)
    if x1 <= x0 or y1 <= y0:
        return None
    counts = np.bincount(b[y0:y1:stride, x0:x1:stride].ravel(), minlength=N_BINS).astype(np.float64)
    return counts / counts.sum()


def bhattacharyya(p: np.ndarray, refs: list[np.ndarray]) -> float:
    """max over ``refs`` of BC(p, q) = sum_b sqrt(p_b q_b), the Bhattacharyya coefficient, in [0, 1]."""
    sp = np.sqrt(p)
    return float(max(np.einsum("k,k->", sp, np.sqrt(q)) for q in refs))


@dataclass(frozen=True)
class Scan:
    """BC of the boxes of one size over a grid of centres.

    bc : (ny, nx) float64, max over the references of BC; -1 where the centre lies outside the
        searched region. xs : (nx,), ys : (ny,) image coordinates of the centres.
    raw : (ny, nx) the BC before the outside was marked (what :meth:`at` reads); stride : grid step, px.
    area : image area (px^2) of the searched centres (the chances clutter had).
    """

    bc: np.ndarray
    xs: np.ndarray
    ys: np.ndarray
    area: float
    raw: np.ndarray
    stride: int

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """BC at the centres (x, y) (each (N,)), bilinear on the grid; beyond it, the nearest box
        that lies wholly in the frame."""
        u = ((x - self.xs[0]) / self.stride).astype(np.float32).reshape(-1, 1)
        v = ((y - self.ys[0]) / self.stride).astype(np.float32).reshape(-1, 1)
        return remap_points(self.raw.astype(np.float32), u, v, cv2.INTER_LINEAR, cv2.BORDER_REPLICATE).astype(np.float64)

    def best(self, mask: np.ndarray | None = None) -> tuple[float, np.ndarray] | None:
        """The best BC (over ``mask`` if given) and its centre (2,); None when nothing was scanned."""
        bc = self.bc if mask is None else np.where(mask, self.bc, -1.0)
        if bc.size == 0:
            return None
        i, j = np.unravel_index(int(np.argmax(bc)), bc.shape)
        if bc[i, j] < 0:
            return None
        return float(bc[i, j]), np.array([float(self.xs[j]), float(self.ys[i])])

    def away(self, centre: np.ndarray, half: tuple[float, float]) -> np.ndarray:
        """(ny, nx) bool: the scanned centres farther than ``half`` (hx, hy) from ``centre`` in x or y."""
        far_x = np.abs(self.xs - centre[0]) >= half[0]
        far_y = np.abs(self.ys - centre[1]) >= half[1]
        return (far_y[:, None] | far_x[None, :]) & (self.bc >= 0)

    def clutter(self, centre: np.ndarray, size: tuple[float, float], min_boxes: int = 16
                ) -> tuple[float, float] | None:
        """The colour cue's clutter about a box of ``size`` (w, h) at ``centre``: the best rho_c =
        1 - BC of the scanned boxes one to two box sizes from it (a histogram counts the whole box,
        so a box that overlaps the target shares its colours), and the image area (px^2) of those
        centres. None when fewer than ``min_boxes`` were scanned there."""
        near_x = np.abs(self.xs - centre[0]) <= 2.0 * size[0]
        near_y = np.abs(self.ys - centre[1]) <= 2.0 * size[1]
        ring = self.away(centre, size) & near_y[:, None] & near_x[None, :]
        n = int(ring.sum())
        best = self.best(ring) if n >= min_boxes else None
        if best is None:
            return None
        return 1.0 - best[0], float(n) * self.stride * self.stride


def scan(b: np.ndarray, centre: np.ndarray, margin: tuple[float, float], size: tuple[float, float],
         refs: list[np.ndarray], stride: int) -> Scan | None:
    """BC against ``refs`` of every box of ``size`` (w, h) whose centre lies within ``centre`` +-
    ``margin`` and whose samples all lie in the frame, on a grid of ``stride`` px.

    The counts of every box at once: a box filter over the one-hot planes of the sampled region
    (an integral histogram, Porikli 2005, in effect). None when no such box fits.
    """
    Hh, Ww = b.shape
    hw, hh = (size[0] - 1) / 2.0, (size[1] - 1) / 2.0
    x0 = max(0, int(math.floor(centre[0] - margin[0] - hw)))
    y0 = max(0, int(math.floor(centre[1] - margin[1] - hh)))
    x1 = min(Ww, int(math.ceil(centre[0] + margin[0] + hw)) + 1)
    y1 = min(Hh, int(math.ceil(centre[1] + margin[1] + hh)) + 1)
    sub = b[y0:y1:stride, x0:x1:stride]
    cw, ch = max(1, int(round(size[0] / stride))), max(1, int(round(size[1] / stride)))
    ny, nx = sub.shape[0] - ch + 1, sub.shape[1] - cw + 1
    if ny < 1 or nx < 1:
        return None
    onehot = np.zeros(sub.shape + (N_BINS,), dtype=np.float32)
    np.put_along_axis(onehot, sub[..., None].astype(np.intp), 1.0, axis=2)
    # counts of each bin in the box whose top-left sample is (i, j): a box filter of the one-hot
    # planes (sums of 0 and 1 in float32 are exact, so the bits do not depend on how it is split)
    counts = cv2.boxFilter(onehot, -1, (cw, ch), normalize=False, anchor=(0, 0),
                           borderType=cv2.BORDER_CONSTANT)[:ny, :nx].reshape(ny, nx, N_BINS)
    sq = np.sqrt(counts / np.float32(cw * ch))
    # BC = sum_b sqrt(p_b q_b), the best over the references
    bc = np.max(np.stack([np.einsum("ijk,k->ij", sq, np.sqrt(q)) for q in refs]), axis=0)
    xs = x0 + (np.arange(nx) + (cw - 1) / 2.0) * stride
    ys = y0 + (np.arange(ny) + (ch - 1) / 2.0) * stride
    inside_x = np.abs(xs - centre[0]) <= margin[0] + 0.5 * stride
    inside_y = np.abs(ys - centre[1]) <= margin[1] + 0.5 * stride
    marked = np.where(inside_y[:, None] & inside_x[None, :], bc, -1.0)
    area = float(inside_x.sum() * inside_y.sum()) * stride * stride
    return Scan(bc=marked, xs=xs, ys=ys, area=area, raw=bc, stride=stride)
