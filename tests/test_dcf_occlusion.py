"""dcf's occlusion options: the search's several peaks and its place prior conditioned on the region
(:mod:`gflow_core.dcf.reacquire`), the learning gate (:mod:`gflow_core.dcf.gate`), the colour cue's
failure rate in the search, and the velocity after a re-detection (``redetect_speed``)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import norm

from gflow_core.dcf import filter as cf
from gflow_core.dcf.gate import within
from gflow_core.dcf.longterm import init_longterm, reliable
from gflow_core.dcf.model import Candidate
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.reacquire import log_truncation, peaks
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER, _dists, _judge, _learn
from gflow_core.tracker import FrameRng, step
from tests.core.test_dcf_tracker import Scene
from tests.test_dcf_search_clutter import hidden_frames

HIDE = (12, 24)  # frames [12, 24): a patch of background covers the target


def _bump(shape: tuple[int, int], r: float, c: float, a: float, s: float = 1.5) -> np.ndarray:
    i, j = np.mgrid[: shape[0], : shape[1]]
    return a * np.exp(-((i - r) ** 2 + (j - c) ** 2) / (2 * s * s))


def test_peaks_are_the_best_separate_maxima_best_first() -> None:
    y = _bump((40, 60), 10, 12, 1.0) + _bump((40, 60), 30, 45, 0.8) + _bump((40, 60), 11, 40, 0.6)
    got = peaks(y, (5, 5), 3)
    assert [(r, c) for r, c, _ in got] == [(10, 12), (30, 45), (11, 40)]
    assert got[0] == cf.peak(y)  # the first is the filter's own peak
    assert [v for _, _, v in got] == sorted((v for _, _, v in got), reverse=True)
    # more peaks asked than bumps: the rest lie away from every better one, never beside it
    many = peaks(y, (5, 5), 12)
    for n, (r, c, _) in enumerate(many):
        for r0, c0, _ in many[:n]:
            assert abs(r - r0) > 5 or abs(c - c0) > 5
    assert len(peaks(y, (100, 100), 4)) == 1  # suppression over the whole map: one


def test_the_place_prior_conditioned_on_the_region() -> None:
    pred, frame = np.array([200.0, 120.0]), (400, 300)
    # a region of 8 standard deviations either way holds the whole prior: nothing changes
    assert log_truncation(pred, 5.0, 5.0, (40.0, 40.0), frame) == pytest.approx(0.0, abs=1e-9)
    # a prior far wider than the region: -log Z, Z its mass over the region (scipy's normal)
    sx, sy, m = 900.0, 700.0, (60.0, 30.0)
    z = (norm.cdf(m[0] / sx) - norm.cdf(-m[0] / sx)) * (norm.cdf(m[1] / sy) - norm.cdf(-m[1] / sy))
    assert log_truncation(pred, sx, sy, m, frame) == pytest.approx(-math.log(z), rel=1e-9)
    # ... there the truncated density is about uniform over the region: the place term log N / Z + log A ~ 0
    log_n = -math.log(2 * math.pi * sx * sy)
    area = (2 * m[0]) * (2 * m[1])
    assert log_n + log_truncation(pred, sx, sy, m, frame) + math.log(area) == pytest.approx(0.0, abs=0.01)
    # a prediction at the frame's corner: a quarter of the prior lies in the frame
    assert log_truncation(np.array([0.0, 0.0]), 5.0, 5.0, (40.0, 40.0), frame) == pytest.approx(math.log(4.0), abs=1e-6)


def _state(p: DCFParams):
    sc = Scene(lambda t: (110.0 + 1.5 * t, 95.0), seed=3)
    st, _ = TRACKER.init(p, TRACKER.observe(p, sc.frame(0)), sc.truth(0), FrameRng(1, 7, 0), {})
    return sc, st


def test_the_gate_is_the_long_term_filters_rule_and_refuses_a_frame_seen_badly() -> None:
    p = DCFParams(learn_level=1.0)
    sc, st = _state(p)
    lt = init_longterm(st.model, st.target, st.clutter)
    for rho in (0.3, 0.55, 0.7, 0.71, 0.9):
        assert within(lt.target, rho, p.longterm_level, p.min_std) == reliable(lt, rho, p)
    obs = TRACKER.observe(p, sc.frame(1))
    c = np.array(sc.path(1))
    sd = math.sqrt(st.target.m2 - st.target.m1 ** 2)
    # seen as usual (the mean distance): learnt; seen far worse than usual: the model is not learnt
    _, good = _learn(st, obs, p, c, 1.0 - st.target.m1, None, True)
    _, bad = _learn(st, obs, p, c, 1.0 - (st.target.m1 + 3.0 * sd), None, True)
    assert "model" in good and "model" not in bad
    # the target's distribution follows it either way
    assert bad["target"].n == st.target.n + 1
    # off (the default): every confident frame teaches
    _, off = _learn(st, obs, DCFParams(), c, 1.0 - (st.target.m1 + 3.0 * sd), None, True)
    assert "model" in off


def test_the_colour_cue_fails_more_often_in_the_search_when_asked() -> None:
    p = DCFParams(search_colour_outlier=0.0)  # as colour_outlier everywhere
    _, st = _state(p)
    ds = _dists(st, None)
    # a placement the filter likes but whose colours are the clutter's
    cand = Candidate(r=0.5, centre=np.array([100.0, 90.0]), log_f=0.0, area=5000.0, r_colour=0.05)
    base = _judge(st, ds, cand, 2.0, 0.0, p)
    assert _judge(st, ds, cand, 2.0, 0.0, dataclasses.replace(p, search_colour_outlier=0.005)) == base
    more = _judge(st, ds, cand, 2.0, 0.0, dataclasses.replace(p, search_colour_outlier=0.2))
    assert more > base
    # a placement whose colours are the target's: the colour cue's support shrinks too
    good = dataclasses.replace(cand, r_colour=1.0 - st.ctarget.m1)
    assert _judge(st, ds, good, 2.0, 0.0, dataclasses.replace(p, search_colour_outlier=0.2)) <= \
        _judge(st, ds, good, 2.0, 0.0, p)


def _hidden_frames(speed: float):
    return hidden_frames(lambda t: (60.0 + speed * t, 95.0), HIDE, HIDE[1] + 10)


def test_after_a_redetection_the_motion_prior_is_widened_by_the_typical_speed() -> None:
    sc, frames = _hidden_frames(4.0)
    p = DCFParams()  # on by default
    assert p.redetect_speed
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    found = []
    for t in range(1, len(frames)):
        before = st
        st, est = step(TRACKER, p, st, TRACKER.observe(p, frames[t]), FrameRng(1, 7, t))
        if t == HIDE[0] - 1:
            # E|v|^2 learnt on the tracked frames: the target moves 4 px a frame
            assert 4.0 < st.speed2 < 16.0 * 1.5
            arrays, values = to_arrays(st)
            assert from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), p).speed2 == st.speed2
        if before.hidden_run > 0 and st.hidden_run == 0 and est.phase == "redetect":
            found.append(t)
            assert not st.velocity.any()
            if before.hidden_run >= p.hidden_after:
                # judged hidden before: the velocity is unknown, the next frame's prior wider by sqrt(E|v|^2 / 2)
                assert st.spread == pytest.approx(math.sqrt(0.5 * before.speed2)) and st.spread > 1.0
            else:
                # a frame in doubt: the velocity was known a frame ago, the prior is the usual one
                assert st.spread == 0.0
    assert any(t >= HIDE[1] for t in found), f"the target was never found again: {found}"
    assert st.hidden_run == 0 and est.target_state == "tracked"
    assert abs(est.box[0] - sc.truth(len(frames) - 1)[0]) < 6.0
    # off (as recordings made before it run): nothing learnt, nothing kept in a snapshot
    off = DCFParams(redetect_speed=False)
    st, _ = TRACKER.init(off, TRACKER.observe(off, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    for t in range(1, HIDE[0]):
        st, _ = step(TRACKER, off, st, TRACKER.observe(off, frames[t]), FrameRng(1, 7, t))
    assert st.speed2 == 0.0 and "speed2" not in to_arrays(st)[1]


def test_the_options_validate() -> None:
    for bad in ({"search_peaks": 0}, {"learn_level": -1.0}, {"learn_level": math.inf}, {"search_colour_outlier": 1.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            DCFParams(**bad)
