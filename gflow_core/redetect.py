"""Searching a frame for a target that was hidden or lost, and the clutter it is judged against.

A tracker that judges its target hidden (:mod:`gflow_core.visibility`) stops learning its
look and searches for it with the exemplars it trusted before the loss, never with what
covered it. This module is that search, shared by the trackers:

* :func:`search` -- dense normalised correlation of the exemplars over a window of centres
  (up to the whole frame) at several sizes, coarse to fine: the window is resampled so the
  exemplars have at most ``coarse_area`` pixels, the best peak of each size is kept, and the
  best ``refine`` peaks are measured again at the exemplars' own resolution with a few
  pixels of freedom. Every centre searched lies inside the frame, so a box placed by the
  search never leaves the image by more than half its size.
* :func:`clutter_best` -- the best correlation of a response map away from the estimate:
  a sample of what the background's best look-alike scores, for the clutter distribution.

This is the detector half of TLD (Kalal, Mikolajczyk & Matas, PAMI 2012) without its learned
classifier: the "detector" is the tracker's own likelihood (the exemplars and their metric)
evaluated everywhere, and whether a detection is the target is decided by the distributions
of :mod:`gflow_core.visibility`, not by a threshold of its own.

Coordinates are image (x, y) pixels with the origin at the top-left pixel centre; exemplars
are (th, tw, C) float32 channel images at resolution ``res`` = (tw, th).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Candidate", "search", "clutter_best", "response_centres", "shrink", "ncc", "window_energy", "FLAT"]


@dataclass(frozen=True)
class Candidate:
    """A detection: best correlation ``r``, its centre (x, y), its size as ``log_f`` (the log
    of the factor applied to the searched size), and ``area``, the image area (px^2) of the
    centres searched summed over the sizes (how many chances clutter had to score as well)."""

    r: float
    centre: np.ndarray
    log_f: float
    area: float = 0.0


def response_centres(origin: np.ndarray, k: float, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Image x (cols) and y (rows) of the exemplar centre at each position of a response map of
    ``shape`` (rows, cols) whose position (0, 0) is at image ``origin``, ``k`` map px per image px."""
    return origin[0] + np.arange(shape[1]) / k, origin[1] + np.arange(shape[0]) / k


def clutter_best(r: np.ndarray, origin: np.ndarray, k: float, centre: np.ndarray, half: tuple[float, float],
                 min_positions: int = 16) -> tuple[float, float] | None:
    """The best value of the response map ``r`` (rows, cols) at centres farther than ``half``
    (hx, hy image px) from ``centre`` in x or y -- the best look-alike away from the estimate --
    and the image area (px^2) of those centres. None when fewer than ``min_positions`` such
    centres exist (a window hardly larger than the box)."""
    xs, ys = response_centres(origin, k, r.shape)
    far_x = np.abs(xs - centre[0]) >= half[0]
    far_y = np.abs(ys - centre[1]) >= half[1]
    mask = far_y[:, None] | far_x[None, :]
    count = int(mask.sum())
    if count < min_positions:
        return None
    return float(r[mask].max()), count / (k * k)


def shrink(exemplar: np.ndarray, res: tuple[int, int]) -> np.ndarray:
    """An exemplar resampled to ``res`` (tw, th) by area averaging: (th, tw, C) float32."""
    out = cv2.resize(exemplar, res, interpolation=cv2.INTER_AREA)
    return out.reshape(res[1], res[0], -1)


#: a placement whose channels carry less than this fraction of the exemplar's energy has no structure
FLAT = 1e-4


