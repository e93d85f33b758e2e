"""The scale filter's pick under a prior on the target's size (``scale_prior``, gflow_core.dcf.sizeprior):
a response that barely prefers a larger size no longer moves a box already larger than the first one, a
clear zoom still does, a target whose look changes but whose size does not keeps its box's size, and a
bad value is refused in one line."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from gflow import GflowError, Tracker
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.scale import detect_scale, init_scale, size_posterior
from gflow_core.params import make
from tests.core.test_dcf_tracker import Scene, _texture, _track

STEP = math.log(1.02)


def test_a_near_tie_is_resolved_towards_the_first_size() -> None:
    """17 scales: the response's peak one step up, its middle 0.1 % below; a box already 0.3 above the
    first size in log keeps its size (or shrinks), one at the first size takes the step as before."""
    y = np.exp(-0.5 * (np.arange(17) - 8.505) ** 2 / 4.0)
    assert int(np.argmax(y)) == 9
    assert int(np.argmax(size_posterior(y, 1.02, 0.3, 0.3, 30.0))) <= 8
    assert int(np.argmax(size_posterior(y, 1.02, 0.0, 0.3, 30.0))) == 9


def test_a_clear_zoom_still_moves_the_box() -> None:
    """DSST's zoom test with the prior (std 0.3, kappa 30): a 6 % zoom is still found."""
    rng = np.random.default_rng(9)
    img = cv2.resize(rng.uniform(0, 255, (30, 30)).astype(np.float32), (300, 300), interpolation=cv2.INTER_CUBIC)
    sf = init_scale(img, (150.0, 150.0), (40.0, 60.0), 17, 1.02, 2048, 4)
    for zoom in (0.94, 1.06):
        z = cv2.warpAffine(img, cv2.getRotationMatrix2D((150.0, 150.0), 0.0, zoom), (300, 300))
        d, _ = detect_scale(sf, z, (150.0, 150.0), (40.0, 60.0), 1.02, 4, 0.01, prior=(0.0, 0.3, 30.0))
        assert abs(d - math.log(zoom)) <= 0.5 * STEP + 1e-9, (zoom, math.exp(d))


class Morph(Scene):
    """The 30 x 36 target whose texture turns into another over 60 frames; its size never changes."""

    def __init__(self, path, seed: int = 0) -> None:
        super().__init__(path, seed)
        self.first, self.second = self.target, _texture(np.random.default_rng(seed + 100), 36, 30, 5.0)

    def frame(self, t: int) -> np.ndarray:
        a = min(1.0, t / 60)
        self.target = (1.0 - a) * self.first + a * self.second
        return super().frame(t)


@pytest.mark.parametrize("seed", [6, 8])
def test_a_target_that_keeps_its_size_keeps_its_box_size(seed: int) -> None:
    """The target changes its look but not its size over 100 frames: with scale_prior 0.05 the box's width
    stays within 7 % of the first (the response's peak alone moves it 10-19 % on these scenes)."""
    sc = Morph(lambda t: (130 + 40 * math.sin(t / 15), 100 + 25 * math.cos(t / 11)), seed)
    frames = [sc.frame(t) for t in range(100)]
    _, out = _track(frames, sc.truth(0), DCFParams(scale_prior=0.05))
    worst = max(abs(math.log(e.box[2] / 30.0)) for e in out)
    assert worst <= math.log(1.07), math.exp(worst)


@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf")])
def test_a_bad_scale_prior_is_refused_in_one_line(value: float) -> None:
    with pytest.raises(ValueError) as e:
        make(DCFParams, {"scale_prior": value})
    assert "scale_prior must be finite and >= 0" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(GflowError, match="scale_prior must be finite and >= 0"):
        Tracker("dcf", scale_prior=value)
