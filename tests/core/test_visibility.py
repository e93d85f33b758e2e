"""The visibility model (gflow_core.visibility): moments of a sigma^2 chi^2_d variable give its
d and sigma back (eq. 10), the density and CDF are the Gamma's, and the three hypotheses are
weighed as the module says; and the search (gflow_core.redetect) finds a target anywhere in a
frame at the size it has, and samples the clutter away from the estimate."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy import stats

from gflow_core import redetect
from gflow_core.orientation import orientation_channels
from gflow_core.visibility import ChiSquare, visibility


def _learnt(samples: np.ndarray, rate: float = 0.001) -> ChiSquare:
    m = ChiSquare()
    for v in samples:
        m = m.update(float(v), rate)
    return m


def test_moments_give_d_and_sigma_of_a_chi_squared_distance():
    # rho = sigma^2 chi^2_d with d = 12, sigma^2 = 0.01 (sec. 3: rho / sigma^2 ~ chi^2_d)
    rng = np.random.default_rng(0)
    rho = 0.01 * rng.chisquare(12, size=4000)
    m = _learnt(rho)
    d, s2 = m.params(min_std=1e-6)
    assert abs(d - 12) < 1.0 and abs(s2 - 0.01) < 0.001
    # density and CDF are the Gamma(d / 2, 2 sigma^2)'s
    for x in (0.05, 0.12, 0.3):
        assert math.isclose(m.log_pdf(x, 1e-6), stats.gamma(d / 2, scale=2 * s2).logpdf(x), rel_tol=1e-9)
        assert math.isclose(float(m.cdf(np.array([x]), 1e-6)[0]), stats.gamma(d / 2, scale=2 * s2).cdf(x), rel_tol=1e-9)
    # the smallest of n draws: n (1 - F)^(n - 1) p, which integrates to 1 below the mode
    n = 20.0
    xs = np.linspace(1e-4, 2.0, 20001)
    dens = np.exp([m.log_pdf_min(float(x), n, 1e-6) for x in xs[::50]])
    assert np.isfinite(dens).all() and dens.max() > 0
    # a floor on the spread: a steady distance does not make an infinitely sharp distribution
    steady = _learnt(np.full(50, 0.2), rate=0.05)
    d, s2 = steady.params(min_std=0.05)
    assert math.isclose(math.sqrt(2 * d) * s2, 0.05, rel_tol=1e-6)  # std of sigma^2 chi^2_d is sigma^2 sqrt(2 d)
    with pytest.raises(ValueError, match="rate"):
        ChiSquare().update(0.1, 0.0)


def test_three_hypotheses_weigh_a_distance():
    rng = np.random.default_rng(1)
    target = _learnt(0.005 * rng.chisquare(30, size=300))  # rho ~ 0.15 (r ~ 0.85)
    clutter = _learnt(0.01 * rng.chisquare(70, size=300))  # rho ~ 0.7 (r ~ 0.3)
    seen = visibility(0.15, target, clutter, 0.03)
    assert seen.visible > 0.8 and seen.present
    hidden = visibility(0.72, target, clutter, 0.03)
    assert hidden.hidden > 0.9 and not hidden.present
    partly = visibility(0.45, target, clutter, 0.03)  # r = 0.55: neither as usual nor clutter
    assert partly.partial > 0.5 and partly.present
    # one-sided: a closer match than usual is the target, a worse one than clutter is clutter
    assert visibility(0.01, target, clutter, 0.03).visible >= seen.visible
    assert visibility(1.3, target, clutter, 0.03).hidden > 0.99
    # a prior that the target is hidden needs stronger evidence to call it back
    assert not visibility(0.45, target, clutter, 0.03, prior=(0.0005, 0.0005, 0.999)).present
    # the best of many more positions than the clutter was learnt on: a middling match is clutter
    assert visibility(0.5, target, clutter, 0.03, prior=(1.0, 0.0, 1.0), trials=1.0).visible > \
        visibility(0.5, target, clutter, 0.03, prior=(1.0, 0.0, 1.0), trials=500.0).visible
    # a jump away from the prediction costs the present hypotheses
    assert visibility(0.45, target, clutter, 0.03, log_place=-8.0).hidden > 0.5
    # no samples yet: the hypothesis is left out
    assert visibility(0.7, ChiSquare(), ChiSquare(), 0.03).partial == 1.0


def _scene(cx: float, cy: float, size: float, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(60, 200, (240, 320)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.GaussianBlur(np.random.default_rng(11).uniform(0, 255, (40, 30)).astype(np.float32), (0, 0), 1.2)
    t = cv2.resize(tex, (int(round(size * 0.75)), int(round(size))), interpolation=cv2.INTER_LINEAR)
    x0, y0 = int(round(cx - t.shape[1] / 2)), int(round(cy - t.shape[0] / 2))
    img[y0:y0 + t.shape[0], x0:x0 + t.shape[1]] = t
    return img


def test_search_finds_the_target_anywhere_at_its_size():
    from gflow_core.regions import region

    f0 = orientation_channels(_scene(80.0, 70.0, 40.0))
    size = (30.0, 40.0)
    res = (30, 40)
    ex = region(f0, np.array([80.0, 70.0]), size, 1.0)[:40, :30]
    # moved 170 px and grown by 15 %: found over the whole frame, at the larger size
    f1 = orientation_channels(_scene(250.0, 160.0, 46.0))
    cands = redetect.search(f1, [ex], res, size, np.array([80.0, 70.0]), (400.0, 400.0), (0.0, -0.15, 0.15))
    assert [c.log_f for c in cands] == [0.0, -0.15, 0.15]
    best = max(cands, key=lambda c: c.r)
    assert best.log_f == 0.15 and best.r > 0.8 and np.hypot(*(best.centre - [250.0, 160.0])) < 3.0
    assert best.area == pytest.approx(320 * 240 * 3)
    # a window that does not reach it does not find it
    near = redetect.search(f1, [ex], res, size, np.array([80.0, 70.0]), (40.0, 40.0), (0.0,))
    assert near[0].r < 0.6 and np.hypot(*(near[0].centre - [80.0, 70.0])) < 60
    # every centre searched is in the frame: a box never more than half outside
    edge = redetect.search(f1, [ex], res, size, np.array([5.0, 5.0]), (30.0, 30.0), (0.0,))
    assert all(0 <= c.centre[0] <= 319 and 0 <= c.centre[1] <= 239 for c in edge)


def test_clutter_best_leaves_the_estimate_out():
    r = np.zeros((21, 21), np.float32)
    r[10, 10] = 0.9  # the estimate's peak
    r[2, 3] = 0.4  # a look-alike far away
    best, area = redetect.clutter_best(r, np.array([0.0, 0.0]), 1.0, np.array([10.0, 10.0]), (3.0, 3.0))
    assert best == pytest.approx(0.4) and area == 21 * 21 - 5 * 5
    assert redetect.clutter_best(r, np.array([0.0, 0.0]), 1.0, np.array([10.0, 10.0]), (11.0, 11.0)) is None