def window_energy(win: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H - th + 1, W - tw + 1) float64: sum of the squared channels of ``win`` (H, W, C) under every
    placement of a template of ``shape`` (th, tw), by an integral image."""
    th, tw = shape
    sq = np.einsum("ijc,ijc->ij", win, win, dtype=np.float64)
    ii = cv2.integral(sq, sdepth=cv2.CV_64F)
    return ii[th:, tw:] - ii[:-th, tw:] - ii[th:, :-tw] + ii[:-th, :-tw]


def ncc(win: np.ndarray, ex: np.ndarray, energy: np.ndarray | None = None) -> np.ndarray:
    """The normalised correlation map of the exemplar ``ex`` (th, tw, C) with ``win`` (H, W, C),
    0 (no evidence) where the window is flat: the channels are normalised with a floor, so a
    region without edges holds values near 0, whose correlation is the ratio of two rounding
    errors (measured: r = 0.98 on a black border, 1e-19 in amplitude after resampling).
    ``energy``: :func:`window_energy` of ``win`` at ``ex``'s shape, when the caller has it."""
    r = cv2.matchTemplate(win, ex, cv2.TM_CCOEFF_NORMED)
    e = window_energy(win, ex.shape[:2]) if energy is None else energy
    return np.where(e < FLAT * float(np.einsum("ijc,ijc->", ex, ex, dtype=np.float64)), np.float32(0.0), r)


def _best_of(win: np.ndarray, exemplars: list[np.ndarray]) -> np.ndarray:
    """max over exemplars of the normalised correlation map of each with ``win`` (:func:`ncc`)."""
    e = window_energy(win, exemplars[0].shape[:2])
    r = ncc(win, exemplars[0], e)
    for ex in exemplars[1:]:
        r = np.maximum(r, ncc(win, ex, e))
    return r


