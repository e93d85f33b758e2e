"""How much of the target's velocity carries on: the motion model's gain learnt from the track (``motion_fit``).

The motion prior predicts the centre as c_{t-1} + v dt (constant velocity), v the running mean of the
estimates' displacements. That holds a target that keeps its heading (a walker, a car) and fails one
that jolts back and forth (a toy shaken by hand, a jumping face, motion seen at every 3rd frame),
whose next displacement is no likelier along v than against it: there the prediction lands a whole
displacement beyond the target on every reversal, and the prior's spread about it is too tight to
take the target back. Which of the two a target is, the track itself shows. Learnt dynamics (Blake,
Isard & Reynard 1995; North & Blake 1998, "Learning dynamical models using expectation-maximisation")
fit an auto-regressive model to the tracked motion; here its one coefficient, the gain g of

    d_t = g u_t + e_t,        u_t = v_{t-1} dt,   d_t = c_t - c_{t-1},   e_t ~ N(0, sigma_t^2 I),

is fitted by Bayesian linear regression with a prior g ~ N(1, 1) (the constant-velocity model, weakly
held) and forgetting at rate a = ``motion_fit`` on the frames the target was tracked:

    A_t = (1 - a) A_{t-1} + d_t . u_t / sigma_t^2,     B_t = (1 - a) B_{t-1} + |u_t|^2 / sigma_t^2,
    g_t = clip((A_t + 1) / (B_t + 1), 0, 1),                         (the posterior mean of g)

sigma_t the motion prior's std on that frame (sqrt(sx sy)), so a frame's displacement counts by how
much it says against the prior's own spread. The prediction becomes c_{t-1} + g v dt: g = 1 is the
constant-velocity model, g = 0 the last place (a window where CSRT and KCF put theirs).

Departures: the auto-regressive coefficient is a scalar shared by x and y (a 2x2 matrix needs more
frames than a jolting target keeps one regime for), it is clipped to [0, 1] (a negative gain, an
oscillation's, predicts a reversal whose timing one coefficient cannot know), and the noise variance
is the prior's, not fitted. With ``motion_switch`` the two modes make the prediction (:mod:`.modes`) and the
gain is learnt but not applied.
"""

from __future__ import annotations

import numpy as np

__all__ = ["gain", "update"]


def gain(fit: tuple[float, float]) -> float:
    """g = clip((A + 1) / (B + 1), 0, 1): the velocity's gain from the sums ``fit`` = (A, B) (module docstring)."""
    a_sum, b_sum = fit
    # g = (A + g0 / s0^2) / (B + 1 / s0^2), g0 = s0 = 1: the posterior mean under the prior N(1, 1)
    return float(min(max((a_sum + 1.0) / (b_sum + 1.0), 0.0), 1.0))


def update(fit: tuple[float, float], d: np.ndarray, u: np.ndarray, var: float, rate: float) -> tuple[float, float]:
    """The sums (A, B) after a tracked frame of displacement ``d`` (2,) px, predicted velocity share
    ``u`` = v_{t-1} dt (2,) px and the prior's variance ``var`` px^2, forgotten at ``rate``."""
    a_sum, b_sum = fit
    # A_t = (1 - a) A_{t-1} + d . u / sigma^2;  B_t = (1 - a) B_{t-1} + |u|^2 / sigma^2
    return ((1.0 - rate) * a_sum + float(d @ u) / var, (1.0 - rate) * b_sum + float(u @ u) / var)
