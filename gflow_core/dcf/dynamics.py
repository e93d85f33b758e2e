"""The correlation-filter tracker's dynamics: the proposal's random walk and the motion model.

Kept apart from :mod:`gflow_core.dcf.tracker` so the proposal stage, which needs only the walk,
does not import the tracker's mathematics (a stage process pays for its imports when it starts).

The state of a particle is (x, y, log s). Its dynamics over ``dt`` frame periods are a constant
velocity model whose noise grows with the target's speed and with dt:

    c_t = c_{t-1} + v dt + (sigma_0 sqrt(dt) + beta |v| dt) w,    w ~ N(0, I_2),

with sigma_0 = ``std_xy_rel`` sqrt(w0 h0) and beta = ``speed_noise``; v is the velocity of the
estimates (a running mean, ``velocity_memory``). The pipeline draws it in two parts: the proposal
stage draws the random walk sigma_0 sqrt(dt) w_1 about the posterior's particles
(:func:`walk`, from the particles alone, as every proposal stage does); the filter, which holds v,
adds v dt and the speed's share beta |v| dt w_2 (:func:`speed_noise`). The two Gaussian parts add
up to a variance sigma_0^2 dt + beta^2 |v|^2 dt^2, which is not (sigma_0 sqrt(dt) + beta |v| dt)^2
but bounds it within a factor 2: a departure of the split, not of the model's intent.

The walk works on alpha = (x, y, theta, s) with theta = 0 and s = exp(log s), the particles as the
pipeline's particle messages carry them, so a step through the tracker protocol and one through
the stages give the same bits.
"""

from __future__ import annotations

import numpy as np

from ..appearance.dynamics import alpha_of, particles_of
from ..m2.dynamics import random_walk
from .params import DCFParams

__all__ = ["alpha_of", "particles_of", "walk", "speed_noise", "PURPOSE_WALK"]

#: the stream of a frame's draws the proposal's random walk takes
PURPOSE_WALK = 0xDCF1


def walk(params: DCFParams, alpha: np.ndarray, size0: tuple[float, float], rng: np.random.Generator,
         dt: float = 1.0) -> np.ndarray:
    """The proposal's random walk of (N, 4) alpha over ``dt`` frame periods:

        beta_t = beta_{t-1} + sqrt(dt) diag(sigma_0, sigma_0, 0, 0) w,   w ~ N(0, I),

    beta = (x, y, theta, log s), sigma_0 = ``params.walk_std`` of the initial box of size ``size0``
    (the scale is the scale filter's, not walked)."""
    std_xy = params.walk_std((0.0, 0.0, float(size0[0]), float(size0[1])))
    return random_walk(std_xy, 0.0, 0.0).predict(alpha, rng, dt)


def speed_noise(params: DCFParams, velocity: np.ndarray, dt: float) -> float:
    """The std (px) of the speed's share of the centre's noise over ``dt`` periods: beta |v| dt."""
    return params.speed_noise * float(np.hypot(velocity[0], velocity[1])) * dt
