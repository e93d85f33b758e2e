"""dcf through fast motion: the particles drawn at several peaks of the response (gflow_core.dcf.proposal)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.proposal import assign, detections
from gflow_core.dcf.tracker import _particles


def _bumps(h: int, w: int, at: list[tuple[int, int, float]]) -> np.ndarray:
    """(h, w) map of Gaussian bumps of std 2 cells at (row, col) with the given heights."""
    i, j = np.mgrid[0:h, 0:w]
    return sum(v * np.exp(-((i - r) ** 2 + (j - c) ** 2) / 8.0) for r, c, v in at)


def _response(y: np.ndarray) -> tm.Response:
    # map index (i, j) is the image point (100 + j / 0.5, 50 + i / 0.5): 2 image px a map px
    return tm.Response(y=y, origin=(100.0, 50.0), q=(0.5, 0.5))


def test_the_detections_are_the_separate_peaks_best_first_and_one_is_the_maximum_alone() -> None:
    """A copy that scores a little above the target: k = 2 gives both (the copy first), k = 1 the copy
    alone (the proposal before detect_peaks); a bump's own shoulder is no second peak."""
    resp = _response(_bumps(40, 60, [(20, 10, 0.40), (20, 40, 0.42)]))
    one = detections(resp, (10.0, 10.0), 1)
    np.testing.assert_array_equal(one, resp.peak()[0][None, :])
    two = detections(resp, (10.0, 10.0), 2)
    np.testing.assert_allclose(two, [[180.0, 90.0], [120.0, 90.0]])
    # three asked, two bumps: the third is the best placement half a box from both, a shoulder's
    three = detections(resp, (10.0, 10.0), 3)
    assert three.shape == (3, 2)
    np.testing.assert_allclose(three[:2], two)
    assert np.all(np.max(np.abs(three[2][None, :] - two), axis=1) >= 10.0)


def test_the_particles_at_the_response_are_shared_equally_among_the_peaks() -> None:
    """With two peaks, the detect_fraction of the particles falls in two equal groups, one at each peak;
    with one peak (detect_peaks = 1) every one is about the best, as before."""
    p = DCFParams(particles=100, detect_fraction=0.3, detect_std=1.0)
    st = type("S", (), {"velocity": np.zeros(2), "log_s": 0.0})()
    proposed = np.zeros((100, 3))
    peaks = np.array([[180.0, 90.0], [120.0, 90.0]])
    parts = _particles(st, proposed, peaks, 0.0, p, np.random.default_rng(0), 1.0)
    det = parts[70:]
    near = np.argmin(np.abs(det[:, 0][:, None] - peaks[None, :, 0]), axis=1)
    assert np.bincount(near, minlength=2).tolist() == [15, 15]
    one = _particles(st, proposed, peaks[:1], 0.0, p, np.random.default_rng(0), 1.0)
    assert np.all(np.abs(one[70:, 0] - 180.0) < 6.0)
    assert assign(5, 2).tolist() == [0, 1, 0, 1, 0]


@pytest.mark.parametrize("kw", [{"detect_peaks": 0}])
def test_bad_values_are_refused(kw) -> None:
    with pytest.raises(ValueError, match="detect_peaks must be >= 1"):
        DCFParams(**kw)

