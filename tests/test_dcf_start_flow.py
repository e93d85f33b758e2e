"""The forward-backward check a tentative dcf track asks of a frame in doubt (:mod:`gflow_core.dcf.coherence`):
a textured patch that moves is tracked by its points, with the shift it moved by; random noise (no
motion) and a flat patch (no texture) are not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gflow_core.dcf.coherence import MIN_NCC, coherent, flow

BOX = (100.0, 80.0, 40.0, 50.0)


def _scene(rng: np.random.Generator) -> np.ndarray:
    small = rng.uniform(0, 255, size=(30, 40)).astype(np.float32)
    return np.clip(cv2.resize(small, (320, 240), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)


def test_a_moving_texture_is_tracked_with_its_shift() -> None:
    """The frame moved by (6, -3) px: every point tracked, the median shift within 0.1 px of it, a small
    forward-backward error and a high NCC: coherent."""
    img = _scene(np.random.default_rng(1))
    moved = np.roll(img, (-3, 6), axis=(0, 1))
    f = flow(img, moved, BOX)
    assert f.tracked > 0.9 and f.fb < 0.5 and f.ncc > 0.9
    assert np.allclose(f.shift, (6.0, -3.0), atol=0.1)
    assert coherent(f)


def test_noise_and_a_flat_patch_do_not_move_coherently() -> None:
    """Two frames of independent uniform noise: the patches are unrelated (median NCC under MIN_NCC) and
    the check refuses them; a flat grey patch: its points are not tracked."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        a, b = (rng.integers(0, 256, (240, 320), dtype=np.uint8) for _ in range(2))
        f = flow(a, b, BOX)
        assert f.ncc < MIN_NCC
        assert not coherent(f)
    img = _scene(np.random.default_rng(2))
    x, y, w, h = (int(v) for v in BOX)
    img[y - 4:y + h + 4, x - 4:x + w + 4] = 128
    f = flow(img, img, BOX)
    assert f.tracked < 0.5 and not coherent(f)


def test_frames_that_do_not_fit_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="uint8 frames of one size"):
        flow(np.zeros((10, 10), np.uint8), np.zeros((10, 12), np.uint8), (1.0, 1.0, 4.0, 4.0))
