"""Whether the points of a box move coherently from one frame to the next: the forward-backward check.

Kalal, Mikolajczyk & Matas, "Forward-Backward Error: Automatic Detection of Tracking Failures", ICPR
2010 (the Median Flow tracker, TLD's short-term part): a grid of points in the box of frame t-1 is
tracked to frame t by pyramidal Lucas-Kanade and back again; a point whose backward track does not
return where it started, or whose patches at t-1 and t are unlike (normalised cross-correlation,
NCC), was not tracked; the box moves by the median displacement of the points that were.
Here the check is the evidence a tentative track (:mod:`.confirm`) asks of a frame in doubt before it
takes it as the target's: the texture of the last frame's box moved coherently to frame t.

* Random noise (independent from frame to frame) has no motion: the points' patches at t-1 and t are
  unrelated, NCC about 0 (the NCC of two independent patches of n pixels has std 1 / sqrt(n), 0.09 for
  the 11 x 11 windows here; Lucas-Kanade's alignment raises it: measured median 0.06-0.16 on
  frames of uniform noise), and the forward-backward error is large (median 9-21 px).
* A flat patch (a grey occluder) has no texture: Lucas-Kanade's gradient matrix is singular and its
  status says the point was not tracked.
* tiger1's blurred, fast-moving toy (from frame 55) keeps median NCC 0.69-0.99 and a median
  forward-backward error of 0.01-4.6 px.

The rules, with their sources: the 10 x 10 grid of points, and a median forward-backward error
above 10 px is a failure (Kalal et al. 2010); at least half the points tracked both ways (Median
Flow keeps the better half of the points; fewer than half tracked at all leaves no half to keep);
and median NCC at least 0.5 (more than five standard deviations of two independent patches' NCC
above 0: ours, where Median Flow ranks by NCC and keeps the better half).

Departures: Median Flow uses the check to move the box; here the box is the filter's, and the flow
only witnesses that the frame holds a texture that moved. The flow's displacement is not required to
agree with the filter's: measured on jumping's stress clips, where the face jumps 24 px in a frame,
the filter's box lags it (9 px) on the very frame in doubt; refusing that frame (the boxes' IoU
under 0.5) lost the face on frames 9-15 and cost every jumping case 0.02-0.3 of success on seed 1. Lucas-Kanade's windows are 11 x 11 pixels over 3 pyramid levels (OpenCV's
defaults are 21 x 21, Median Flow's 3 x 3 over 5); NCC is read over the same window.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Flow", "flow", "coherent", "GRID", "WINDOW", "LEVELS", "MIN_TRACKED", "MAX_FB", "MIN_NCC"]

#: points per side of the box's grid (Kalal et al. 2010's 10 x 10)
GRID = 10
#: Lucas-Kanade's window (px per side) and pyramid levels beyond the frame's own
WINDOW, LEVELS = 11, 3
#: the share of points that must be tracked forward and back
MIN_TRACKED = 0.5
#: px, the median forward-backward error above which the track failed (Kalal et al. 2010)
MAX_FB = 10.0
#: the median NCC of a point's patches at t-1 and t below which they are unrelated
MIN_NCC = 0.5

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03)


@dataclass(frozen=True)
class Flow:
    """The grid's flow from frame t-1 to t: ``tracked`` the share of points tracked forward and back,
    ``fb`` their median forward-backward error (px; inf with none), ``ncc`` their median NCC (-1 with
    none), ``shift`` (2,) float64 their median displacement (x, y) px (0 with none)."""

    tracked: float
    fb: float
    ncc: float
    shift: np.ndarray


def _ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """NCC of the patches (n, k, k) ``a`` and ``b``, pair by pair (0 for a flat one)."""
    a = a - a.mean(axis=(1, 2), keepdims=True)
    b = b - b.mean(axis=(1, 2), keepdims=True)
    # NCC = sum(a b) / sqrt(sum(a^2) sum(b^2))
    den = np.sqrt(np.einsum("nij,nij->n", a, a) * np.einsum("nij,nij->n", b, b))
    num = np.einsum("nij,nij->n", a, b)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def _patches(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(n, WINDOW, WINDOW) float64 patches of the grey ``img`` centred at the (n, 2) points (x, y), sub-pixel."""
    return np.stack([cv2.getRectSubPix(img, (WINDOW, WINDOW), (float(x), float(y))) for x, y in pts]).astype(np.float64)


def flow(prev: np.ndarray, cur: np.ndarray, box: tuple[float, float, float, float]) -> Flow:
    """The flow of a grid of points in ``box`` (x, y, w, h) of frame t-1 to frame t and back.

    Parameters
    ----------
    prev, cur : (H, W) uint8 grey frames t-1 and t.
    box : the box of frame t-1, px (points outside the frame are clipped into it).
    """
    if prev.shape != cur.shape or prev.dtype != np.uint8 or cur.dtype != np.uint8 or prev.ndim != 2:
        raise ValueError(f"flow needs two (H, W) uint8 frames of one size, got {prev.shape} and {cur.shape}")
    x, y, w, h = box
    H, W = prev.shape
    gx = np.clip(x + (np.arange(GRID) + 0.5) * w / GRID, 0.0, W - 1.0)
    gy = np.clip(y + (np.arange(GRID) + 0.5) * h / GRID, 0.0, H - 1.0)
    p0 = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 1, 2).astype(np.float32)
    win = (WINDOW, WINDOW)
    # forward p0 -> p1 on (t-1, t), backward p1 -> p0b on (t, t-1)
    # (nextPts is an output: without OPTFLOW_USE_INITIAL_FLOW its values are not read)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, p0.copy(), winSize=win, maxLevel=LEVELS, criteria=_CRITERIA)
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, p1.copy(), winSize=win, maxLevel=LEVELS, criteria=_CRITERIA)
    a, b, back = p0[:, 0].astype(np.float64), p1[:, 0].astype(np.float64), p0b[:, 0].astype(np.float64)
    ok = (st1[:, 0] == 1) & (st2[:, 0] == 1) & np.isfinite(b).all(axis=1) & np.isfinite(back).all(axis=1)
    if not ok.any():
        return Flow(0.0, float("inf"), -1.0, np.zeros(2))
    a, b, back = a[ok], b[ok], back[ok]
    # FB error e_i = |p0_i - p0b_i| (Kalal et al. 2010, eq. 1: the distance between a point and its track's return)
    fb = np.hypot(*(a - back).T)
    ncc = _ncc(_patches(prev, a), _patches(cur, b))
    return Flow(float(ok.mean()), float(np.median(fb)), float(np.median(ncc)), np.median(b - a, axis=0))


def coherent(f: Flow) -> bool:
    """Whether the flow ``f`` says the box's texture moved coherently (the rules of the module docstring)."""
    return f.tracked >= MIN_TRACKED and f.fb <= MAX_FB and f.ncc >= MIN_NCC
