"""size_kept: the fraction of on-target frames whose box area is within a factor of the truth; the AUC split into
what the place and the size cost (place_and_size)."""

from __future__ import annotations

import pytest

from gflow_core.evaluation.metrics import auc, place_and_size, size_kept, success_curve


def test_a_collapsing_box_on_the_target_fails_while_its_centre_stays():
    gt = {t: (100.0, 100.0, 40.0, 60.0) for t in range(10)}
    # the same centre, the area shrinking by 1.25x per frame: areas 1, 0.8, 0.64, 0.51, 0.41, ...
    pred = {}
    for t in range(10):
        k = 0.8 ** (t / 2)  # side factor: area factor 0.8^t
        w, h = 40.0 * k, 60.0 * k
        pred[t] = (120.0 - w / 2, 130.0 - h / 2, w, h)
    assert size_kept(gt, pred) == pytest.approx(4 / 10)  # 1, 0.8, 0.64, 0.512 are within 2x
    assert size_kept(gt, pred, factor=4.0) == pytest.approx(7 / 10)


def test_only_frames_on_target_count():
    gt = {0: (0.0, 0.0, 10.0, 10.0), 1: (0.0, 0.0, 10.0, 10.0), 2: (0.0, 0.0, 10.0, 10.0)}
    pred = {0: (0.0, 0.0, 10.0, 10.0), 1: (50.0, 50.0, 1.0, 1.0), 2: (2.0, 2.0, 30.0, 30.0)}
    # frame 1 is off target (no overlap) and ignored; frame 2 is on target and 9x too large
    assert size_kept(gt, pred) == pytest.approx(0.5)
    assert size_kept(gt, {1: (50.0, 50.0, 1.0, 1.0)}) is None
    assert size_kept(gt, {}) is None


def test_a_negative_width_or_height_is_refused_and_a_box_of_no_size_overlaps_nothing():
    """A box reaching back from its corner had its centre on the wrong side of it: (30, 30, -20, -20) against
    (10, 10, 20, 20) scored a centre error of 0, a hit. It is refused, naming the box; a box of no size
    (w or h 0) is a box that overlaps nothing."""
    import numpy as np

    from gflow_core.evaluation.metrics import centre_error, iou, score

    g = np.array([[10.0, 10.0, 20.0, 20.0], [10.0, 10.0, 20.0, 20.0]])
    with pytest.raises(ValueError, match="predicted box 1 has a negative width or height"):
        centre_error(g, np.array([[10.0, 10.0, 20.0, 20.0], [30.0, 30.0, -20.0, -20.0]]))
    with pytest.raises(ValueError, match="ground-truth box 0 has a negative"):
        iou(np.array([[10.0, 10.0, -1.0, 20.0]]), g[:1])
    with pytest.raises(ValueError, match="negative width or height"):
        score({0: (10, 10, 20, 20)}, {0: (30, 30, -20, -20)})
    assert iou(g[:1], np.array([[10.0, 10.0, 0.0, 20.0]]))[0] == 0.0


def test_the_auc_splits_into_what_the_place_and_the_size_cost():
    """A box on the right centre at twice the true size loses overlap to its size alone: with the true size at its
    centre it is perfect; a box of the right size 5 px off loses it to its place alone."""
    gt = {t: (100.0, 100.0, 40.0, 60.0) for t in range(4)}
    big = {t: (80.0, 70.0, 80.0, 120.0) for t in range(4)}  # the same centre (120, 130), twice the size
    perfect = auc(gt, gt)  # 20 / 21: no overlap is above the last threshold, 1
    place, size = place_and_size(gt, big)
    assert auc(gt, place) == pytest.approx(perfect)  # the truth's size at the box's centre: the truth itself
    assert auc(gt, size) == pytest.approx(auc(gt, big))  # the box's size at the truth's centre: the box itself
    assert auc(gt, big) == pytest.approx(float(success_curve(gt, big).mean())) and auc(gt, big) < 0.3
    off = {t: (105.0, 100.0, 40.0, 60.0) for t in range(4)}  # the right size, 5 px right
    place, size = place_and_size(gt, off)
    assert auc(gt, size) == pytest.approx(perfect) and auc(gt, place) == pytest.approx(auc(gt, off))
    assert auc(gt, off) < perfect


def test_the_split_leaves_a_frame_without_a_prediction_a_failure():
    gt = {0: (0.0, 0.0, 10.0, 10.0), 1: (0.0, 0.0, 10.0, 10.0)}
    place, size = place_and_size(gt, {0: (2.0, 2.0, 10.0, 10.0)})
    assert set(place) == set(size) == {0}
    assert auc(gt, place) < auc(gt, size) == pytest.approx(0.5 * auc(gt, gt))
