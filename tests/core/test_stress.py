"""Stress cases: the plan (frames, truth, visibility) and the rendered frames, on a made-up sequence."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.evaluation.stress import (CASES, KINDS, StressCase, fill_truth, occluder_size, plan_case, render_frame,
                               target_copy, visible_fraction)

W, H = 200, 150


def _truth(n: int = 200) -> np.ndarray:
    """A 20x30 box walking right by 0.3 px a frame and bobbing up and down."""
    t = np.arange(n, dtype=np.float64)
    return np.stack([40 + 0.3 * t, 50 + 5 * np.sin(t / 9), np.full(n, 20.0), np.full(n, 30.0)], 1)


def _plan(case: StressCase, n: int = 200, seed: int = 0, lead: int = 30, tail: int = 60):
    return plan_case(case, _truth(n), (W, H), np.random.default_rng(seed), lead=lead, tail=tail)


def _image(seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(H, W, 3), dtype=np.uint8)


def test_every_kind_has_a_default_case_and_names_are_unique():
    assert {c.kind for c in CASES} == set(KINDS)
    assert len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_plan_frames_window_and_truth(case):
    truth = _truth()
    p = _plan(case)
    w0, w1 = p.window
    assert w0 == 30 and len(p) == w1 + 60
    assert np.all((p.source >= 0) & (p.source < truth.shape[0]))
    # outside the window nothing is perturbed and the truth is the original's (a look stays on)
    calm = np.r_[0:w0] if case.persistent else np.r_[0:w0, w1:len(p)]
    assert not p.perturbed[calm].any()
    assert np.allclose(p.boxes[calm], truth[p.source[calm]])
    assert p.perturbed[w0:w1].all() == (case.kind != "none")
    assert not any(p.changed(i) for i in calm)
    assert ((p.visible >= 0) & (p.visible <= 1)).all()


def test_still_occluder_hides_the_target_for_the_whole_window():
    p = _plan(StressCase("o", "occlude", 60))
    w0, w1 = p.window
    assert (p.visible[w0:w1] == 0).all()
    assert p.visible[:w0] == pytest.approx(1.0) and p.visible[w1:] == pytest.approx(1.0)
    assert np.unique(p.occluder[w0:w1], axis=0).shape[0] == 1  # it does not move
    assert np.isnan(p.occluder[:w0]).all() and np.isnan(p.occluder[w1:]).all()


def test_sweep_hides_the_target_in_the_middle_only():
    p = _plan(StressCase("s", "sweep", 40))
    w0, w1 = p.window
    vis = p.visible[w0:w1]
    assert vis[0] == pytest.approx(1) and vis[-1] == pytest.approx(1) and (vis == 0).sum() >= 10
    hidden = np.flatnonzero(vis == 0)
    assert (np.diff(hidden) == 1).all()  # one stretch
    assert np.diff(p.occluder[w0:w1, 0]).min() > 0  # it moves one way


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_partial_occluder_hides_its_fraction(seed):
    p = _plan(StressCase("p", "partial", 40, 1 / 3), seed=seed)
    w0, w1 = p.window
    assert p.visible[w0:w1] == pytest.approx(np.full(w1 - w0, 2 / 3))


def test_slide_crosses_the_target_bottom_to_top():
    p = _plan(StressCase("s", "slide", 60))
    w0, w1 = p.window
    top = p.occluder[w0:w1, 1] - p.boxes[w0:w1, 1]
    assert top[0] == pytest.approx(p.boxes[w0, 3]) and top[-1] < -p.boxes[w0, 3]
    assert p.visible[w0] == pytest.approx(1) and p.visible[w1 - 1] == pytest.approx(1)
    assert p.visible[w0:w1].min() < 0.1


def test_leave_takes_the_target_out_of_the_frame_and_back():
    p = _plan(StressCase("l", "leave", 40))
    w0, w1 = p.window
    mid = slice(w0 + 12, w1 - 12)
    assert (p.visible[mid] == 0).all()
    assert p.visible[w0] == pytest.approx(1) and p.visible[w1 - 1] == pytest.approx(1)
    assert p.boxes[mid, 0].max() + p.boxes[mid, 2].max() < 0  # out through the left edge (the nearer one)
    assert np.allclose(p.boxes[:, 0] - _truth()[p.source, 0], p.shift)


def test_fast_keeps_one_frame_in_k():
    p = _plan(StressCase("f", "fast", 60, 3))
    w0, w1 = p.window
    assert w1 - w0 == 20
    assert (np.diff(p.source[w0:w1 + 1]) == 3).all()
    assert (np.diff(p.source[:w0 + 1]) == 1).all() and (np.diff(p.source[w1:]) == 1).all()


def test_a_short_sequence_is_played_forwards_then_backwards():
    p = _plan(StressCase("o", "occlude", 60), n=100)  # needs 150 frames
    assert len(p) == 150 and p.source.max() == 99 and p.source[-1] == 198 - 149
    assert (np.abs(np.diff(p.source)) == 1).all()
    assert np.allclose(p.boxes, _truth(100)[p.source])


def test_every_case_starts_where_the_untouched_run_does_and_it_holds_their_frames():
    runs = {c.name: _plan(c, n=400) for c in CASES}
    control = runs["none"]
    assert not control.perturbed.any() and not any(control.changed(i) for i in range(len(control)))
    for name, p in runs.items():
        assert p.source[0] == control.source[0] == (400 - len(control)) // 2, name
        w0, w1 = p.window
        gone = p.case.length - (w1 - w0)  # the frames a fast case drops
        after = np.arange(w1, len(p))
        assert np.array_equal(p.source[after], control.source[after + gone]), name


def test_roll_goes_up_to_its_angle_and_back():
    p = _plan(StressCase("r", "roll-camera", 41, 35.0))
    w0, w1 = p.window
    assert p.angle[w0] == pytest.approx(0) and p.angle[w1 - 1] == pytest.approx(0, abs=1e-9)
    assert p.angle.max() == pytest.approx(35.0) and (p.region == 0).all()
    q = _plan(StressCase("r", "roll-target", 41, 35.0))
    assert (q.region[w0:w1] > 0).all() and q.visible == pytest.approx(1.0)


def test_render_leaves_calm_frames_alone_and_pastes_the_patch():
    img = _image()
    patch = np.full((40, 30, 3), 77, np.uint8)
    p = _plan(StressCase("o", "occlude", 25))
    w0, _ = p.window
    assert np.array_equal(render_frame(img, p, w0 - 1, patch), img)
    out = render_frame(img, p, w0 + 3, patch)
    x, y, w, h = p.boxes[w0 + 3]
    assert (out[int(y) + 1:int(y + h) - 1, int(x) + 1:int(x + w) - 1] == 77).all()
    assert occluder_size(p) is not None and occluder_size(_plan(StressCase("b", "blur", 20, 9.0))) is None


def test_render_roll_camera_turns_the_image_about_the_target():
    img = np.zeros((H, W, 3), np.uint8)
    p = _plan(StressCase("r", "roll-camera", 41, 45.0))
    i = int(np.argmax(p.angle))
    x, y, w, h = p.boxes[i]
    cx, cy = int(round(x + w / 2)), int(round(y + h / 2))
    img[cy - 1:cy + 2, cx + 20:cx + 31] = 255  # a bar to the right of the target's centre
    out = render_frame(img, p, i)
    # 45 degrees counter-clockwise on screen: the bar now points up and to the right
    d = 25 / np.sqrt(2)
    assert out[int(round(cy - d)), int(round(cx + d))].max() > 200
    assert out[cy, cx + 25].max() < 50


def test_render_dark_and_noise_are_seeded():
    img = np.full((H, W, 3), 200, np.uint8)
    p = _plan(StressCase("d", "dark", 41, 0.25))
    i = int(np.argmax(1 - p.gain))
    a = render_frame(img, p, i, rng=np.random.default_rng([5, i]))
    b = render_frame(img, p, i, rng=np.random.default_rng([5, i]))
    assert np.array_equal(a, b)
    assert abs(a.mean() - 50) < 2 and a.std() > 10  # darkened to a quarter, with noise of sigma 15


def test_render_blur_smears_an_edge():
    img = np.zeros((H, W, 3), np.uint8)
    img[:, W // 2:] = 255
    p = _plan(StressCase("b", "blur", 41, 21.0), seed=3)
    i = int(np.argmax(p.blur))
    out = render_frame(img, p, i)
    row = out[H // 2, :, 0].astype(int)
    ramp = np.count_nonzero((row > 10) & (row < 245))
    expected = 21 * abs(np.cos(np.radians(p.blur_angle)))
    assert ramp == pytest.approx(expected, abs=3)


def test_visible_fraction():
    assert visible_fraction(np.array([10.0, 10, 20, 10]), (100, 100)) == 1.0
    assert visible_fraction(np.array([-10.0, 10, 20, 10]), (100, 100)) == 0.5
    assert visible_fraction(np.array([10.0, 10, 20, 10]), (100, 100), np.array([0.0, 0, 20, 100])) == 0.5
    assert visible_fraction(np.array([10.0, 10, 20, 10]), (100, 100), np.array([np.nan] * 4)) == 1.0


@pytest.mark.parametrize("kw, msg", [
    (dict(name="x", kind="wobble", length=10), "unknown kind"),
    (dict(name="x", kind="occlude", length=0), "at least one frame"),
    (dict(name="x", kind="partial", length=10, amount=1.5), "fraction"),
    (dict(name="x", kind="roll-camera", length=10, amount=120.0), "angle"),
    (dict(name="x", kind="fast", length=10, amount=2.5), "integer"),
])
def test_bad_cases_are_refused(kw, msg):
    with pytest.raises(ValueError, match=msg):
        StressCase(**kw)


def test_bad_truth_and_image_are_refused():
    case = StressCase("o", "occlude", 10)
    t = _truth()
    t[5, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        plan_case(case, t, (W, H), np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        plan_case(case, _truth()[:, :3], (W, H), np.random.default_rng(0))
    p = _plan(case)
    with pytest.raises(ValueError, match="plan is for"):
        render_frame(np.zeros((10, 10, 3), np.uint8), p, 0)
    with pytest.raises(ValueError, match="give one"):
        render_frame(_image(), p, p.window[0] + 1)


def test_fill_truth_interpolates_between_labelled_frames():
    boxes, labelled = fill_truth({3: (10.0, 20.0, 30.0, 40.0), 8: (20.0, 10.0, 30.0, 50.0), 13: (20.0, 10.0, 30.0, 50.0)})
    assert boxes.shape == (11, 4) and labelled.tolist() == [True] + [False] * 4 + [True] + [False] * 4 + [True]
    assert boxes[0].tolist() == [10.0, 20.0, 30.0, 40.0] and boxes[5].tolist() == [20.0, 10.0, 30.0, 50.0]
    assert boxes[2].tolist() == pytest.approx([14.0, 16.0, 30.0, 44.0])  # 2/5 of the way
    with pytest.raises(ValueError, match="at least two"):
        fill_truth({0: (1.0, 2.0, 3.0, 4.0)})


def test_sparse_truth_starts_every_run_on_a_labelled_frame_and_marks_the_labelled_ones():
    n = 400
    labelled = np.arange(n) % 5 == 0
    for case in CASES:
        p = plan_case(case, _truth(n), (W, H), np.random.default_rng(0), labelled=labelled)
        assert p.labelled[0] and np.array_equal(p.labelled, labelled[p.source]), case.name
        dense = plan_case(case, _truth(n), (W, H), np.random.default_rng(0))
        # the start moves back to the labelled frame at or before the dense plan's start
        assert 0 <= dense.source[0] - p.source[0] < 5 and p.source[0] % 5 == 0, case.name
        assert dense.labelled.all()
    with pytest.raises(ValueError, match="frame 0 labelled"):
        plan_case(CASES[0], _truth(n), (W, H), np.random.default_rng(0), labelled=~labelled)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_distract_copy_crosses_the_target_in_a_straight_line_and_walks_on(seed):
    """The copy walks at a steady pace, level, from 2.5 widths to one side of the target's place at the
    window's middle to 2.5 on the other, covers the target there and keeps going after the window; the
    truth never moves with it."""
    p = _plan(StressCase("d", "distract", 40), seed=seed)
    w0, w1 = p.window
    mid = w0 + round(0.5 * (w1 - 1 - w0))
    o = p.occluder
    assert np.isnan(o[:w0]).all() and not np.isnan(o[w0:]).any()
    step = np.diff(o[w0:, 0])
    assert np.allclose(step, step[0]) and abs(step[0]) > 0 and np.ptp(o[w0:, 1]) == 0  # straight and steady
    c = p.boxes[mid, :2] + p.boxes[mid, 2:] / 2
    assert np.allclose(o[mid, :2] + o[mid, 2:] / 2, c, atol=abs(step[0]))  # over the target in the middle
    start = (o[w0, 0] + o[w0, 2] / 2 - c[0]) / p.boxes[mid, 2]
    assert 2.3 < abs(start) < 2.7 and np.sign(step[0]) == -np.sign(start)
    assert p.visible[w0] == pytest.approx(1.0) and p.visible[mid] < 0.2
    assert np.allclose(p.boxes, _truth()[p.source]) and p.perturbed[w0:].all() and not p.perturbed[:w0].any()


def test_target_copy_is_the_box_mirrored_and_refuses_a_box_outside():
    img = _image()
    c = target_copy(img, np.array([10.0, 20.0, 30.0, 40.0]))
    assert c.shape == (40, 30, 3) and np.array_equal(c, img[20:60, 10:40][:, ::-1])
    assert target_copy(img, np.array([-10.0, -5.0, 30.0, 40.0])).shape == (35, 20, 3)  # clipped to the image
    with pytest.raises(ValueError, match="not in the 200x150 image"):
        target_copy(img, np.array([500.0, 20.0, 30.0, 40.0]))


def test_distract_copy_and_path_of_a_box_in_the_image_are_as_before():
    """Pinned: the copy is the box's pixels mirrored, the box clipped to the image where it is partly out, and the
    path the copy walks (the values the code gave before a box outside the image was made a skipped case)."""
    p = _plan(StressCase("d", "distract", 40), seed=0)
    w0 = p.window[0]
    img = _image()
    x, y = (int(round(v)) for v in p.boxes[w0, :2])
    assert np.array_equal(target_copy(img, p.boxes[w0]), img[y:y + 30, x:x + 20][:, ::-1])
    assert np.array_equal(target_copy(img, np.array([-10.0, -5.0, 30.0, 40.0])), img[0:35, 0:20][:, ::-1])
    assert np.array_equal(target_copy(img, np.array([185.0, 130.0, 30.0, 40.0])), img[130:150, 185:200][:, ::-1])
    np.testing.assert_array_equal(p.occluder[w0], [3.7179487179487154, 46.67449242510589, 20.0, 30.0])
    np.testing.assert_array_equal(p.occluder[-1], [257.56410256410254, 46.67449242510589, 20.0, 30.0])
