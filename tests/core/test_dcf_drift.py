"""Template update with drift correction (``drift_correct``, :mod:`gflow_core.dcf.drift`): the estimate
re-aligned with the first frame's filter.

Unit checks of the alignment on made-up maps, and real frames: ../shared/data/david_indoor with the running
filter taught the face 8 px off, as it learns it when the box slides during the turn to profile: without the
correction the box stays off; with it, it comes back."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf.drift import aligned
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.tracker import TRACKER
from gflow_core.tracker import FrameRng, step
from pipeline.io.frame_readers import folder_frames
from pipeline.recording.results import read_boxes

from conftest import data_dir


def _map(peak: tuple[float, float], size: int = 41, width: float = 3.0) -> tm.Response:
    """A Gaussian bump at image point ``peak`` on a map of ``size``^2 positions, one per image px from (0, 0)."""
    ys, xs = np.mgrid[0:size, 0:size].astype(float)
    an = np.exp(-((xs - peak[0]) ** 2 + (ys - peak[1]) ** 2) / (2 * width ** 2))
    return tm.Response(an, (0.0, 0.0), (1.0, 1.0), an=an)


def test_the_anchors_peak_within_epsilon_is_the_estimate() -> None:
    star = aligned(_map((24.0, 17.0)), np.array([20.0, 20.0]), 6.0)
    assert star is not None and np.allclose(star, [24.0, 17.0])


def test_a_peak_beyond_epsilon_is_no_alignment() -> None:
    # the map still rises at the disk's edge: an ascent from the estimate would go past epsilon
    assert aligned(_map((34.0, 20.0)), np.array([20.0, 20.0]), 6.0) is None
    flat = tm.Response(np.zeros((41, 41)), (0.0, 0.0), (1.0, 1.0), an=np.zeros((41, 41)))
    assert aligned(flat, np.array([20.0, 20.0]), 6.0) is None


def test_epsilon_must_be_a_finite_non_negative_number() -> None:
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="drift_correct"):
            DCFParams(drift_correct=bad)


def _errors_after_drift(frames: list[np.ndarray], gt: dict, p: DCFParams, off: np.ndarray) -> list[float]:
    """Centre errors (px) of frames 1.. after the tracker starts on frame 0's true box with its running filter
    (and its particles) taught the target ``off`` (2,) px away: a drift already learnt."""
    obs = TRACKER.observe(p, frames[0])
    st, _ = TRACKER.init(p, obs, gt[0], FrameRng(1, 7, 0), {})
    c = st.centre + off
    mdl = tm.learn(st.model, obs.image, obs.grey, (float(c[0]), float(c[1])), 0.0, st.geom, p, 1.0, scale=False)
    parts = st.particles.copy()
    parts[:, :2] += off
    st = dataclasses.replace(st, model=mdl, centre=c, particles=parts)
    out = []
    for t in range(1, len(frames)):
        st, est = step(TRACKER, p, st, TRACKER.observe(p, frames[t]), FrameRng(1, 7, t))
        (gx, gy, gw, gh), (x, y, w, h) = gt[t], est.box
        out.append(float(np.hypot(gx + gw / 2 - x - w / 2, gy + gh / 2 - y - h / 2)))
    return out


def test_a_learnt_drift_is_undone_by_the_first_frames_filter() -> None:
    root = data_dir("david_indoor")
    gt = read_boxes(root / "groundtruth.csv")
    frames = [cv2.imread(str(path)) for _, path in list(folder_frames(root / "frames"))[:41]]
    off = np.array([8.0, -8.0])
    kept = _errors_after_drift(frames, gt, DCFParams(drift_correct=0.0), off)
    undone = _errors_after_drift(frames, gt, DCFParams(drift_correct=0.2), off)
    # without the correction the learnt offset is the filter's idea of the target: the box stays off
    assert np.mean(kept[-10:]) > 7.0, kept
    # with it, the first frame's filter's peak (within 0.2 sqrt(w h), about 10 px) takes the box back
    assert np.mean(undone[:5]) < 3.0 and np.mean(undone[-10:]) < 4.0, undone
