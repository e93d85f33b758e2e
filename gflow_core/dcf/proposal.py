"""Where the particles drawn at the response go: the separate peaks of the response, not only its best.

The update draws a ``detect_fraction`` of the particles about the response's peak (the mixture proposal
of :func:`gflow_core.dcf.tracker.step`, after Isard & Blake's ICONDENSATION, ECCV 1998). A proposal that
puts them at the best peak alone misses the target whenever something else scores a little higher: a
copy of the target that stays where the prediction is while the target itself moves fast, or a target
the prediction lags. The random walk about the prediction does not reach the target's own peak either
when it moved farther than the walk spreads, so the posterior has no particle there and the estimate
follows the copy. Okuma et al.'s boosted particle filter (ECCV 2004, sec. 4, eq. 2) draws from a
mixture of Gaussians about every detection,

    q(x_t | x_{t-1}, y_t) = b q_det(x_t | y_t) + (1 - b) p(x_t | x_{t-1}),
    q_det = (1 / K) sum_k N(x_t; d_k, sigma_d^2 I),

d_k the K detections; here d_k are the ``detect_peaks`` best separate maxima of the response (each
half a box from every better one, :func:`gflow_core.dcf.reacquire.peaks`), and the motion prior and the
likelihood weigh each, as they weigh every particle.

Departures: Okuma et al. take every detection their Adaboost cascade accepts; here a fixed number of the
response's peaks are taken, each given an equal share of the particles whatever its value (a peak far
below the best gets particles whose weights the likelihood makes negligible). Their importance weights
divide by the proposal's density, p(z | x) p(x | x_{t-1}) / q(x); the tracker's weights, with one peak
or several, are p(z | x) p(x | x_{t-1}) alone, so a peak that draws particles gains posterior mass by
drawing them (dividing by q was measured and loses more than it gets back: docs/dcf-development.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .reacquire import peaks

__all__ = ["detections", "assign"]


def detections(resp: Any, half: tuple[float, float], k: int) -> np.ndarray:
    """(K, 2) image points (x, y) of the ``k`` best separate maxima of the response ``resp``
    (:class:`.model.Response`: its map ``y`` (h, w), index (i, j) the point ``origin + (j / q_x, i / q_y)``),
    best first, K <= k; each peak is at least ``half`` (hx, hy) image px from every better one. The first is
    the map's maximum (:meth:`.model.Response.peak`, which ``k`` = 1 returns alone)."""
    if k == 1:
        return resp.peak()[0][None, :]
    cells = (int(half[1] * resp.q[1]), int(half[0] * resp.q[0]))
    pts = [resp.point(i, j) for i, j, _ in peaks(resp.y, cells, k)]
    return np.array(pts, dtype=np.float64).reshape(-1, 2)


def assign(n: int, k: int) -> np.ndarray:
    """(n,) the peak each of ``n`` particles drawn at the response is about: 0, 1, ..., k - 1, 0, 1, ...
    (equal shares, the best peak's at least as large as any other's)."""
    return np.arange(n) % max(k, 1)

