"""The stress case ``confetti``: flakes that fall in front of the target, on a made-up sequence."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.evaluation.stress import CASES, StressCase, flakes_at, plan_case, render_frame

W, H = 200, 150
CONFETTI = next(c for c in CASES if c.kind == "confetti")


def _truth(n: int = 200) -> np.ndarray:
    """A 20x30 box walking right by 0.3 px a frame."""
    t = np.arange(n, dtype=np.float64)
    return np.stack([40 + 0.3 * t, np.full(n, 50.0), np.full(n, 20.0), np.full(n, 30.0)], 1)


def _plan(case: StressCase = CONFETTI, seed: int = 0):
    return plan_case(case, _truth(), (W, H), np.random.default_rng(seed))


def test_flakes_fall_in_the_window_only_and_the_same_ones_from_the_same_rng():
    p = _plan()
    w0, w1 = p.window
    assert p.shower is not None and p.shower[w0:w1].all() and not p.shower[:w0].any() and not p.shower[w1:].any()
    assert flakes_at(p, w0 - 1).shape == (0, 6) and flakes_at(p, w1).shape == (0, 6)
    assert [p.changed(i) for i in range(len(p))] == list(p.shower)
    q = _plan()
    assert np.array_equal(p.flakes, q.flakes)
    assert not np.array_equal(p.flakes, _plan(seed=1).flakes)


def test_flakes_fall_and_tumble_and_wrap_round_the_frame():
    p = _plan()
    w0 = p.window[0]
    a, b = flakes_at(p, w0), flakes_at(p, w0 + 1)
    dy = b[:, 1] - a[:, 1]
    fell = dy > 0
    # every flake falls 1-3 % of the frame's height a frame, unless it wrapped round to the top
    assert np.all((dy[fell] >= 0.01 * H - 1e-9) & (dy[fell] <= 0.03 * H + 1e-9))
    assert fell.mean() > 0.9
    assert not np.allclose(a[:, 3], b[:, 3])  # the breadth changes as they tumble
    later = flakes_at(p, w0 + 39)
    m = 2.0 * p.flakes[:, 4].max()
    assert np.all((later[:, 0] >= -m) & (later[:, 0] < W + m) & (later[:, 1] >= -m) & (later[:, 1] < H + m))


def test_flakes_cover_about_the_fraction_of_the_frame_asked():
    p = _plan()
    img = np.zeros((H, W, 3), np.uint8)
    covered = [(render_frame(img, p, i).max(axis=2) > 0).mean() for i in range(*p.window)]
    # overlapping flakes counted once (a Poisson cover), their raster edges counted
    assert float(np.mean(covered)) == pytest.approx(CONFETTI.amount, rel=0.15)


def test_the_visible_fraction_is_the_box_the_flakes_leave_uncovered():
    p = _plan()
    img = np.zeros((H, W, 3), np.uint8)
    w0, w1 = p.window
    for i in range(w0, w1, 7):
        out = render_frame(img, p, i)
        x, y, w, h = (int(v) for v in p.boxes[i])
        free = (out[y:y + h, x:x + w].max(axis=2) == 0).mean()
        # the plan's mask and the rendered frame agree up to the box's sub-pixel edges
        assert p.visible[i] == pytest.approx(free, abs=0.06)
    assert 0.4 < p.visible[w0:w1].mean() < 0.95
    assert p.visible[:w0] == pytest.approx(1.0) and p.visible[w1:] == pytest.approx(1.0)


def test_flakes_are_coloured_on_colour_frames_and_grey_on_grey_ones():
    p = _plan()
    i = p.window[0] + 5
    colour = render_frame(np.full((H, W, 3), (10, 20, 30), np.uint8), p, i)
    assert (colour[..., 0] != colour[..., 1]).mean() > 0.5 * CONFETTI.amount
    grey = render_frame(np.full((H, W, 3), 20, np.uint8), p, i)
    assert np.array_equal(grey[..., 0], grey[..., 1]) and np.array_equal(grey[..., 1], grey[..., 2])
    assert (grey[..., 0] != 20).mean() > 0.5 * CONFETTI.amount
    one = render_frame(np.full((H, W), 20, np.uint8), p, i)
    assert one.ndim == 2 and (one != 20).mean() > 0.5 * CONFETTI.amount


def test_flakes_keep_the_scale_of_the_target():
    small, big = _plan(), plan_case(CONFETTI, _truth() * np.array([1, 1, 2, 2]), (W, H), np.random.default_rng(0))
    # twice the box: flakes twice as long, fewer of them, the same cover
    assert np.median(big.flakes[:, 4]) == pytest.approx(2 * np.median(small.flakes[:, 4]), rel=0.15)
    assert big.flakes.shape[0] < small.flakes.shape[0] / 2
    img = np.zeros((H, W, 3), np.uint8)
    covered = [(render_frame(img, big, i).max(axis=2) > 0).mean() for i in range(*big.window)]
    assert float(np.mean(covered)) == pytest.approx(CONFETTI.amount, rel=0.15)


@pytest.mark.parametrize("amount", [0.0, 0.5, -0.1])
def test_a_cover_outside_zero_to_a_half_is_refused(amount):
    with pytest.raises(ValueError, match="fraction of the frame"):
        StressCase("c", "confetti", 40, amount)
