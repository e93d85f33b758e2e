"""dcf's motion prior with the target's own displacement, measured frame to frame (``flow_mix``;
gflow_core.dcf.flowpred)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gflow_core.dcf import flowpred as fp
from gflow_core.dcf.coherence import coherent, flow
from gflow_core.dcf import modes as mm
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import DCFObservation
from gflow_core.dcf.tracker import TRACKER
from gflow_core.evaluation.metrics import centre_error
from gflow_core.tracker import FrameRng, step
from tests.core.test_dcf_tracker import Scene, _resumed, _track

LOWE = DCFParams().flow_ratio


def _moving(speed: float) -> Scene:
    return Scene(lambda t: (80.0 + speed * t, 100.0 - 0.5 * speed * t))


@pytest.mark.parametrize("speed", [7.0, 20.0, 40.0])
def test_the_last_box_is_found_where_it_moved(speed: float) -> None:
    """The target moved (speed, -speed / 2) px (its frames are placed at whole pixels): the match's displacement
    is the true one within half a pixel, and it passes the ratio test."""
    sc = _moving(speed)
    m = fp.matched(sc.frame(0), sc.frame(1), sc.truth(0))
    assert m is not None and m.reliable(LOWE)
    true = np.round(np.array(sc.truth(1)[:2])) - np.round(np.array(sc.truth(0)[:2]))
    np.testing.assert_allclose(m.shift, true, atol=0.5)


def test_the_whole_box_finds_a_jump_that_a_grid_of_points_misses() -> None:
    """A 20 px jump on a textured background: the grid of 11 px Lucas-Kanade windows (Median Flow's, the
    confirm check's) is refused or misses it by 10 px or more; the whole box's match finds it."""
    sc = _moving(20.0)
    f = flow(sc.frame(0), sc.frame(1), sc.truth(0))
    true = np.round(np.array(sc.truth(1)[:2])) - np.round(np.array(sc.truth(0)[:2]))
    assert not coherent(f) or np.hypot(*(f.shift - true)) >= 10.0
    m = fp.matched(sc.frame(0), sc.frame(1), sc.truth(0))
    assert m is not None and np.hypot(*(m.shift - true)) < 0.5


def test_a_match_among_look_alikes_or_in_noise_is_not_used() -> None:
    """Two copies of the target in frame t: the best match is no better than the runner-up, and Lowe's ratio
    refuses it; a frame of noise matches nothing (NCC far below 0.5); a box off the frame is not matched."""
    sc = _moving(10.0)
    prev, cur = sc.frame(0), sc.frame(1)
    x, y = (int(round(v)) for v in sc.truth(1)[:2])
    twice = cur.copy()
    twice[y + 40:y + 76, x:x + 30] = cur[y:y + 36, x:x + 30]
    m = fp.matched(prev, twice, sc.truth(0))
    assert m is not None and m.ncc > 0.9 and not m.reliable(LOWE)
    noise = np.random.default_rng(5).integers(0, 256, prev.shape, dtype=np.uint8)
    m = fp.matched(prev, noise, sc.truth(0))
    assert m is not None and m.ncc < 0.3 and not m.reliable(LOWE)
    assert fp.matched(prev, cur, (-5.0, 10.0, 30.0, 36.0)) is None


def test_the_mixture_follows_the_markov_chain_and_moves_each_mode_by_its_own_prediction() -> None:
    """pi_t(1) = (1 - q) mu + q (1 - mu) (eq. 2); the window at c + pi_0 v dt + pi_1 d; the particles drawn in
    the flow's mode move by d, those of constant velocity by v dt."""
    p = DCFParams(flow_mix=0.1)
    c, v, d = np.array([100.0, 80.0]), np.array([10.0, 0.0]), np.array([-20.0, 6.0])
    m = fp.mixture(p, 0.5, c, v, d, (20.0, 20.0), 5.0, 0.0, 1.0)
    assert m.pi.tolist() == pytest.approx([0.5, 0.5])
    assert fp.mixture(p, 0.0, c, v, d, (20.0, 20.0), 5.0, 0.0, 1.0).pi.tolist() == pytest.approx([0.9, 0.1])
    np.testing.assert_allclose(m.mean, c + 0.5 * v + 0.5 * d)
    rng = np.random.default_rng(2)
    modes = mm.draw(m, 4000, rng)
    moved = mm.move(m, np.tile(c, (4000, 1)), modes, rng)
    np.testing.assert_allclose(moved[modes == 0].mean(axis=0), c + v, atol=0.5)
    np.testing.assert_array_equal(moved[modes == 1], np.tile(c + d, ((modes == 1).sum(), 1)))
    # the flow's mode explains a place the flow saw the target go far better than constant velocity alone
    lp, r = mm.log_prior(m, (c + d)[None, :])
    assert r[0] > 0.99


def _out_and_back(t: int) -> tuple[float, float]:
    """20 px a frame to the right for 5 frames, then back at that speed."""
    return (80.0 + 20.0 * min(t, 5) - 20.0 * max(t - 5, 0), 100.0)


def test_the_flow_follows_a_target_the_velocity_cannot() -> None:
    """A target that starts at 20 px a frame and turns back at that speed: constant velocity alone loses it on
    the first frame (and never finds it); with the flow's mode every frame is within 3 px and the mode's
    posterior is high on the frames the velocity is wrong (the start, the turn)."""
    sc = Scene(_out_and_back)
    frames = [sc.frame(t) for t in range(12)]
    truth = np.array([sc.truth(t) for t in range(12)])
    plain, ests = _track(frames, sc.truth(0))
    assert centre_error(truth, np.array([e.box for e in ests]))[1] > 15.0
    p = DCFParams(flow_mix=0.1)
    st, est = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    boxes, mu = [est.box], [st.manoeuvre]
    for t in range(1, 12):
        st, est = step(TRACKER, p, st, TRACKER.observe(p, frames[t]), FrameRng(1, 7, t))
        boxes.append(est.box)
        mu.append(st.manoeuvre)
    assert centre_error(truth, np.array(boxes)).max() < 3.0
    assert mu[1] > 0.5 and mu[6] > 0.5


def test_no_displacement_is_measured_for_a_hidden_target_or_without_a_last_frame() -> None:
    sc = _moving(10.0)
    p = DCFParams(flow_mix=0.1)
    st, _ = TRACKER.init(p, TRACKER.observe(p, sc.frame(0)), sc.truth(0), FrameRng(1, 7, 0), {})
    obs: DCFObservation = TRACKER.observe(p, sc.frame(1))
    assert st.last_grey is not None and fp.observed(st, obs, LOWE) is not None
    assert fp.observed(dataclasses.replace(st, hidden_run=1), obs, LOWE) is None
    assert fp.observed(dataclasses.replace(st, last_grey=None), obs, LOWE) is None


def test_with_the_flow_a_step_is_the_same_bits_after_a_snapshot() -> None:
    sc = Scene(_out_and_back)
    frames = [sc.frame(t) for t in range(10)]
    p = DCFParams(flow_mix=0.2)
    st, _ = _track(frames[:7], sc.truth(0), p)
    assert 0.0 < st.manoeuvre < 1.0 and st.last_grey is not None
    back = _resumed(st, frames, 7, p)
    assert back.manoeuvre == st.manoeuvre and np.array_equal(back.last_grey, st.last_grey)


@pytest.mark.parametrize("kw, match", [({"flow_mix": 1.0}, "flow_mix must be in"),
                                       ({"flow_mix": -0.1}, "flow_mix must be in"),
                                       ({"flow_ratio": 0.0}, "flow_ratio must be in"),
                                       ({"flow_mix": 0.1, "motion_switch": 0.1}, "set one of them")])
def test_bad_values_are_refused(kw, match) -> None:
    with pytest.raises(ValueError, match=match):
        DCFParams(**kw)
