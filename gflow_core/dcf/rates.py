"""The running filter's learning rate while it is young (``young``).

The running filter is an exponential average of the samples it has learnt (DSST eq. 5, BACF sec.
3.3) at rate eta = ``rate`` (0.02): after n frames the first one still weighs (1 - eta)^n, 0.82
after ten, so for its first few dozen frames the filter is nearly the first frame's, however
unlike the target that frame is (blurred, half hidden, about to turn). Averaged over the frames
it has seen instead, the n-th new sample weighs 1 / (n + 1):

    eta_n = max(eta, 1 / (n0 + n + 1)),

n the frames learnt before, n0 = ``young`` the frames the first sample counts for; with n0 = 1
the filter is the plain mean of the frames it has seen until that mean's rate falls to eta (at
about 1 / eta frames), and an exponential average at eta from then on -- the rule the running
moments of the score distributions follow (:meth:`gflow_core.visibility.ChiSquare.update`). The
first frame keeps its place in detection through the anchor (``anchor_weight``).

Departure: the frames counted are those the target was judged present on (the samples its
distance distribution has learnt beyond the prior's, which the state already holds); the filter
learns only on the confident ones among them, so n can run ahead of the frames it has learnt,
which only brings the fixed rate sooner.

**The rate while the look changes** (``rate_adapt``; off at 0). A target whose look changes faster
than the filter learns -- a skater turning, motion played at two or three times its speed -- is
scored lower frame after frame until it is judged hidden with the box on it. The running filter is
the estimate of a local-level model, the look a_t = a_{t-1} + w (variance q) seen as x_t = a_t + e
(variance r), whose steady-state Kalman gain is the rate eta; the innovation's variance is then S_0
= P + r and r = (1 - eta) S_0. Matching the innovation's variance to the one observed (Mehra, IEEE
TAC 1970; the adaptive Kalman filter), with the distance rho = 1 - y at the estimate taken as the
innovation's variance (it grows as the frame's sample departs from the model), S_0 the target's mean
distance rho_bar (:mod:`gflow_core.visibility`, its long-run mean at ``target_rate``) and S_t the
distance's short-run mean at rate a = ``rate_adapt``,

    S_t = (1 - a) S_{t-1} + a rho_t,
    eta_t = max(eta, 1 - (1 - eta) rho_bar / S_t),             (K = 1 - r / S)

so the rate rises while the target's distance runs above its usual level and is eta again once the
long-run mean has caught up or the distance fallen back. Departures: Mehra estimates q and r from
the innovations' sample covariance over a window; here r is fixed by eta and the target's mean
distance, S is a running mean, and only the filter's rate adapts (the colour model's and the scale
filter's do not); the distance is a response, not a squared innovation, so the matching is an
analogy, not the Kalman filter of the sample. The filter learns only on the frames the tracker is
confident of, as at every rate; S follows every frame the target is judged present on.
"""

from __future__ import annotations

from ..visibility import ChiSquare
from .params import DCFParams

__all__ = ["filter_rate", "recent", "adapted"]


def filter_rate(p: DCFParams, seen: int) -> float:
    """The running filter's learning rate after ``seen`` frames the target was present on (module
    docstring): ``p.rate`` without ``young``."""
    if p.young <= 0:
        return p.rate
    # eta_n = max(eta, 1 / (n0 + n + 1))
    return max(p.rate, 1.0 / (p.young + max(seen, 0) + 1.0))


def recent(p: DCFParams, held: float, target: ChiSquare, rho: float) -> float:
    """S_t, the short-run mean of the target's distance after a present frame of distance ``rho`` (module
    docstring): ``held`` the one before (0: none yet, started from the target's mean ``target``)."""
    before = held if held > 0 else target.mean()
    # S_t = (1 - a) S_{t-1} + a rho_t
    return (1.0 - p.rate_adapt) * before + p.rate_adapt * rho


def adapted(p: DCFParams, eta: float, target: ChiSquare, s_t: float) -> float:
    """eta_t = max(eta, 1 - (1 - eta) rho_bar / S_t): the filter's rate ``eta`` raised while the short-run
    mean ``s_t`` of the distance exceeds the target's mean rho_bar (``eta`` without ``rate_adapt``)."""
    if p.rate_adapt <= 0 or s_t <= 0:
        return eta
    # K = 1 - r / S, r = (1 - eta) S_0, S_0 = rho_bar
    return max(eta, 1.0 - (1.0 - eta) * target.mean() / s_t)
