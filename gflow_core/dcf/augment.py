"""The first frame's filter trained on warped copies of its window as well (``augment``).

The filter of the first frame is the average of one sample: it knows the target only as it looked
then, and its response falls off quickly when the target rolls, blurs or changes size before the
running average has seen it do so. Bolme et al. (MOSSE, CVPR 2010) train the initial
filter on eight random small affine perturbations of the first frame's patch; Bhat et al. (UPDT,
ECCV 2018) on a fixed set of copies -- rotations, blur, shifts, flips, dropout. Here a
fixed set (no random draw, so the model does not depend on the seed):

* rotations of the window about the target's centre by +-a/3, +-2a/3 and +-a, a = ``augment_roll``
  degrees (in-plane roll of the target or the camera);
* a change of size by exp(+-``augment_scale``) about the same centre;
* a Gaussian blur of ``augment_blur`` template pixels (motion and focus blur; UPDT's blur).

Every copy keeps the target at the window's centre, so the Gaussian label stays where it is
(UPDT's shifted copies move the label with them; with the label fixed, as BACF's running average
of samples needs, a shift would teach the wrong place, so there are none).

The copies' features are averaged into the first sample -- the sample the masked filter is
solved from (BACF sec. 3.3) or the numerator and denominator of the closed form (DSST eq. 5) --
as

    x_0 = (1 - w) x(I_0) + w mean_j x(T_j I_0),        w = ``augment``,

so that the first filter is what the running average would be had the target already shown those
looks; ``augment`` 0 is the filter of the first frame alone. Departure: MOSSE and UPDT solve the
regression over all copies (sum_j |X_j|^2 in the denominator); the masked filter here is solved
from the averaged sample, as BACF solves it from the running average of frames.
"""

from __future__ import annotations

import math
from typing import Callable

import cv2
import numpy as np

from . import filter as cf
from .features import sample
from .params import DCFParams

__all__ = ["warps", "copies", "first_sample"]


def warps(p: DCFParams) -> list[tuple[float, float, float]]:
    """The copies' (angle in degrees, log-size change, blur sigma in template px) of ``p``, fixed."""
    out: list[tuple[float, float, float]] = []
    if p.augment_roll > 0:
        for f in (1.0, 2.0, 3.0):
            a = p.augment_roll * f / 3.0
            out += [(a, 0.0, 0.0), (-a, 0.0, 0.0)]
    if p.augment_scale > 0:
        out += [(0.0, p.augment_scale, 0.0), (0.0, -p.augment_scale, 0.0)]
    if p.augment_blur > 0:
        out.append((0.0, 0.0, p.augment_blur))
    return out


def copies(grey: np.ndarray, centre: tuple[float, float], size: tuple[int, int], k: tuple[float, float],
           p: DCFParams) -> list[np.ndarray]:
    """The warped copies (:func:`warps`) of the window of ``size`` (w, h) template px at ``centre`` sampled at
    ``k`` from ``grey`` (H, W) float32, or a colour frame (H, W, 3) uint8 BGR: a list of (h, w) (or (h, w, 3))
    float32 patches, each rotated, resized and blurred about the window's centre; the image's border is
    replicated outside it (as :func:`.features.sample`)."""
    w, h = int(size[0]), int(size[1])
    out = []
    for angle, log_f, blur in warps(p):
        f = math.exp(log_f)
        # a window large enough that every output pixel of the rotated, resized copy falls inside it
        grow = (abs(math.cos(math.radians(angle))) + abs(math.sin(math.radians(angle)))) / min(f, 1.0)
        bw, bh = int(math.ceil(w * grow)) + 4, int(math.ceil(h * grow)) + 4
        big = sample(grey, centre, (bw, bh), k)
        # dst = R(angle) f (src - c_big) + c_out: the copy's centre is the window's
        M = cv2.getRotationMatrix2D(((bw - 1) / 2.0, (bh - 1) / 2.0), angle, f)
        M[0, 2] += (w - 1) / 2.0 - (bw - 1) / 2.0
        M[1, 2] += (h - 1) / 2.0 - (bh - 1) / 2.0
        patch = cv2.warpAffine(big, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if blur > 0:
            patch = cv2.GaussianBlur(patch, (0, 0), blur)
        out.append(patch.astype(np.float32))
    return out


def first_sample(x_hat: np.ndarray, grey: np.ndarray, centre: tuple[float, float], size: tuple[int, int],
                 k: tuple[float, float], label_hat: np.ndarray | None, spectrum: Callable[[np.ndarray], np.ndarray],
                 p: DCFParams) -> cf.Spectrum | np.ndarray:
    """The first sample with the copies averaged in (module docstring).

    x_hat : (hc, wc // 2 + 1, C) complex, the first window's spectrum; ``grey`` the frame the copies are
    warped from, (H, W) grey float32 or (H, W, 3) BGR uint8 (with the colour names, which need the colour);
    ``spectrum`` maps a copy, (h, w) or (h, w, 3), to such a spectrum (its cells, windowed). With ``label_hat`` (the label's rfft2) the closed
    form's numerator and denominator (:class:`.filter.Spectrum`, DSST eq. 3, averaged as eq. 5), without
    it the sample itself (the masked filter's, BACF sec. 3.3)."""
    xs = [spectrum(c) for c in copies(grey, centre, size, k, p)]
    w = p.augment if xs else 0.0
    if label_hat is None:
        # x_0 = (1 - w) x(I_0) + w mean_j x(T_j I_0)
        return (1.0 - w) * x_hat + w * (np.mean(xs, axis=0) if xs else 0.0)
    first = cf.train(x_hat, label_hat)
    if not xs:
        return first
    rest = [cf.train(x, label_hat) for x in xs]
    # A_0 = (1 - w) A(I_0) + w mean_j A(T_j I_0), B_0 likewise                    (DSST eq. 5; MOSSE's initial filter)
    return cf.blend(first, cf.Spectrum(np.mean([r.num for r in rest], axis=0), np.mean([r.den for r in rest], axis=0)),
                    w)
