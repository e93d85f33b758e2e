"""Training items from frames: background subtraction, edges, boxes, patches (sec. 4.1, 5.1, 5.2)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gflow_core.m2 import training
from gflow_core.m2.learn import learn


def background(rng: np.random.Generator, h: int = 90, w: int = 140) -> np.ndarray:
    noise = rng.uniform(0, 1, size=(h // 10 + 1, w // 10 + 1))
    bg = cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip(60 + 40 * bg, 0, 255).astype(np.uint8)


def walking_frames(rng: np.random.Generator, n: int = 24) -> tuple[list[np.ndarray], np.ndarray]:
    """A bright ellipse crossing a textured background, its shape pulsing like a gait."""
    bg = background(rng)
    frames, centres = [], []
    for t in range(n):
        f = cv2.cvtColor(bg, cv2.COLOR_GRAY2BGR)
        cx, cy = 25.0 + 3.5 * t, 45.0 + 0.5 * np.sin(t)
        ax = int(round(10 + 3 * np.sin(2 * np.pi * t / 8)))
        cv2.ellipse(f, (int(round(cx)), int(round(cy))), (ax, 22), 0, 0, 360, (220, 210, 200), -1)
        frames.append(f)
        centres.append((round(cx), round(cy)))
    return frames, np.array(centres, dtype=np.float64)


def test_median_background_removes_the_moving_object() -> None:
    rng = np.random.default_rng(0)
    frames, _ = walking_frames(rng)
    bg = training.median_background(frames)
    truth = cv2.cvtColor(background(np.random.default_rng(0)), cv2.COLOR_GRAY2BGR).astype(np.float64)
    assert np.abs(bg - truth).max() <= 1.0


def test_curves_from_background_finds_the_silhouette() -> None:
    rng = np.random.default_rng(0)
    frames, centres = walking_frames(rng)
    ts = training.curves_from_background(frames, max_points=80)
    assert ts.kind == "curve" and len(ts) == len(frames)
    assert ts.frame_index.tolist() == list(range(len(frames)))
    # centroid placement within a pixel of the ellipse centre, scale 1
    assert np.abs(ts.placement[:, :2] - centres).max() < 1.0
    assert (ts.placement[:, 3] == 1.0).all()
    assert ts.items.n_points.max() <= 80
    # edge points lie on the ellipse boundary: |x/a|^2 + |y/22|^2 ~ 1 within the Canny blur
    pts = ts.items.curve(0)
    r = np.hypot(pts[:, 0] / 10.0, pts[:, 1] / 22.0)
    assert np.median(np.abs(r - 1.0)) < 0.12
    assert ts.ref_size == pytest.approx([21.0, 45.0], abs=4.0)


def test_curves_from_boxes_and_patches_from_boxes() -> None:
    rng = np.random.default_rng(1)
    frames, centres = walking_frames(rng, n=10)
    boxes = np.stack([centres[:, 0] - 14, centres[:, 1] - 24, np.full(10, 29.0), np.full(10, 49.0)], 1)
    boxes[3] = np.nan  # a frame without ground truth is skipped
    ts = training.curves_from_boxes(frames, boxes, max_points=60)
    assert len(ts) == 9 and 3 not in ts.frame_index
    assert ts.ref_size == pytest.approx([29.0, 49.0])
    assert np.abs(ts.placement[:, :2] - centres[ts.frame_index]).max() < 1e-9
    assert np.abs(ts.items.centroids()).max() < 3.0  # roughly aligned
    bg = training.median_background(frames)
    ts_bg = training.curves_from_boxes(frames, boxes, background=bg, max_points=60)
    assert len(ts_bg) == 9
    ps = training.patches_from_boxes(frames, boxes, (24, 16))
    assert ps.kind == "patch" and ps.items.shape == (9, 24, 16)
    # the bright ellipse fills the middle of every patch
    assert ps.items[:, 12, 8].min() > 180
    full = training.patches_from_frames(frames, (18, 28))
    assert full.items.shape == (10, 18, 28) and full.items.dtype == np.float64


def test_training_input_errors() -> None:
    rng = np.random.default_rng(2)
    frames, centres = walking_frames(rng, n=6)
    with pytest.raises(ValueError, match="no training frames"):
        training.curves_from_background([])
    static = [frames[0]] * 5
    with pytest.raises(ValueError, match="no foreground"):
        training.curves_from_background(static)
    with pytest.raises(ValueError, match="shape"):
        training.curves_from_background([frames[0], frames[0][:50]])
    with pytest.raises(ValueError, match="one box"):
        training.curves_from_boxes(frames, np.zeros((3, 4)))
    with pytest.raises(ValueError, match="no valid ground-truth box"):
        training.curves_from_boxes(frames, np.full((6, 4), np.nan))
    with pytest.raises(ValueError, match="NaN"):
        training.median_background([np.full((8, 8), np.nan)])
    ts = training.curves_from_background(frames)
    single = training.TrainingSet(items=ts.items[0], placement=ts.placement[:1], frame_index=ts.frame_index[:1],
                                  sequence=ts.sequence[:1], ref_size=ts.ref_size, kind="curve")
    with pytest.raises(ValueError, match="single"):
        learn(single, "chamfer", K=1)
    with pytest.raises(ValueError, match="K=7"):
        learn(ts, "chamfer", K=7)
    with pytest.raises(ValueError, match="no validation"):
        learn(ts, "chamfer", K=6)
    with pytest.raises(ValueError, match="works on patch items"):
        learn(ts, "shuffle", K=2)


def test_concat_training_sets_keeps_sequences_apart() -> None:
    rng = np.random.default_rng(3)
    a = training.curves_from_background(walking_frames(rng, n=6)[0], sequence=0)
    b = training.curves_from_background(walking_frames(rng, n=12)[0], sequence=1)
    c = training.concat_training_sets([a, b])
    assert len(c) == 18 and c.sequence.tolist() == [0] * 6 + [1] * 12
    with pytest.raises(ValueError, match="mix"):
        training.concat_training_sets([a, training.patches_from_frames(walking_frames(rng, n=3)[0])])
