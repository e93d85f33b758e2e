"""The colour cue (gflow_core.colour): Perez et al.'s bins, histograms that count a box, an integral
histogram scan that agrees with them box by box, and a search that finds a box by its colour; and the
cue's place in the visibility model (gflow_core.visibility.Cue)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gflow_core import colour as col
from gflow_core.visibility import ChiSquare, Cue, visibility


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """A BGR frame of noisy grey clutter with a red-and-yellow target box (x, y, w, h)."""
    img = rng.integers(40, 200, size=(120, 160, 1), dtype=np.uint8).repeat(3, axis=2)
    box = (100, 30, 24, 30)
    x, y, w, h = box
    img[y:y + h, x:x + w] = (0, 0, 220)
    img[y + h // 2:y + h, x:x + w] = (0, 220, 220)
    return img, box


def test_bins_put_coloured_pixels_in_hue_saturation_bins_and_grey_ones_in_value_bins():
    img = np.zeros((2, 3, 3), np.uint8)
    img[0, 0] = (0, 0, 255)  # red: hue 0, saturated
    img[0, 1] = (255, 0, 0)  # blue: hue 120
    img[0, 2] = (128, 128, 128)  # grey: a value bin
    img[1] = (10, 10, 10)  # dark: a value bin
    b = col.bins(img)
    assert b[0, 0] < col.N_H * col.N_S and b[0, 1] < col.N_H * col.N_S and b[0, 0] != b[0, 1]
    assert b[0, 2] >= col.N_H * col.N_S and b[1, 0] >= col.N_H * col.N_S and b[0, 2] != b[1, 0]
    grey = col.bins(img[..., 1])
    assert (grey >= col.N_H * col.N_S).all()
    # a float image in [0, 1] is binned as its uint8 self
    assert (col.bins(img.astype(np.float32) / 255.0) == b).all()


def test_scan_gives_the_bhattacharyya_coefficient_of_each_box_and_finds_the_target_by_colour():
    rng = np.random.default_rng(0)
    img, (x, y, w, h) = _scene(rng)
    b = col.bins(img)
    centre = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0])
    stride = col.stride_for((w, h))
    ref = col.histogram(b, centre, (w, h), stride)
    assert ref is not None and math.isclose(ref.sum(), 1.0) and ref.shape == (col.N_BINS,)
    assert math.isclose(col.bhattacharyya(ref, [ref]), 1.0)
    # search the whole frame from its middle: the best box is the target's
    sc = col.scan(b, np.array([80.0, 60.0]), (80.0, 60.0), (w, h), [ref], stride)
    assert sc is not None
    best = sc.best()
    assert best is not None and best[0] > 0.95 and np.abs(best[1] - centre).max() <= stride
    # box by box, the scan equals the histogram of the same samples
    i, j = 5, 7
    hist = col.histogram(b, np.array([sc.xs[j], sc.ys[i]]), (stride * round(w / stride), stride * round(h / stride)), stride)
    assert hist is not None and math.isclose(sc.raw[i, j], col.bhattacharyya(hist, [ref]), rel_tol=1e-9)
    # away from the target, the best colour is clutter's (grey: no red or yellow)
    away = sc.away(centre, (float(w), float(h)))
    far = sc.best(away)
    assert far is not None and far[0] < 0.5
    # read at any centre, the grid's value
    assert math.isclose(float(sc.at(np.array([sc.xs[j]]), np.array([sc.ys[i]]))[0]), sc.raw[i, j], rel_tol=1e-6)


def test_a_box_outside_the_frame_has_no_histogram_and_a_region_smaller_than_the_box_no_scan():
    b = col.bins(np.full((20, 20, 3), 100, np.uint8))
    assert col.histogram(b, np.array([-50.0, -50.0]), (10.0, 10.0), 1) is None
    assert col.scan(b, np.array([10.0, 10.0]), (1.0, 1.0), (40.0, 40.0), [np.ones(col.N_BINS) / col.N_BINS], 1) is None


def _learnt(mean: float, std: float, rng: np.random.Generator) -> ChiSquare:
    m = ChiSquare()
    for v in np.clip(rng.normal(mean, std, 400), 0.0, 1.0):
        m = m.update(float(v), 0.01)
    return m


def test_a_second_cue_multiplies_in_and_decides_where_the_first_is_in_doubt():
    rng = np.random.default_rng(2)
    target, clutter = _learnt(0.3, 0.08, rng), _learnt(0.7, 0.08, rng)
    ctarget, cclutter = _learnt(0.05, 0.02, rng), _learnt(0.4, 0.08, rng)
    # the edges alone: a distance between the two is in doubt
    alone = visibility(0.62, target, clutter, 0.05, prior=(0.001, 0.0, 0.999))
    assert alone.visible < 0.5
    # the colour of the target there: visible
    agree = visibility(0.62, target, clutter, 0.05, prior=(0.001, 0.0, 0.999), cues=(Cue(0.05, ctarget, cclutter),))
    assert agree.visible > 0.5
    # the colour of clutter there: hidden, more surely than the edges alone said
    differ = visibility(0.62, target, clutter, 0.05, cues=(Cue(0.45, ctarget, cclutter),))
    assert differ.hidden > visibility(0.62, target, clutter, 0.05).hidden
    # a candidate that is the best of many colour boxes needs a closer colour match
    many = visibility(0.62, target, clutter, 0.05, prior=(0.001, 0.0, 0.999),
                      cues=(Cue(0.15, ctarget, cclutter, trials=200.0),))
    few = visibility(0.62, target, clutter, 0.05, prior=(0.001, 0.0, 0.999), cues=(Cue(0.15, ctarget, cclutter),))
    assert many.visible < few.visible
    # a cue with nothing learnt yet is left out
    assert visibility(0.62, target, clutter, 0.05, cues=(Cue(0.05, ChiSquare(), cclutter),)) == visibility(
        0.62, target, clutter, 0.05)


@pytest.mark.parametrize("shape", [(30, 40, 3), (30, 40), (30, 40, 4), (30, 40, 1)])
def test_bins_accept_every_image_layout_the_tracker_accepts(shape):
    img = np.random.default_rng(3).integers(0, 255, size=shape, dtype=np.uint8)
    b = col.bins(img)
    assert b.shape == (30, 40) and b.dtype == np.uint8 and int(b.max()) < col.N_BINS


def test_a_grey_frame_has_no_colour_and_the_preprocessing_sends_no_bins_for_it() -> None:
    """A grey video stored as colour (three equal channels) has no colour: ``is_grey`` says so, and the
    preprocess stage asked for colour bins sends them for a colour frame only (the contour trackers'
    lost guard then weighs the edges alone)."""
    from stages.base import StageContext
    from gflow_msgs.messages import Frame, Header, NDArray
    from stages.preprocess import PreprocessParams, PreprocessStage

    rng = np.random.default_rng(0)
    grey = rng.integers(0, 256, (40, 50), dtype=np.uint8)
    as_colour = np.repeat(grey[..., None], 3, axis=2)
    tinted = as_colour.copy()
    tinted[5, 7, 2] ^= 1  # one pixel whose channels differ
    assert col.is_grey(grey) and col.is_grey(as_colour) and col.is_grey(grey[..., None])
    assert not col.is_grey(tinted)
    pre = PreprocessStage(PreprocessParams(colour=True), StageContext("preprocess", "s"))
    sent = []
    for t, img in enumerate((as_colour, tinted)):
        (_, f), = pre.step(t, {"frames": Frame(Header("s", t, t * 40_000_000), NDArray.of(img))})
        sent.append(getattr(f, "bins", None))
    assert sent[0] is None and sent[1] is not None
    assert np.array_equal(sent[1].array(), col.bins(tinted))
