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
"""

from __future__ import annotations

from .params import DCFParams

__all__ = ["filter_rate"]


def filter_rate(p: DCFParams, seen: int) -> float:
    """The running filter's learning rate after ``seen`` frames the target was present on (module
    docstring): ``p.rate`` without ``young``."""
    if p.young <= 0:
        return p.rate
    # eta_n = max(eta, 1 / (n0 + n + 1))
    return max(p.rate, 1.0 / (p.young + max(seen, 0) + 1.0))
