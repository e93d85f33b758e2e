"""dcf with a look-alike beside the target (``lookalike_doubt``, :mod:`gflow_core.dcf.lookalike`): the unit
rule, and skating1 on the real frames, where other skaters pass beside the target."""

from __future__ import annotations

from gflow_core.dcf.lookalike import beside
from gflow_core.visibility import ChiSquare


def _dist(mean: float, std: float, n: int = 20) -> ChiSquare:
    d = ChiSquare()
    for k in range(n):  # samples at mean +- std: running moments of that mean and spread
        d = d.update(mean + (std if k % 2 else -std), 1.0 / (k + 1))
    return d


def test_a_runner_up_that_scores_as_the_target_is_a_look_alike():
    target, clutter = _dist(0.6, 0.05), _dist(0.85, 0.04)
    assert beside(target, clutter, (0.38, 100.0), 0.02)  # rho 0.62: the target's
    assert not beside(target, clutter, (0.14, 100.0), 0.02)  # rho 0.86: the clutter's
    assert not beside(target, clutter, None, 0.02)  # no place away from the estimate
    assert not beside(ChiSquare(), clutter, (0.38, 100.0), 0.02)  # nothing learnt of the target yet


def _doubted(doubt: bool, frames: int = 200, first: bool = False) -> list[int]:
    """The frames of skating1 (seed 1, from its first box) on which the target was tracked and nothing was learnt:
    its velocity, size, distance distributions and model all the last frame's (the frames ``lookalike_doubt``
    holds back); with ``first``, only the first such frame (tracking stops there)."""
    import cv2

    import gflow
    from pipeline.io.frame_readers import folder_frames
    from pipeline.recording.results import read_boxes
    from tests.conftest import data_dir

    seq = data_dir("skating1")
    paths = dict(folder_frames(seq / "frames"))
    tracker = gflow.Tracker("dcf", seed=1, lookalike_doubt=doubt)
    tracker.init(cv2.imread(str(paths[0])), read_boxes(seq / "groundtruth.csv")[0])
    held = []
    for t in range(1, frames):
        before = tracker.state
        tracker.step(cv2.imread(str(paths[t])), t)
        after = tracker.state
        if (after.target_state == "tracked" and after.velocity.tobytes() == before.velocity.tobytes()
                and after.log_s == before.log_s and after.model is before.model and after.target is before.target
                and after.clutter is before.clutter):
            held.append(t)
            if first:
                break
    return held


def test_skating1_frames_with_a_skater_beside_her_teach_nothing():
    """skating1: other skaters pass beside the target under stage light. With ``lookalike_doubt`` the frames on
    which one of them scores as she does are tracked and teach nothing (model, size, distributions, velocity);
    without it no tracked frame of the first 200 leaves them all as they were. (Its AUC on skating1 is not
    asserted: with seed 1 it was 0.57 against the default's 0.49 on one kind of machine and 0.45 against 0.57 on
    another, where other SIMD kernels round the last bits otherwise; docs/dcf-development.md.) The run with the
    option stops at the first frame held back (frame 65 here, of 65 and 175-178), the one without it runs all 200."""
    held = _doubted(True, first=True)
    assert held, "no frame of skating1's first 200 was held back as a look-alike's"
    assert _doubted(False) == []
