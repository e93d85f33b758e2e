"""How far the pose may move over a step of several frame periods: the spread of the pose transition.

The paper leaves the pose transition open (Marks et al. 2004, sec. 2) and its frames are one period
apart; the tracker's transition is a random walk with a standard deviation per period
(:class:`.filter.GFlowConfig`). Over a step of ``dt`` periods (a live source skips frames) a random
walk's variance is ``dt`` times a period's. A head's motion is not a random walk from one period to
the next, though: it keeps its velocity for a while (walking away, turning), so over a few periods it
moves nearly ``dt`` times as far as in one, not ``sqrt(dt)`` times. On david_indoor's reference
landmarks the centre moves 4.3 px RMS over one frame and 11.6 over three (2.7 times; a random walk:
1.7), the log of the size 1.8 % and 3.2 %.

:func:`walk_growth` is the variance of the displacement over ``dt`` periods relative to one period's
when the velocity is an Ornstein-Uhlenbeck process of correlation time ``tau`` periods (the
"integrated Ornstein-Uhlenbeck" motion model; Singer, IEEE Trans. AES 1970, puts the same process on
the acceleration): with ``E v(t) v(t + s) = q exp(-|s| / tau)``,

    Var X(T) = 2 q tau^2 (T / tau - 1 + exp(-T / tau)),

so ``g(dt) = Var X(dt) / Var X(1)``. ``tau = 0`` is the random walk (``g = dt``), ``tau -> inf`` a
constant unknown velocity (``g = dt^2``); ``g(1) = 1`` for every ``tau``, so the one-period
transition, and every run at the source's own pace, is the same.
"""

from __future__ import annotations

import math

__all__ = ["walk_growth"]


def walk_growth(dt: float, tau: float) -> float:
    """Variance of the pose's displacement over ``dt`` frame periods over that of one period.

    Parameters
    ----------
    dt : float
        Frame periods the step spans (``>= 1``, finite).
    tau : float
        Correlation time of the velocity, in periods (``>= 0``, finite; ``0``: a random walk).

    Returns
    -------
    float
        ``g(dt) = (dt / tau - 1 + exp(-dt / tau)) / (1 / tau - 1 + exp(-1 / tau))``; ``dt`` when
        ``tau = 0``; exactly ``1.0`` at ``dt = 1``.

    Raises ``ValueError`` for a ``dt`` or ``tau`` outside those ranges.
    """
    if not (math.isfinite(dt) and dt >= 1.0):
        raise ValueError(f"dt must be finite and >= 1 frame period, got {dt!r}")
    if not (math.isfinite(tau) and tau >= 0.0):
        raise ValueError(f"walk_memory must be finite and >= 0 periods, got {tau!r}")
    if dt == 1.0:
        return 1.0
    if tau == 0.0:
        return float(dt)

    def h(x: float) -> float:
        # x - 1 + exp(-x), written so that it keeps its precision for small x (~ x^2 / 2)
        return x + math.expm1(-x)

    # Var X(T) / Var X(1) of the integrated Ornstein-Uhlenbeck velocity
    return h(dt / tau) / h(1.0 / tau)
