"""The posterior's mode and its mean on the map as dcf's estimate (``estimate_mode``, ``estimate_learn``,
``estimate_mean``; off by default: docs/dcf-development.md).

On made-up response maps: the mode weighs the response against the motion prior as the particles' weights
do (a higher peak far from the prediction loses to a lower one at it when the prior says so, and wins when
the prior is wide), and never leaves the frame; the mean on the map is the limit of the particles' weighted
mean. On a small scene, one frame: learning at the mode leaves the box at the particles' mean."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.tracker import TRACKER, _map_mean, _mode
from gflow_core.tracker import FrameRng, step

from dcf_scene import BOX, frame


def _two_peaks(near: float, far: float) -> tm.Response:
    """A map of 81 x 81 positions, one per image px from (0, 0): a bump of height ``near`` at (40, 40) and
    one of ``far`` at (70, 40)."""
    ys, xs = np.mgrid[0:81, 0:81].astype(float)
    y = near * np.exp(-((xs - 40) ** 2 + (ys - 40) ** 2) / 8.0) + far * np.exp(-((xs - 70) ** 2 + (ys - 40) ** 2) / 8.0)
    return tm.Response(y, (0.0, 0.0), (1.0, 1.0))


def test_the_mode_weighs_the_response_against_the_motion_prior() -> None:
    p = DCFParams()
    resp = _two_peaks(0.3, 0.5)
    pred = np.array([40.0, 40.0])
    # kappa (30) x 0.2 = 6 nats for the far peak; 30 px at a std of 5 px costs 18: the near one is the mode
    assert np.allclose(_mode(resp, pred, 5.0, 5.0, None, p, 1.0, (200, 200)), [40.0, 40.0])
    # at a std of 30 px it costs 0.5: the far one is
    assert np.allclose(_mode(resp, pred, 30.0, 30.0, None, p, 1.0, (200, 200)), [70.0, 40.0])


def test_the_mode_stays_in_the_frame() -> None:
    p = DCFParams()
    resp = _two_peaks(0.3, 0.5)
    # a frame 60 px wide: the far peak's centre (x 70) is outside it
    m = _mode(resp, np.array([40.0, 40.0]), 30.0, 30.0, None, p, 1.0, (60, 100))
    assert 0.0 <= m[0] <= 59.0 and np.allclose(m, [40.0, 40.0])


def test_the_local_mode_is_the_peak_climbed_to_from_the_mean() -> None:
    p = DCFParams()
    resp = _two_peaks(0.3, 0.5)
    pred = np.array([40.0, 40.0])
    # a wide prior makes the far peak the global mode; from a mean beside the near one, the climb stops there
    assert np.allclose(_mode(resp, pred, 30.0, 30.0, None, p, 1.0, (200, 200), np.array([43.2, 38.6])), [40.0, 40.0])
    assert np.allclose(_mode(resp, pred, 30.0, 30.0, None, p, 1.0, (200, 200), np.array([66.0, 41.0])), [70.0, 40.0])


def test_the_reach_must_be_a_finite_non_negative_number() -> None:
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="estimate_reach"):
            DCFParams(estimate_reach=bad)


def test_the_map_mean_is_the_limit_of_the_particles_weighted_mean() -> None:
    """The quadrature on the map is what the particles' weighted mean tends to: particles drawn uniformly
    over the map's positions, weighted by the same kappa y(x) + log prior, agree with it to their noise."""
    p = DCFParams()
    resp = _two_peaks(0.3, 0.5)
    pred = np.array([50.0, 40.0])
    exact = _map_mean(resp, pred, 20.0, 20.0, None, p, 1.0, (200, 200))
    rng = np.random.default_rng(0)
    parts = rng.integers(0, 81, size=(200_000, 2)).astype(float)
    lw = p.kappa * resp.y[parts[:, 1].astype(int), parts[:, 0].astype(int)] \
        - 0.5 * (((parts - pred) / 20.0) ** 2).sum(axis=1)
    w = np.exp(lw - lw.max())
    mc = (w[:, None] * parts).sum(axis=0) / w.sum()
    # two peaks 30 px apart, both weighed: the mean lies between them, nearer the likelier far one
    assert 55.0 < exact[0] < 70.0 and abs(exact[1] - 40.0) < 1e-6
    assert np.allclose(mc, exact, atol=0.3)


def test_the_map_mean_of_a_flat_map_is_the_prediction_kept_in_the_frame() -> None:
    p = DCFParams()
    flat = tm.Response(np.zeros((81, 81)), (0.0, 0.0), (1.0, 1.0))
    assert np.allclose(_map_mean(flat, np.array([40.0, 40.0]), 3.0, 3.0, None, p, 1.0, (200, 200)), [40.0, 40.0])
    # a frame 30 px wide: the positions beyond it are not counted
    m = _map_mean(flat, np.array([40.0, 40.0]), 3.0, 3.0, None, p, 1.0, (30, 200))
    assert m[0] <= 29.0


def _one_step(p: DCFParams) -> tuple[tuple[float, ...], np.ndarray]:
    """The box and the detection filter after one frame of dcf_scene's target, moved 3 px right, from its
    first box."""
    first = frame(True)
    moved = np.roll(first, 3, axis=1)
    st, _ = TRACKER.init(p, TRACKER.observe(p, first), (115.5, 82.5, *BOX), FrameRng(1, 7, 0), {})
    st, est = step(TRACKER, p, st, TRACKER.observe(p, moved), FrameRng(1, 7, 1))
    return tuple(est.box), st.model.det


def test_learning_at_the_mode_leaves_the_box_at_the_mean() -> None:
    """``estimate_learn``: the same particles and box as the default's on the frame, a model taught at the
    mode instead; ``estimate_mode`` alone moves the box as well."""
    box0, det0 = _one_step(DCFParams())
    box1, det1 = _one_step(DCFParams(estimate_mode=True, estimate_learn=True))
    box2, det2 = _one_step(DCFParams(estimate_mode=True))
    assert np.allclose(box1, box0)
    assert not np.allclose(det1, det0)
    assert not np.allclose(box2, box0) and np.allclose(det2, det1)


def test_options_that_change_the_mode_need_it() -> None:
    for name in ("estimate_local", "estimate_learn"):
        with pytest.raises(ValueError, match=f"{name} needs estimate_mode"):
            DCFParams(**{name: True})
    with pytest.raises(ValueError, match="estimate_reach needs estimate_local"):
        DCFParams(estimate_mode=True, estimate_reach=1.0)
    with pytest.raises(ValueError, match="estimate_mean and estimate_mode"):
        DCFParams(estimate_mean=True, estimate_mode=True)
