"""The dcf first filter trained on warped copies of the first window (``augment``, :mod:`gflow_core.dcf.augment`)
and the running filter's rate while it is young (``young``, :mod:`gflow_core.dcf.rates`)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf.augment import copies, warps
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.rates import filter_rate
from gflow_core.dcf.tracker import TRACKER
from pipeline.io.frame_readers import folder_frames
from pipeline.recording.results import read_boxes

from conftest import data_dir


def _centroid(patch: np.ndarray) -> tuple[float, float]:
    w = patch - patch.min()
    ys, xs = np.mgrid[: patch.shape[0], : patch.shape[1]]
    return float((w * xs).sum() / w.sum()), float((w * ys).sum() / w.sum())


def test_the_copies_roll_resize_and_blur_about_the_target() -> None:
    """A bright bar at the target's centre: every copy keeps its centroid at the window's centre; the rolled
    copies turn the bar by the angles asked, the blurred one spreads it."""
    grey = np.zeros((200, 260), np.float32)
    cv2.rectangle(grey, (110, 96), (150, 104), 255.0, -1)  # a 41 x 9 bar centred at (130, 100)
    p = DCFParams(augment=0.5, augment_roll=30.0, augment_scale=0.1, augment_blur=2.0)
    assert [w[0] for w in warps(p)] == pytest.approx([10, -10, 20, -20, 30, -30, 0, 0, 0])
    out = copies(grey, (130.0, 100.0), (81, 61), (1.0, 1.0), p)
    assert len(out) == 9 and all(c.shape == (61, 81) and c.dtype == np.float32 for c in out)
    for c, (angle, log_f, blur) in zip(out, warps(p)):
        cx, cy = _centroid(c)
        assert abs(cx - 40.0) < 0.5 and abs(cy - 30.0) < 0.5
        # the bar's main axis from the second moments: cv2's positive angle turns it anticlockwise on screen
        m = cv2.moments(c)
        axis = 0.5 * np.degrees(np.arctan2(2.0 * m["mu11"], m["mu20"] - m["mu02"]))
        assert axis == pytest.approx(-angle, abs=1.5)
    assert (out[-1] > 10).sum() > (out[6] > 10).sum()  # the blurred copy is wider than the resized one
    assert warps(DCFParams(augment=0.5, augment_roll=0.0, augment_scale=0.0, augment_blur=0.0)) == []


@pytest.mark.parametrize("mask", [1.0, 0.0])
def test_a_rolled_target_stands_out_more_with_augmented_copies(mask: float) -> None:
    """david_indoor's first frame rolled about the face: the first filter's response at the face against
    its best half a box away is higher with the copies at 20 and 30 degrees (the masked filter and the
    closed form alike)."""
    d = data_dir("david_indoor")
    img = cv2.imread(str(folder_frames(d / "frames")[0][1]))
    box = read_boxes(d / "groundtruth.csv")[0]
    c0 = (box[0] + (box[2] - 1) / 2.0, box[1] + (box[3] - 1) / 2.0)
    ratios = {}
    for a in (0.0, 0.5):
        p = DCFParams(augment=a, mask=mask)
        o = TRACKER.observe(p, img)
        geom = tm.geometry((box[2], box[3]), p)
        m = tm.init_model(o.image, o.grey, o.is_grey, c0, geom, p)
        for angle in (0, 20, 30):
            rolled = cv2.warpAffine(img, cv2.getRotationMatrix2D(c0, angle, 1.0), (img.shape[1], img.shape[0]),
                                    borderMode=cv2.BORDER_REPLICATE)
            o2 = TRACKER.observe(p, rolled)
            r = tm.respond(m, o2.image, o2.grey, c0, 0.0, geom, p)
            away = r.best_away(np.array(c0), (0.5 * box[2], 0.5 * box[3]), "cf")
            assert away is not None
            ratios[a, angle] = float(r.at(np.array([c0]), "cf")[0]) / away[0]
    assert ratios[0.5, 20] > 1.1 * ratios[0.0, 20] and ratios[0.5, 30] > 1.1 * ratios[0.0, 30]
    # unrolled the face still stands out: near the first frame's own ratio, or far above 1 (the closed form's
    # response to its own training sample is a spike, 320 times its best away; 25 times with the copies)
    assert ratios[0.5, 0] > min(0.85 * ratios[0.0, 0], 5.0)


def test_without_copies_the_first_filter_is_the_first_frames() -> None:
    """augment > 0 with every warp off leaves the model as augment 0 makes it, bit for bit."""
    rng = np.random.default_rng(3)
    img = (rng.random((120, 160)) * 255).astype(np.uint8)
    p0 = DCFParams()
    p1 = DCFParams(augment=0.7, augment_roll=0.0, augment_scale=0.0, augment_blur=0.0)
    o = TRACKER.observe(p0, img)
    geom = tm.geometry((30.0, 24.0), p0)
    m0 = tm.init_model(o.image, o.grey, o.is_grey, (80.0, 60.0), geom, p0)
    m1 = tm.init_model(o.image, o.grey, o.is_grey, (80.0, 60.0), geom, p1)
    assert np.array_equal(m0.det, m1.det) and np.array_equal(m0.anchor, m1.anchor)


def test_the_young_filters_rate_is_the_mean_of_the_frames_seen_until_it_reaches_eta() -> None:
    p = DCFParams(rate=0.02)
    assert [filter_rate(p, n) for n in (0, 5, 100)] == [0.02, 0.02, 0.02]
    y = DCFParams(rate=0.02, young=1.0)
    # eta_n = max(eta, 1 / (n0 + n + 1)): 1/2, 1/3, ... down to eta after 1 / eta frames
    assert [filter_rate(y, n) for n in (0, 1, 2)] == pytest.approx([1 / 2, 1 / 3, 1 / 4])
    assert filter_rate(y, 47) == pytest.approx(1 / 49) and filter_rate(y, 48) == 0.02 and filter_rate(y, 500) == 0.02
    assert filter_rate(DCFParams(young=3.0), 0) == pytest.approx(1 / 4)
    # the running filter so learnt is the plain mean of its samples: two frames give equal weights
    x0, x1, x2 = (np.full((3, 2, 1), v, complex) for v in (1.0, 4.0, 10.0))
    m = x0
    for n, x in enumerate((x1, x2)):
        a = filter_rate(y, n)
        m = (1.0 - a) * m + a * x
    assert np.allclose(m, (x0 + x1 + x2) / 3.0)


@pytest.mark.parametrize("bad", [dict(augment=1.5), dict(augment=-0.1), dict(augment_roll=-5.0), dict(augment_roll=120.0),
                                 dict(augment_scale=float("nan")), dict(augment_blur=-1.0), dict(young=-1.0),
                                 dict(young=float("inf"))])
def test_mistyped_settings_are_refused_by_name(bad: dict) -> None:
    name = next(iter(bad))
    with pytest.raises(ValueError, match=name):
        DCFParams(**bad)


def test_both_are_off_by_default_so_older_recordings_read_them_as_the_code_before() -> None:
    """Off by default, neither needs ``param(before=...)``: a plan recorded before they existed reads
    today's default, which is what the code did then (turned on by default, each would need before=0)."""
    from gflow_core.params import added_later
    p = DCFParams()
    assert (p.augment, p.young) == (0.0, 0.0)
    assert "augment" not in added_later(DCFParams) and "young" not in added_later(DCFParams)
