"""The appearance tracker's dynamics: the proposal's random walk on (x, y, log s) (M2 sec. 4.3, A = I).

Kept apart from :mod:`gflow_core.appearance.tracker` so the proposal stage, which needs only this,
does not import the appearance mathematics (OpenCV's matching, scipy's special functions): a stage
process pays for its own imports when it starts, which a live source's first frames wait for.

The walk works on alpha = (x, y, theta, s) with theta = 0 and s = exp(log s), the particles as
the pipeline's particle messages carry them, so a step through the tracker protocol and one
through the stages give the same bits.
"""

from __future__ import annotations

import numpy as np

from .params import AppearanceParams
from ..m2.dynamics import random_walk

__all__ = ["alpha_of", "particles_of", "walk", "PURPOSE_WALK"]

#: the stream of a frame's draws the proposal's random walk takes
PURPOSE_WALK = 0x9209


def alpha_of(parts: np.ndarray) -> np.ndarray:
    """(N, 3) (x, y, log s) -> (N, 4) alpha = (x, y, 0, s)."""
    return np.column_stack([parts[:, 0], parts[:, 1], np.zeros(len(parts)), np.exp(parts[:, 2])])


def particles_of(alpha: np.ndarray) -> np.ndarray:
    """(N, 4) alpha = (x, y, theta, s) -> (N, 3) (x, y, log s) (theta is not tracked)."""
    return np.column_stack([alpha[:, 0], alpha[:, 1], np.log(alpha[:, 3])])


def walk(params: AppearanceParams, alpha: np.ndarray, size0: tuple[float, float], rng: np.random.Generator,
         dt: float = 1.0) -> np.ndarray:
    """The proposal's random walk of (N, 4) alpha over ``dt`` frame periods (M2 sec. 4.3, A = I):

        beta_t = beta_{t-1} + sqrt(dt) diag(std_xy, std_xy, 0, std_log_s) w,   w ~ N(0, I),

    with beta = (x, y, theta, log s) and std_xy = ``params.walk_std`` of the initial box of size
    ``size0`` (w0, h0)."""
    std_xy = params.walk_std((0.0, 0.0, float(size0[0]), float(size0[1])))
    return random_walk(std_xy, 0.0, params.std_log_s).predict(alpha, rng, dt)
