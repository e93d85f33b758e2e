"""The posterior's mode as dcf's estimate (``estimate_mode``, off by default: docs/dcf-development.md).

On made-up response maps: the mode weighs the response against the motion prior as the particles' weights
do (a higher peak far from the prediction loses to a lower one at it when the prior says so, and wins when
the prior is wide), and never leaves the frame."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.tracker import _mode


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
