"""A motion prior with heavy tails: the bivariate Student-t in place of the Gaussian (``motion_tail``).

The constant-velocity prior N(c; pred, diag(sx^2, sy^2)) costs a target that turned or jolted
quadratically in its distance from the prediction: 58 px at a std of 12 px is exp(-11), so a toy that
swings back between two frames seen (tiger1 at every 3rd frame) is outweighed by leaves at the
prediction however much better it matches. A manoeuvre is a rare, large step of the process noise,
which a Gaussian does not have and a Student-t does: the t is a Gaussian whose variance is itself
drawn (an inverse-gamma scale mixture), the textbook model of process noise with outliers (Roth,
Ozkan & Gustafsson, "A Student's t filter for heavy tailed process and measurement noise", ICASSP
2013; Agamennoni, Nieto & Nebot, IEEE TSP 2012). Near the prediction it is the Gaussian's shape; far
from it, its cost grows as log distance, not its square.

The bivariate t of nu degrees of freedom and scale diag(sx^2, sy^2) is

    t(c) = 1 / (2 pi sx sy) (1 + d^2 / nu)^(-(nu + 2) / 2),   d^2 = (dx / sx)^2 + (dy / sy)^2,

since Gamma((nu + 2) / 2) / Gamma(nu / 2) = nu / 2: the Gaussian's normaliser, and the Gaussian in the
limit nu -> inf. Departure from the papers: their dynamics are Gaussian throughout.

How heavy the tails are is the track's to say. With ``motion_tail_weight`` pi < 1 the prior is the mixture

    p(c) = (1 - pi) N(c; pred, S) + pi t_nu(c; pred, S),

the Gaussian for the target that keeps to its motion and the t for its manoeuvres, and with
``motion_tail_rate`` a > 0 the weight pi is learnt from the track's own innovations by online EM
(Cappe & Moulines, JRSS-B 2009): on each frame the target is tracked, the t's responsibility for the
innovation d (the response's peak less the prediction, where the peak is on the estimate; else the
estimate less the prediction) is r = pi t(d) / p(d), and

    pi <- (1 - a) pi + a r,

held within [``TAIL_MIN``, 1 - ``TAIL_MIN``]. A smooth target (a walker, a skater the camera pans
with) teaches pi towards its floor and its prior back towards the Gaussian, which holds it against a
look-alike a few deviations away; a target shaken back and forth teaches pi up.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["log_kernel", "log_density", "responsibility", "learn", "TAIL_MIN"]

#: the floor and (1 - it) the ceiling of the learnt weight of the t
TAIL_MIN = 0.01


def _log_t(dx: np.ndarray, dy: np.ndarray, sx: float, sy: float, nu: float) -> np.ndarray:
    d2 = (dx / sx) ** 2 + (dy / sy) ** 2
    # log t = -(nu + 2) / 2 log(1 + d^2 / nu) + const
    return -0.5 * (nu + 2.0) * np.log1p(d2 / nu)


def log_kernel(dx: np.ndarray, dy: np.ndarray, sx: float, sy: float, nu: float, pi: float = 1.0) -> np.ndarray:
    """(N,) the prior's log density up to its constant 1 / (2 pi sx sy) at offsets (dx, dy) (N,) px from the
    prediction: -d^2 / 2 (nu <= 0 or pi <= 0: the Gaussian), -(nu + 2) / 2 log(1 + d^2 / nu) (pi >= 1: the
    t), else the mixture's log((1 - pi) N + pi t)."""
    if nu <= 0 or pi <= 0:
        # log N = -(dx^2 / 2 sx^2 + dy^2 / 2 sy^2) + const
        return -(dx ** 2 / (2.0 * sx * sx) + dy ** 2 / (2.0 * sy * sy))
    if pi >= 1:
        return _log_t(dx, dy, sx, sy, nu)
    log_n = -(dx ** 2 / (2.0 * sx * sx) + dy ** 2 / (2.0 * sy * sy))
    # log((1 - pi) N + pi t): both of the normaliser 1 / (2 pi sx sy)
    return np.logaddexp(math.log1p(-pi) + log_n, math.log(pi) + _log_t(dx, dy, sx, sy, nu))


def log_density(dx: float, dy: float, sx: float, sy: float, nu: float, pi: float = 1.0) -> float:
    """The prior's normalised log density at one offset (dx, dy) px: log N, log t or their mixture's, all
    with the normaliser 1 / (2 pi sx sy)."""
    k = float(log_kernel(np.array([dx]), np.array([dy]), sx, sy, nu, pi)[0])
    return k - math.log(2.0 * math.pi * sx * sy)


def responsibility(d: np.ndarray, sx: float, sy: float, nu: float, pi: float) -> float:
    """r = pi t(d) / ((1 - pi) N(d) + pi t(d)): the t's share of the innovation ``d`` (2,) px."""
    dx, dy = np.array([d[0]]), np.array([d[1]])
    log_n = float(log_kernel(dx, dy, sx, sy, nu, 0.0)[0])
    log_t = float(_log_t(dx, dy, sx, sy, nu)[0])
    a, b = math.log1p(-pi) + log_n, math.log(pi) + log_t
    return 1.0 / (1.0 + math.exp(min(a - b, 700.0)))


def learn(pi: float, d: np.ndarray, sx: float, sy: float, nu: float, rate: float) -> float:
    """The t's weight after a tracked frame of innovation ``d`` (2,) px: pi <- (1 - a) pi + a r, within
    [TAIL_MIN, 1 - TAIL_MIN] (online EM; the module docstring)."""
    pi = min(max(pi, TAIL_MIN), 1.0 - TAIL_MIN)
    # pi <- (1 - a) pi + a r
    new = (1.0 - rate) * pi + rate * responsibility(d, sx, sy, nu, pi)
    return min(max(new, TAIL_MIN), 1.0 - TAIL_MIN)
