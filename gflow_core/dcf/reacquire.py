"""Getting a hidden target back: the search's candidates and the place prior they are judged under.

The search for a hidden target (:func:`gflow_core.dcf.tracker.step`) slides the filter over a region
about the prediction and judges a placement against "hidden" (the clutter it has learnt). Two parts
of that are here:

* :func:`search_peaks` -- the ``k`` best separate placements of each size, not only the best one.
  TLD's detector hands every patch its classifier accepts to the integrator (Kalal, Mikolajczyk &
  Matas, PAMI 2012, sec. 5.3), and MUSTer and LCT re-detect among several candidates: a distractor
  that outscores the target on the filter alone (another skater, a patch at the frame's edge)
  hides the target from a search that judges only its best placement, where the colour score and
  the place would tell them apart. Each peak is at least half a box from every better one (non-
  maximum suppression), so two peaks are two placements, not one placement twice.
* :func:`log_truncation` -- the target's place prior conditioned on the region searched. The motion
  prior spreads while the target is unseen (``search_growth``); after tens of frames its standard
  deviation is wider than the frame, and a Gaussian that wide puts most of its mass outside the
  region searched. The candidate is a placement in the region, so its place under "visible" is
  the prior truncated to the region, N(c; pred, S) / Z with Z the prior's mass over it; clutter's is
  uniform over the region, 1 / A. Without the truncation a long occlusion makes every placement
  some nats less likely to be the target than clutter only because the prior has spread, which is
  what the spread was meant to avoid.

Departure: the papers' detectors (TLD's cascade, LCT's random fern, MUSTer's key-point store) are
detectors of their own; here the detector is the tracker's filter slid over the region and the
decision stays the visibility model's likelihood ratio (:mod:`gflow_core.visibility`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from . import model as tm
from .params import DCFParams

__all__ = ["peaks", "search_peaks", "log_truncation"]


def peaks(y: np.ndarray, half: tuple[int, int], k: int) -> list[tuple[int, int, float]]:
    """Up to ``k`` (row, col, value) local maxima of the map ``y`` (h, w), best first: each the maximum of
    the rectangle of half-sides ``half`` (rows, cols) about it, and at least that far from every better
    one (greedy non-maximum suppression). The first is :func:`.filter.peak`'s (the first of equal maxima
    in row-major order)."""
    out: list[tuple[int, int, float]] = []
    y = np.array(y, dtype=np.float64)
    hr, hc = max(int(half[0]), 0), max(int(half[1]), 0)
    for _ in range(max(k, 0)):
        i = int(np.argmax(y))
        r, c = divmod(i, y.shape[1])
        v = float(y[r, c])
        if not math.isfinite(v):
            break
        out.append((r, c, v))
        y[max(0, r - hr): r + hr + 1, max(0, c - hc): c + hc + 1] = -np.inf
    return out


def search_peaks(model: tm.TargetModel, image: np.ndarray, grey: np.ndarray, hold: np.ndarray,
                 margin: tuple[float, float], log_s: float, geom: tm.Geometry, p: DCFParams,
                 log_sizes: tuple[float, ...], k: int) -> list[tm.Candidate]:
    """The ``k`` best separate placements by the filter alone at each log-size change in ``log_sizes``
    (the order of :func:`.model.search`, whose candidates are the first of each size), each with the
    colour score there; a placement's neighbours within half a box are suppressed. ``area`` sums the
    areas searched over the sizes."""
    out: list[tm.Candidate] = []
    area = 0.0
    for lf in log_sizes:
        r = tm.respond_region(model, image, grey, hold, margin, log_s + lf, geom, p)
        if r is None:
            continue
        assert r.cf is not None
        s = float(np.exp(log_s + lf))
        # half a box in map cells: q map px per image px
        half = (int(0.5 * geom.size0[1] * s * r.q[1]), int(0.5 * geom.size0[0] * s * r.q[0]))
        area += r.area()
        for i, j, v in peaks(r.cf, half, k):
            out.append(tm.Candidate(v, r.point(i, j), float(lf), 0.0, None if r.colour is None else float(r.colour[i, j])))
    return [tm.Candidate(c.r, c.centre, c.log_f, area, c.r_colour) for c in out]


def _mass(lo: float, hi: float, mu: float, sd: float) -> float:
    """P(lo <= X <= hi) of X ~ N(mu, sd^2)."""
    # Phi(z) = (1 + erf(z / sqrt 2)) / 2
    a, b = (lo - mu) / (sd * math.sqrt(2.0)), (hi - mu) / (sd * math.sqrt(2.0))
    return 0.5 * (math.erf(b) - math.erf(a))


def log_truncation(pred: np.ndarray, sx: float, sy: float, pred_margin: tuple[float, float],
                   frame: tuple[int, int]) -> float:
    """-log Z, Z the mass of the place prior N(pred, diag(sx^2, sy^2)) over the centres searched, ``pred``
    +- ``pred_margin`` within the ``frame`` (W, H) (a floor of 1e-300): added to the place term
    log N(c; pred, S) + log A of :func:`gflow_core.dcf.tracker._log_place`, it makes the prior's
    density that of the prior conditioned on the region."""
    W, H = frame
    # Z = (Phi((x1 - px) / sx) - Phi((x0 - px) / sx)) (Phi((y1 - py) / sy) - Phi((y0 - py) / sy))
    zx = _mass(max(0.0, pred[0] - pred_margin[0]), min(W - 1.0, pred[0] + pred_margin[0]), float(pred[0]), sx)
    zy = _mass(max(0.0, pred[1] - pred_margin[1]), min(H - 1.0, pred[1] + pred_margin[1]), float(pred[1]), sy)
    return -math.log(max(zx, 1e-300) * max(zy, 1e-300))
