"""A hidden target found again by a candidate track (``search_track``, :mod:`gflow_core.dcf.trackscore`): the
search's best placements summed as a track score, the log likelihood ratio of "one object moving" against
"clutter" (uniform, or the still object of the last frame).

Unit checks of the score, and real frames: ../shared/data/surfer at every 3rd frame (``gflow benchmark
--variant fast``), where a camera jolt loses the surfer's head and no single frame of the search gets it
back."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from gflow import Tracker
from gflow_core.dcf import tracker as tr
from gflow_core.dcf import trackscore as ts
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER
from gflow_core.evaluation.metrics import iou
from pipeline.io.frame_readers import folder_frames
from pipeline.recording.results import read_boxes

from conftest import data_dir

P = DCFParams()
#: the candidate track dropped as soon as its log odds are below the prior's (the rule before search_track_wald)
P_OFF = dataclasses.replace(P, search_track_wald=False)
SIDE, CELL, AREA = 30.0, (3.0, 3.0), 200.0 * 300.0


def _run(steps: list[tuple[float, float]], signal: float = 0.0, speed2: float = 25.0) -> list[ts.Track]:
    """The tracks after each placement of ``steps``, every one with the same signal and a place term of 0."""
    out: list[ts.Track] = []
    track = None
    for c in steps:
        track = ts.extend(track, np.array(c), signal, 0.0, SIDE, CELL, speed2, AREA, 1.0, P)
        out.append(track)
    return out


def test_a_track_of_one_frame_is_scored_as_the_frame_alone() -> None:
    (first,) = _run([(100.0, 100.0)], signal=-1.5)
    assert first.n == 1 and first.score == -1.5 and first.motion == 0.0
    assert ts.log_odds(first, P) == pytest.approx(math.log(P.reappear / (1 - P.reappear)) - 1.5)


def test_an_object_moving_steadily_gains_each_frame_and_a_still_one_does_not() -> None:
    # 12 px a frame: four cells of the response grid, 0.4 of the target's side
    moving = _run([(100.0 + 12.0 * t, 100.0 + 4.0 * t) for t in range(6)])
    still = _run([(100.0, 100.0)] * 6)
    gains = np.diff([t.score for t in moving])
    # once the velocity is known each frame's kinematic term is about log(A / (2 pi var)) - log 2: several nats
    assert (gains[1:] > 3.0).all() and gains[0] > 0
    assert moving[-1].n == 6 and ts.log_odds(moving[-1], P) > 0
    # the still object of the last frame explains a placement that did not move at least as well as a target
    assert all(t.score <= 1e-9 for t in still)


def test_a_placement_outside_the_gate_starts_a_new_track() -> None:
    tracks = _run([(100.0, 100.0), (106.0, 102.0), (112.0, 104.0), (250.0, 40.0)])
    assert [t.n for t in tracks] == [1, 2, 3, 1]
    assert tracks[-1].score == 0.0 and tracks[-1].signal == 0.0


def test_a_track_whose_evidence_runs_against_it_is_dropped() -> None:
    """Once the score is below 0 (the log odds below the prior's), the next placement starts a new track."""
    track = None
    tracks = []
    for t, signal in enumerate([0.0, -40.0, 0.0]):
        track = ts.extend(track, np.array([100.0 + 12.0 * t, 100.0]), signal, 0.0, SIDE, CELL, 25.0, AREA, 1.0, P_OFF)
        tracks.append(track)
    assert tracks[1].n == 2 and ts.log_odds(tracks[1], P_OFF) < math.log(P.reappear / (1 - P.reappear))
    assert tracks[2].n == 1 and tracks[2].signal == 0.0


def test_walds_lower_threshold_mirrors_the_upper_one() -> None:
    """Off, a track is dropped once its score is below 0; with search_track_wald (the default) at -log A, log A
    the upper threshold's log likelihood ratio (equal error rates: B = 1 / A)."""
    assert ts.lower(P_OFF) == 0.0
    upper = ts.logit(P.search_track) - ts.logit(P.reappear)
    assert upper > 9.0 and ts.lower(P) == pytest.approx(-upper)
    from gflow_core.params import added_later

    assert P.search_track_wald and added_later(DCFParams)["search_track_wald"] is False


def test_with_wald_a_moving_track_whose_look_runs_against_it_is_kept_until_its_motion_outweighs_it() -> None:
    """A placement that moves as one object but scores like clutter (a blurred target): dropped on every
    frame without the option, so its motion never counts; kept with it, and taken once the motion outweighs
    the look."""
    steps = [(100.0 + 12.0 * t, 100.0 + 4.0 * t) for t in range(8)]
    wald = P
    off, on = [], []
    t_off = t_on = None
    for c in steps:
        t_off = ts.extend(t_off, np.array(c), -4.0, 0.0, SIDE, CELL, 25.0, AREA, 1.0, P_OFF)
        t_on = ts.extend(t_on, np.array(c), -4.0, 0.0, SIDE, CELL, 25.0, AREA, 1.0, wald)
        off.append(t_off)
        on.append(t_on)
    assert [t.n for t in off] == [1] * len(steps)
    assert [t.n for t in on] == list(range(1, len(steps) + 1))
    assert ts.log_odds(on[-1], wald) >= ts.logit(wald.search_track) > ts.log_odds(on[0], wald)


def test_with_wald_a_track_below_the_mirrored_threshold_is_dropped() -> None:
    wald = P
    track = None
    tracks = []
    for t, signal in enumerate([0.0, -40.0, 0.0]):
        track = ts.extend(track, np.array([100.0 + 12.0 * t, 100.0]), signal, 0.0, SIDE, CELL, 25.0, AREA, 1.0, wald)
        tracks.append(track)
    assert tracks[1].n == 2 and tracks[1].score < ts.lower(wald)
    assert tracks[2].n == 1 and tracks[2].signal == 0.0


def test_the_track_survives_a_snapshot_bit_for_bit() -> None:
    seq = data_dir("crossing")
    paths = dict(folder_frames(seq / "frames"))
    p = DCFParams(search_track=0.5)
    st = tr.initialise(TRACKER.observe(p, cv2.imread(str(paths[0]))), read_boxes(seq / "groundtruth.csv")[0], p,
                       np.random.default_rng(0))
    assert st.track is None
    track = ts.Track(np.array([10.5, 20.25]), np.array([1.0, -2.0]), -3.75, 5.5, 4)
    arrays, values = to_arrays(dataclasses.replace(st, track=track))
    back = from_arrays(arrays, values, p).track
    assert back is not None and back.to_array().tobytes() == track.to_array().tobytes()
    assert from_arrays(*to_arrays(st), p).track is None
    with pytest.raises(ValueError, match="7 numbers"):
        ts.Track.of_array(np.zeros(6))


def test_the_option_is_checked_and_off_for_recordings_made_before_it() -> None:
    from gflow_core.params import added_later

    assert DCFParams().search_track == 0.95
    assert added_later(DCFParams)["search_track"] == 0.0
    for bad in (0.3, 1.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="search_track"):
            DCFParams(search_track=bad)


def _fast_overlap(name: str, seed: int = 1, **params: object) -> float:
    """Mean overlap with the label on a shared sequence's labelled frames, played at every 3rd frame from
    frame 0, dcf with ``params``."""
    seq = data_dir(name)
    truth = read_boxes(seq / "groundtruth.csv")
    paths = dict(folder_frames(seq / "frames"))
    kept = [i for i in sorted(paths) if i % 3 == 0]
    tracker = Tracker("dcf", seed=seed, **params)
    overlaps = []
    for i in kept:
        image = cv2.imread(str(paths[i]), cv2.IMREAD_COLOR)
        if i == 0:
            tracker.init(image, truth[0])
            continue
        box = tracker.update(image).box
        if i in truth:
            overlaps.append(float(iou(np.array([truth[i]]), np.array([box]))[0]))
    return float(np.mean(overlaps))


#: the tracker as the surfer's loss was traced: before colour names, the small target's scale and the roll at
#: detection were on by default (with them the jolt does not lose the head: mean overlap about 0.64 without the track)
TRACED = {"colour_names": False, "scale_upsample": False, "roll_detect": False}


def test_the_surfer_at_every_third_frame_is_found_again() -> None:
    """Without the track the head is lost to a camera jolt and never taken back (mean overlap about 0.1);
    with it the search's placements on the head are taken after a few frames."""
    without = _fast_overlap("surfer", search_track=0.0, **TRACED)
    with_track = _fast_overlap("surfer", search_track=0.95, **TRACED)
    assert without < 0.3  # the check can fail: without the track the head stays lost
    assert with_track > 0.45


def test_tigers_toy_at_every_third_frame_is_taken_back_on_more_frames_with_walds_threshold() -> None:
    """The toy, blurred and reversing, is lost by kept frame 14 either way; its search's placements score
    like clutter, so without Wald's lower threshold every candidate track is dropped after one frame, and
    with it the track lasts until its motion takes the toy back on some frames (mean overlap about 0.10
    against 0.14 with seed 1, 0.17 with seed 2)."""
    without = _fast_overlap("tiger1", search_track_wald=False)
    with_wald = _fast_overlap("tiger1", search_track_wald=True)
    assert with_wald > without + 0.02
