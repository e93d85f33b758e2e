"""dcf's motion model that switches (``motion_switch``; gflow_core.dcf.modes)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.dcf import modes as mm
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER
from gflow_core.evaluation.metrics import centre_error
from gflow_core.tracker import FrameRng, step
from tests.core.test_dcf_tracker import Scene, _track


def _motion(mu: float, v: tuple[float, float], switch: float = 0.1) -> mm.Motion:
    return mm.predict(DCFParams(motion_switch=switch), mu, np.array([100.0, 80.0]), np.array(v), (20.0, 20.0),
                      0.5 * float(np.hypot(*v)), 0.0, 1.0)


def test_the_modes_prior_mixes_by_the_markov_chain_and_coincides_for_a_still_target() -> None:
    """pi_t(1) = (1 - p) mu + p (1 - mu); a still target's two modes are one Gaussian, so every place's
    responsibility is pi_t(1) and the posterior stays at it."""
    m = _motion(0.0, (0.0, 0.0))
    assert m.pi.tolist() == pytest.approx([0.9, 0.1])
    assert _motion(1.0, (0.0, 0.0)).pi.tolist() == pytest.approx([0.1, 0.9])
    xy = np.array([[100.0, 80.0], [112.0, 71.0], [90.0, 95.0]])
    _, r = mm.log_prior(m, xy)
    np.testing.assert_allclose(r, 0.1)
    assert mm.posterior(np.full(3, 1.0 / 3.0), r) == pytest.approx(0.1)


def test_the_manoeuvre_explains_a_target_that_stopped_or_turned_and_not_one_that_kept_on() -> None:
    """v = 20 px a frame to the right: particles weighed at the constant-velocity prediction make the
    manoeuvre less likely than its prior (0.1), particles where the target was more likely than that, and
    where it turned back to at its speed, several times its prior (a stop within the constant-velocity prior's
    std, 15 px here, is explained by it nearly as well); the mixture's prior where it turned is far
    above the constant-velocity prior alone."""
    m = _motion(0.0, (20.0, 0.0))
    W = np.full(5, 0.2)
    kept_on = np.array([[120.0, 80.0]] * 5) + np.arange(5)[:, None] * 0.5
    stopped = np.array([[100.0, 80.0]] * 5) + np.arange(5)[:, None] * 0.5
    turned = np.array([[80.0, 80.0]] * 5) + np.arange(5)[:, None] * 0.5
    on = mm.posterior(W, mm.log_prior(m, kept_on)[1])
    assert on < 0.05
    assert mm.posterior(W, mm.log_prior(m, stopped)[1]) > on
    assert mm.posterior(W, mm.log_prior(m, turned)[1]) > 0.4
    cv_only = mm.predict(DCFParams(motion_switch=1e-12), 0.0, np.array([100.0, 80.0]), np.array([20.0, 0.0]),
                         (20.0, 20.0), 10.0, 0.0, 1.0)
    assert mm.log_prior(m, turned)[0][0] > mm.log_prior(cv_only, turned)[0][0] + 0.5
    # the window's centre: c + pi_t(0) v dt
    np.testing.assert_allclose(m.mean, [118.0, 80.0])


def test_the_particles_move_by_their_modes() -> None:
    """Every particle the constant-velocity mode draws moves by v dt, every manoeuvring one stays where the
    walk put it on average, spread by |v| dt."""
    m = _motion(0.5, (20.0, 0.0), switch=0.0 + 1e-9)
    rng = np.random.default_rng(3)
    modes = mm.draw(m, 4000, rng)
    assert 0.45 < modes.mean() < 0.55
    moved = mm.move(m, np.tile([100.0, 80.0], (4000, 1)), modes, rng)
    cv, man = moved[modes == 0], moved[modes == 1]
    np.testing.assert_allclose(cv.mean(axis=0), [120.0, 80.0], atol=0.5)
    np.testing.assert_allclose(cv.std(axis=0), [10.0, 10.0], rtol=0.1)
    np.testing.assert_allclose(man.mean(axis=0), [100.0, 80.0], atol=1.5)
    np.testing.assert_allclose(man.std(axis=0), [20.0, 20.0], rtol=0.1)


def _stop_and_start(t: int) -> tuple[float, float]:
    """12 px a frame to the right until frame 10, still until 20, then 12 px a frame back."""
    x = 60.0 + 12.0 * min(t, 10) - 12.0 * max(t - 20, 0)
    return (x, 100.0)


def test_the_manoeuvre_follows_a_target_that_stops_and_starts() -> None:
    """A target that runs, stops and turns back: the manoeuvre's probability rises on the frame it stops
    and on the frame it turns, and falls while it runs; without the option it stays 0 (constant velocity
    alone) and the tracks differ; both follow the target."""
    sc = Scene(_stop_and_start)
    frames = [sc.frame(t) for t in range(30)]
    p = DCFParams(motion_switch=0.1)
    st, est = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    mu = [st.manoeuvre]
    boxes = [est.box]
    for t in range(1, 30):
        st, est = step(TRACKER, p, st, TRACKER.observe(p, frames[t]), FrameRng(1, 7, t))
        mu.append(st.manoeuvre)
        boxes.append(est.box)
    truth = np.array([sc.truth(t) for t in range(30)])
    assert centre_error(truth, np.array(boxes)).max() < 4.0
    assert mu[11] > mu[10] and mu[21] > mu[20]      # stopped at 11, turned at 21
    assert mu[9] < 0.1 and mu[29] < 0.1             # running at constant velocity
    plain, ests = _track(frames, sc.truth(0))
    assert plain.manoeuvre == 0.0
    assert [e.box for e in ests] != boxes


def test_with_modes_a_step_is_the_same_bits_for_a_seed_and_after_a_snapshot() -> None:
    sc = Scene(_stop_and_start)
    frames = [sc.frame(t) for t in range(16)]
    p = DCFParams(motion_switch=0.2)
    st, _ = _track(frames[:12], sc.truth(0), p)
    assert 0.0 < st.manoeuvre < 1.0
    arrays, values = to_arrays(st)
    back = from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), p)
    assert back.manoeuvre == st.manoeuvre
    for t in range(12, 16):
        obs = TRACKER.observe(p, frames[t])
        st, e1 = step(TRACKER, p, st, obs, FrameRng(1, 7, t))
        back, e2 = step(TRACKER, p, back, obs, FrameRng(1, 7, t))
        assert e1 == e2 and st.manoeuvre == back.manoeuvre


@pytest.mark.parametrize("v", [-0.1, 1.0, float("nan")])
def test_bad_values_are_refused(v) -> None:
    with pytest.raises(ValueError, match="motion_switch must be in \\[0, 1\\)"):
        DCFParams(motion_switch=v)
