"""The chamfer tracker's hold that follows the filter where the edges still fit (``lost_follow``,
gflow_core/contour/tracker.py and :func:`gflow_core.contour.template.still_fits`): the edge
model's test on a synthetic outline, and on real frames (skating1, where the lost guard's
orientation cue judges the turning skater lost by frame 11) the reported box following her while
the guard holds, where the hold of before stands still."""

from __future__ import annotations

import csv

import numpy as np
import pytest

import gflow
from gflow_core import features
from gflow_core.contour.params import ChamferParams, M2Params
from gflow_core.contour.template import still_fits, template_at

from conftest import data_dir


def _square(size: int = 80, at: tuple[int, int] = (40, 40), half: int = 10) -> np.ndarray:
    img = np.zeros((size, size), np.uint8)
    img[at[1] - half: at[1] + half, at[0] - half: at[0] + half] = 200
    return img


def test_still_fits_where_the_outline_is_and_not_beside_it() -> None:
    e, cham = features.edges_and_chamfer(_square(), (50.0, 150.0), 1.0, 80.0, "truncated", 100.0)
    tpl = template_at(e, np.array([39.5, 39.5, 0.0, 1.0]), np.array([30.0, 30.0]), 200)
    assert tpl is not None
    at = np.array([39.5, 39.5, 0.0, 1.0])
    beside = np.array([39.5 + 15.0, 39.5, 0.0, 1.0])
    # on the first frames the template fitted with a mean rho of 0.5 (sum 2.5 over 5 frames)
    assert still_fits(cham, tpl, at, (2.5, 5), 5.0)
    assert not still_fits(cham, tpl, beside, (2.5, 5), 5.0)
    # no fit measured yet (the first frames not over, or the template update off): the hold stands
    assert not still_fits(cham, tpl, at, (0.0, 0), 5.0)


def test_lost_follow_is_the_chamfer_trackers_only() -> None:
    """On by default for chamfer; the M2 tracker, which shares the filter, keeps the plain hold."""
    assert ChamferParams().lost_follow is True
    assert not hasattr(M2Params(), "lost_follow")


def _iou(a, b) -> float:
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    i = ix * iy
    return i / (a[2] * a[3] + b[2] * b[3] - i)


def test_skating1_box_follows_the_skater_while_the_guard_holds() -> None:
    d = data_dir("skating1")
    with open(d / "groundtruth.csv") as f:
        gt = {int(r[0]): [float(v) for v in r[1:5]] for r in list(csv.reader(f))[1:]}
    stop = 60
    runs = {follow: list(gflow.track(d, init=gt[0], tracker="chamfer", seed=1, stop=stop, lost_follow=follow))
            for follow in (False, True)}
    held, followed = runs[False], runs[True]
    lost = [e.frame for e in followed if e.phase == "lost"]
    # the guard judges the skater lost early on both runs (its cue, not the filter, is what fails here)
    assert lost and lost[0] < 20 and [e.frame for e in held if e.phase == "lost"][:1] == lost[:1]
    # the hold of before stands still; the followed box moves
    held_boxes = {tuple(e.box) for e in held if e.phase == "lost"}
    assert len(held_boxes) == 1
    assert len({tuple(e.box) for e in followed if e.phase == "lost"}) > 10
    # and is nearer the skater over the lost frames
    late = [t for t in lost if t >= 40]
    assert late
    iou_f = np.mean([_iou(followed[t].box, gt[t]) for t in late])
    iou_h = np.mean([_iou(held[t].box, gt[t]) for t in late])
    assert iou_f > iou_h + 0.1
