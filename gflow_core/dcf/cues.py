"""A cue that may fail: a learnt distance distribution mixed with an outlier density.

The visibility model (:mod:`gflow_core.visibility`) multiplies the likelihoods of its cues as if
each were always right. The chi-squared fits of a cue's target and clutter distances (Toyama &
Blake eq. 10) have thin tails: a distance a few spreads below the clutter's mean has a density
that falls without bound, so one cue can outvote every other by tens of nats. Staple's colour
score does that where a region is dominated by the target's colours for another reason (an
occluder of the same hue, the frame's border): on the stress benchmark's david_indoor
``occlude-150`` (seed 3) the colour score at the held box gave +27 nats for "visible" against the
filter's -15 and the prior's -8, and the occluder was taken for the face for 80 frames.

The standard remedy is an outlier process (the robust likelihood of Black & Rangarajan 1996; in
multi-cue particle filters, Perez, Vermaak & Blake 2004 sec. 4): with probability ``eps`` the cue
says nothing about the hypothesis and its value is uniform over [0, RHO_MAX],

    p(rho | h) = (1 - eps) p_h(rho) + eps / RHO_MAX,

which bounds the cue's log-likelihood ratio by about log(p_max RHO_MAX / eps) in either direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..visibility import RHO_MAX, ChiSquare

__all__ = ["MayFail", "may_fail"]


def _mix(lp: float, eps: float) -> float:
    """log((1 - eps) exp(lp) + eps / RHO_MAX)."""
    a, b = math.log1p(-eps) + lp, math.log(eps / RHO_MAX)
    hi = max(a, b)
    return hi + math.log(math.exp(a - hi) + math.exp(b - hi))


@dataclass(frozen=True)
class MayFail(ChiSquare):
    """A :class:`ChiSquare` whose densities are mixed with the uniform outlier density (module
    docstring); ``eps`` the probability the cue fails. Its moments are the distribution's own."""

    eps: float = 0.0

    def _plain(self) -> ChiSquare:
        return ChiSquare(self.m1, self.m2, self.n)

    def log_pdf(self, rho: float, min_std: float) -> float:
        """log((1 - eps) p(rho) + eps / RHO_MAX)."""
        return _mix(self._plain().log_pdf(rho, min_std), self.eps)

    def log_pdf_min(self, rho: float, n: float, min_std: float) -> float:
        """The chi-squared part's density of the smallest of ``n`` draws
        (:meth:`ChiSquare.log_pdf_min`), mixed with the outlier's."""
        return _mix(self._plain().log_pdf_min(rho, n, min_std), self.eps)


def may_fail(d: ChiSquare, eps: float) -> ChiSquare:
    """``d`` as a cue that fails with probability ``eps`` (``d`` itself for eps 0)."""
    return d if eps <= 0 else MayFail(d.m1, d.m2, d.n, eps)
