"""frames_to_recover and state_score: getting the target back, and whether the reported state was right."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.evaluation.metrics import frames_to_recover, overlaps, state_score


def test_frames_to_recover_counts_to_the_first_run_on_target():
    ov = np.array([0.9, 0.9, 0.0, 0.0, 0.0, 0.6, 0.0, 0.7, 0.7, 0.7, 0.7, 0.7, 0.1])
    assert frames_to_recover(ov, 2) == 5  # index 7 starts five in a row; the single 0.6 at 5 does not count
    assert frames_to_recover(ov, 0, hold=2) == 0
    assert frames_to_recover(ov, 2, hold=6) is None
    assert frames_to_recover(np.array([0.0, 0.0, 0.8, 0.8]), 0) == 2  # the sequence ends on target
    assert frames_to_recover(np.array([0.0, 0.0]), 0) is None
    with pytest.raises(ValueError, match="outside"):
        frames_to_recover(ov, 20)


def test_frames_to_recover_on_sparse_ground_truth_counts_frames_not_entries():
    # a box every 5th frame: 0, 5, ..., 45; off target on 10-20, back from 25
    frames = np.arange(0, 50, 5)
    ov = np.array([0.9, 0.9, 0.0, 0.1, 0.2, 0.8, 0.8, 0.8, 0.8, 0.8])
    assert frames_to_recover(ov, 10, frames=frames) == 15  # frame 25 starts a run spanning >= 5 frames (25, 30)
    assert frames_to_recover(ov, 0, frames=frames) == 0
    assert frames_to_recover(ov, 12, frames=frames) == 13  # from the first scored frame at or after 12
    assert frames_to_recover(ov, 10, hold=30, frames=frames) == 15  # the run reaches the end on target
    assert frames_to_recover(ov[:6], 10, hold=30, frames=frames[:6]) == 15
    assert frames_to_recover(np.array([0.9, 0.9, 0.0, 0.0]), 0, frames=np.array([10, 15, 20, 25]), hold=2) == 0
    # one scored frame on target spans one frame: not a run of 2, unless the sequence ends on it
    assert frames_to_recover(np.array([0.9, 0.0, 0.9, 0.0]), 10, frames=np.array([10, 15, 20, 25]), hold=2) is None
    # every frame given: the same as without frames
    dense = np.array([0.9, 0.0, 0.0, 0.7, 0.7, 0.7, 0.7, 0.7])
    assert frames_to_recover(dense, 1, frames=np.arange(8)) == frames_to_recover(dense, 1) == 2
    with pytest.raises(ValueError, match="same shape"):
        frames_to_recover(ov, 0, frames=frames[:3])


def test_state_score_grace_counts_frames_on_sparse_ground_truth():
    # a box every 5th frame; hidden on frames 10-30: past the 5-frame grace from frame 15 on
    frames = np.arange(0, 45, 5)
    visible = np.array([1, 1, 0, 0, 0, 0, 0, 1, 1], dtype=float)
    states = ["tracked", "tracked", "tracked", "occluded", "lost", "lost", "tracked", "tracked", "tracked"]
    s = state_score(states, visible, frames=frames)
    assert (s.hidden, s.hidden_right) == (4, 3)  # frames 15, 20, 25, 30; 30 said tracked
    assert (s.shown, s.shown_right) == (4, 4)
    dense = state_score(states, visible)  # read as consecutive frames, only the 5th hidden entry on is scored
    assert dense.hidden == 0


def test_overlaps_is_zero_where_a_prediction_is_missing():
    gt = {0: (0.0, 0.0, 10.0, 10.0), 1: (0.0, 0.0, 10.0, 10.0)}
    assert overlaps(gt, {0: (0.0, 0.0, 10.0, 10.0)}).tolist() == [1.0, 0.0]


def test_state_score_scores_hidden_frames_past_the_grace_and_undisturbed_frames():
    # 4 visible, 8 hidden, 1 half hidden, 3 visible after; frames 12 and 13-15 perturbed / not
    visible = np.array([1, 1, 1, 1] + [0] * 8 + [0.5] + [1, 1, 1], dtype=float)
    perturbed = np.array([0] * 4 + [1] * 9 + [0] * 3, dtype=bool)
    states = (["tracked"] * 4 + ["tracked"] * 5 + ["occluded", "lost", "tracked"] + ["occluded"]
              + ["lost", "tracked", "tracked"])
    s = state_score(states, visible, perturbed)
    assert (s.hidden, s.hidden_right) == (3, 2)  # frames 9-11 scored (the first 5 hidden are not)
    assert (s.shown, s.shown_right) == (7, 6)  # frames 0-3 and 13-15; 13 says lost
    assert s.hidden_rate == pytest.approx(2 / 3) and s.shown_rate == pytest.approx(6 / 7)
    # without the perturbed column, frames with the whole target in view are the undisturbed ones
    s2 = state_score(states, visible, None)
    assert (s2.shown, s2.shown_right) == (7, 6)
    # a frame with no state counts as wrong
    s3 = state_score([None] * 16, visible, perturbed)
    assert s3.hidden_right == 0 and s3.shown_right == 0 and s3.hidden == 3


def test_state_score_refuses_unknown_states_and_mismatched_lengths():
    with pytest.raises(ValueError, match="unknown target state 'hidden'"):
        state_score(["hidden"], np.array([0.0]))
    with pytest.raises(ValueError, match="one value per frame"):
        state_score(["tracked"], np.array([1.0, 1.0]))


def test_no_hidden_frames_means_no_rate():
    s = state_score(["tracked"] * 3, np.ones(3))
    assert s.hidden == 0 and s.hidden_rate is None and s.shown_rate == 1.0
    assert s.to_json()["hidden_reported_occluded_or_lost"] is None


def test_state_score_counts_boxes_off_a_target_in_view_that_were_said_tracked():
    visible = np.array([1, 1, 1, 0, 0, 1, 1, 0.5], dtype=float)
    overlap = np.array([0.9, 0.2, 0.0, 0.0, 0.0, 0.5, 0.0, 0.3])
    states = ["tracked", "tracked", "occluded", "tracked", "lost", "tracked", "lost", "tracked"]
    s = state_score(states, visible, overlap=overlap)
    # off: in view with overlap <= 0.5 -> frames 1, 2, 5, 6, 7 (3 and 4 are hidden: not scored)
    assert (s.off, s.off_tracked) == (5, 3) and s.off_rate == pytest.approx(3 / 5)
    assert s.to_json()["off_target_reported_tracked"] == pytest.approx(0.6)
    assert state_score(states, visible).off == 0  # without overlaps nothing is scored
    with pytest.raises(ValueError, match="same shape"):
        state_score(states, visible, overlap=overlap[:3])


def test_state_score_counts_frames_on_target_per_confidence_band():
    visible = np.array([1, 1, 1, 0, 1, 1], dtype=float)
    overlap = np.array([0.9, 0.1, 0.8, 0.0, 0.7, 0.6])
    conf = np.array([0.1, 0.2, 0.6, 0.9, 0.97, np.nan])
    s = state_score(["tracked"] * 6, visible, overlap=overlap, confidence=conf)
    # bands [0, .25) [.25, .5) [.5, .75) [.75, .95) [.95, 1]; frame 3 is hidden, frame 5 has no confidence
    assert s.bands == ((2, 1), (0, 0), (1, 1), (0, 0), (1, 1))
    js = s.to_json()["confidence_bands"]
    assert js[0] == {"from": 0.0, "to": 0.25, "frames": 2, "on_target": 0.5} and js[1]["on_target"] is None
    assert state_score(["tracked"] * 6, visible, overlap=overlap).bands == ()
