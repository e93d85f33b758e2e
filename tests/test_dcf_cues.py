"""The dcf colour cue that may fail (``colour_outlier``, :mod:`gflow_core.dcf.cues`): its densities are
the learnt distribution's mixed with a uniform one, so its log-likelihood ratio is bounded and the
filter's evidence can outvote it; with eps 0 it is the plain distribution."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gflow_core.dcf.cues import MayFail, may_fail
from gflow_core.dcf.params import DCFParams
from gflow_core.visibility import RHO_MAX, ChiSquare, Cue, visibility


def _dist(mean: float, std: float, n: int = 30) -> ChiSquare:
    return ChiSquare(mean, std * std + mean * mean, n)


def test_eps_zero_is_the_plain_distribution_and_the_mixture_is_a_density() -> None:
    d = _dist(0.44, 0.03)
    assert may_fail(d, 0.0) is d
    m = may_fail(d, 0.01)
    assert isinstance(m, MayFail) and (m.m1, m.m2, m.n) == (d.m1, d.m2, d.n)
    assert m.mode(0.02) == d.mode(0.02)
    grid = np.linspace(1e-4, RHO_MAX, 20001)
    for dist in (d, m):
        area = np.trapezoid([math.exp(dist.log_pdf(float(x), 0.02)) for x in grid], grid)
        assert area == pytest.approx(1.0, abs=2e-3)
    # far in the tail the mixture is the outlier's density; near the mode it is (1 - eps) the plain one
    assert m.log_pdf(0.05, 0.02) == pytest.approx(math.log(0.01 / RHO_MAX), abs=1e-6)
    assert m.log_pdf(0.44, 0.02) == pytest.approx(math.log(0.99 * math.exp(d.log_pdf(0.44, 0.02)) + 0.005), abs=1e-9)
    for n in (1.0, 3.5):
        assert m.log_pdf_min(0.05, n, 0.02) >= math.log(0.01 / RHO_MAX) > d.log_pdf_min(0.05, n, 0.02)


def test_the_colour_cue_alone_cannot_outvote_the_filter() -> None:
    """The held box on an occluder: the filter's distance far worse than the target's (rho 1.0 against
    0.55 +- 0.07), the colour's far better than its clutter's (0.14 against 0.63 +- 0.03)."""
    p = DCFParams()
    target, clutter = _dist(0.55, 0.07), _dist(0.89, 0.06)
    ct, cc = _dist(0.16, 0.03), _dist(0.63, 0.03)
    prior = (p.reappear / 2, p.reappear / 2, 1.0 - p.reappear)

    def judged(eps: float) -> float:
        cue = Cue(0.14, may_fail(ct, eps), may_fail(cc, eps))
        return visibility(1.0, target, clutter, p.min_std, prior=prior, cues=(cue,)).visible

    assert p.colour_outlier > 0
    assert judged(0.0) > 0.5  # the thin tail of the colour clutter outvotes everything
    assert judged(p.colour_outlier) < 0.01
    # where the filter agrees the colour still counts: a good filter distance and a good colour one
    agree = visibility(0.56, target, clutter, p.min_std, prior=prior,
                       cues=(Cue(0.14, may_fail(ct, p.colour_outlier), may_fail(cc, p.colour_outlier)),))
    alone = visibility(0.56, target, clutter, p.min_std, prior=prior)
    assert agree.visible > alone.visible


def test_a_mistyped_outlier_or_search_minimum_is_refused() -> None:
    with pytest.raises(ValueError, match="colour_outlier"):
        DCFParams(colour_outlier=1.0)
    with pytest.raises(ValueError, match="search_min"):
        DCFParams(search_min=0)
