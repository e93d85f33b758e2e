"""The estimate as the mean of the posterior's heaviest mode, not of the whole particle set.

With particles drawn about several peaks of the response (:mod:`.proposal`) the posterior may hold two
modes: the target where it moved and a copy of it, or the place it left, near the prediction. Their
weighted mean lies between them, on neither; the next frame's window is centred there and its
prediction carries the velocity that mean implies, so a tracker that averages two modes drifts to
whichever the next window favours. The mixture particle filter of Vermaak, Doucet & Perez (ICCV 2003,
sec. 3) keeps each mode as a component of the posterior and reports each component's mean; here one
target is tracked, so the estimate is the mean of the heaviest mode:

    m* = argmax_i sum_j W_j [|x_j - x_i| <= h_x] [|y_j - y_i| <= h_y]      (the mass within half a box)
    c  = sum_{j in B(m*)} W_j x_j / sum_{j in B(m*)} W_j,   B(m*) the particles within half a box of m*,

the box's half sides h. When every particle lies within half a box of the heaviest, c is the weighted
mean of them all.

Departure: Vermaak et al. cluster the particles by K-means and keep the components apart through
resampling; here the modes are found anew each frame from the weighted particles (a box-sized kernel's
mode, as one mean-shift step from the best particle), and the particles are resampled as one set.
"""

from __future__ import annotations

import numpy as np

__all__ = ["heaviest_mode"]


def heaviest_mode(parts: np.ndarray, W: np.ndarray, half: tuple[float, float]) -> np.ndarray:
    """(2,) the weighted mean of the particles within ``half`` (hx, hy) px of the particle with the most
    weight within that distance of it: ``parts`` (N, >= 2) the particles' (x, y, ...), ``W`` (N,) their
    normalised weights."""
    xy = parts[:, :2]
    # near_ij = [|x_j - x_i| <= h_x][|y_j - y_i| <= h_y]
    near = (np.abs(xy[:, None, 0] - xy[None, :, 0]) <= half[0]) & (np.abs(xy[:, None, 1] - xy[None, :, 1]) <= half[1])
    # mass_i = sum_j W_j near_ij (einsum, not BLAS: the same bits in one thread and in many)
    mass = np.einsum("ij,j->i", near.astype(np.float64), W)
    sel = near[int(np.argmax(mass))]
    w = W[sel]
    return np.einsum("i,ij->j", w, xy[sel]) / float(w.sum())