def _crop(feat: np.ndarray, lo: np.ndarray, hi: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The part of ``feat`` covering image x in [lo[0], hi[0]] and y in [lo[1], hi[1]] (plus the
    blur's reach), blurred by a Gaussian of ``sigma`` (0: none), and the image (x, y) of its
    pixel (0, 0)."""
    Hh, Ww = feat.shape[:2]
    pad = 3.0 * sigma + 2.0
    x0, y0 = max(0, int(np.floor(lo[0] - pad))), max(0, int(np.floor(lo[1] - pad)))
    x1, y1 = min(Ww, int(np.ceil(hi[0] + pad)) + 1), min(Hh, int(np.ceil(hi[1] + pad)) + 1)
    x1, y1 = max(x1, x0 + 1), max(y1, y0 + 1)
    crop = feat[y0:y1, x0:x1]
    if sigma > 0:
        crop = cv2.GaussianBlur(crop, (0, 0), sigma)
    return crop, np.array([x0, y0], dtype=np.float64)


def _window(src: np.ndarray, offset: np.ndarray, centre: np.ndarray, k: float, out: tuple[int, int]) -> np.ndarray:
    """``out`` (W, H) pixels resampled by ``k`` around image ``centre`` (x, y) from ``src``, a crop
    of the frame whose pixel (0, 0) is image ``offset``. Beyond the crop the channels are 0 (no
    edges): a box partly outside the frame is matched on what is inside (a replicated border
    draws stripes that matched the exemplars of a person's legs at r = 0.66)."""
    W, H = out
    c = centre - offset
    # output pixel (u, v) -> image centre + ((u, v) - (W - 1) / 2) / k
    M = np.array([[1.0 / k, 0.0, c[0] - (W / 2.0 - 0.5) / k],
                  [0.0, 1.0 / k, c[1] - (H / 2.0 - 0.5) / k]], dtype=np.float64)
    w = cv2.warpAffine(src, M, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=0)
    return w.reshape(H, W, -1)


def search(feat: np.ndarray, exemplars: list[np.ndarray], res: tuple[int, int], size: tuple[float, float],
           centre: np.ndarray, margin: tuple[float, float], log_factors: tuple[float, ...],
           coarse_area: int = 300) -> list[Candidate]:
    """The best match of ``exemplars`` at each size over the centres ``centre`` +- ``margin``
    inside the frame.

    Parameters
    ----------
    feat : (H, W, C) float32 channels of the frame.
    exemplars : the trusted exemplars, each (th, tw, C) float32 at ``res`` = (tw, th).
    size : (w, h) image pixels of the box the exemplars cover at factor 1.
    centre : (2,) float64, middle of the searched centres; margin : (mx, my) image px either side.
    log_factors : sizes searched, as log of the factor on ``size`` (0.0 is the size itself).
    coarse_area : the exemplars are shrunk to at most this many pixels for the dense pass; the
        best coarse peak of each size is measured again at full resolution, +- 2 coarse pixels.

    Returns
    -------
    One candidate per size, in the order of ``log_factors`` (a caller that prefers the size it
    had tries them in that order: the anchor matches a smaller box better as the look drifts),
    each with the area searched over all sizes; empty when no centre of the window lies in the
    frame.
    """
    Hh, Ww = feat.shape[:2]
    tw, th = res
    # searched centres: the window clipped to the frame (a box never more than half outside)
    lo = np.array([max(0.0, centre[0] - margin[0]), max(0.0, centre[1] - margin[1])])
    hi = np.array([min(Ww - 1.0, centre[0] + margin[0]), min(Hh - 1.0, centre[1] + margin[1])])
    if (hi < lo).any():
        return []
    c = min(1.0, float(np.sqrt(coarse_area / float(tw * th))))
    cres = (max(4, int(round(tw * c))), max(4, int(round(th * c))))
    small = [shrink(ex, cres) for ex in exemplars] if cres != (tw, th) else list(exemplars)
    mid = 0.5 * (lo + hi)
    # one blur for every size: that of the middle size (the sizes differ by tens of percent)
    k_mid = cres[0] / size[0]
    reach = 0.5 * np.array(size) * float(np.exp(max(log_factors))) + 1.0
    src, off = _crop(feat, lo - reach, hi + reach, 0.4 / k_mid if k_mid < 1 else 0.0)
    area = float((hi[0] - lo[0] + 1.0) * (hi[1] - lo[1] + 1.0)) * len(log_factors)
    out: list[Candidate] = []
    for lf in log_factors:
        f = float(np.exp(lf))
        k = cres[0] / (size[0] * f)
        # window pixels: every searched centre, plus the exemplar around it
        Wn = int(np.ceil((hi[0] - lo[0]) * k)) + cres[0]
        Hn = int(np.ceil((hi[1] - lo[1]) * k)) + cres[1]
        win = _window(src, off, mid, k, (Wn, Hn))
        r = _best_of(win, small)
        # response (u, v) has its exemplar centre at window pixel (u + (cw - 1) / 2, v + (ch - 1) / 2)
        origin = mid + (np.array([(cres[0] - 1) / 2.0, (cres[1] - 1) / 2.0]) - np.array([(Wn - 1) / 2.0, (Hn - 1) / 2.0])) / k
        xs, ys = response_centres(origin, k, r.shape)
        r[(ys < lo[1] - 0.5 / k) | (ys > hi[1] + 0.5 / k), :] = -1.0
        r[:, (xs < lo[0] - 0.5 / k) | (xs > hi[0] + 0.5 / k)] = -1.0
        _, best, _, loc = cv2.minMaxLoc(r)
        if best <= -1.0:
            continue
        # the peak again at full resolution with +- 2 coarse pixels of freedom
        pc = origin + np.array(loc, dtype=np.float64) / k
        kf = tw / (size[0] * f)
        m = int(np.ceil(2.0 / c)) + 1
        half = np.array([tw / 2.0 + m, th / 2.0 + m]) / kf + 1.0
        loc_src, loc_off = _crop(feat, pc - half, pc + half, 0.4 / kf if kf < 1 else 0.0)
        rf = _best_of(_window(loc_src, loc_off, pc, kf, (tw + 2 * m, th + 2 * m)), exemplars)
        _, rb, _, lb = cv2.minMaxLoc(rf)
        pos = pc + (np.array(lb, dtype=np.float64) - m) / kf
        pos = np.array([min(max(pos[0], 0.0), Ww - 1.0), min(max(pos[1], 0.0), Hh - 1.0)])
        out.append(Candidate(r=float(rb), centre=pos, log_f=float(lf), area=area))
    return out
