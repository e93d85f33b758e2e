"""A synthetic scene with known ground truth: textured moving shapes on a textured background.

The target is a textured polygon moving along a smooth closed path while it slowly turns
and changes size; two distractor shapes cross the scene. Everything is drawn from
explicit generators: the scene layout from ``seed``, and the per-frame sensor noise from
``default_rng([seed, t])``, so frame ``t`` is the same whenever and wherever it is drawn.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from . import similarity

__all__ = ["SyntheticScene"]


def _texture(rng: np.random.Generator, h: int, w: int, scale: float, lo: int, hi: int) -> np.ndarray:
    """Smooth random texture (h, w, 3) uint8 with values in [lo, hi]."""
    small = rng.uniform(0, 1, size=(max(2, int(h / scale)), max(2, int(w / scale)), 3)).astype(np.float32)
    big = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    big = (big - big.min()) / max(float(big.max() - big.min()), 1e-6)
    return (lo + big * (hi - lo)).astype(np.uint8)


@dataclass(frozen=True)
class SyntheticScene:
    """Deterministic synthetic video.

    Parameters
    ----------
    width, height : frame size in pixels.
    n_frames : number of frames.
    seed : scene seed.
    noise : std of additive Gaussian sensor noise (grey levels).
    period : frames for the target to go once round its path (motion per frame does not
        depend on ``n_frames``).
    """

    width: int = 320
    height: int = 240
    n_frames: int = 120
    seed: int = 0
    noise: float = 4.0
    period: int = 120
    # drawn in __post_init__ from the seed
    _target: np.ndarray = field(init=False, repr=False, compare=False)
    _target_tex: np.ndarray = field(init=False, repr=False, compare=False)
    _distractors: list[tuple[np.ndarray, float]] = field(init=False, repr=False, compare=False)
    _distractor_tex: np.ndarray = field(init=False, repr=False, compare=False)
    _background: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.width < 64 or self.height < 64:
            raise ValueError(f"synthetic scene must be at least 64x64, got {self.width}x{self.height}")
        if self.n_frames < 1:
            raise ValueError(f"synthetic scene needs at least one frame, got {self.n_frames}")
        rng = np.random.default_rng([self.seed, 0x5CE4E])
        h, w = self.height, self.width
        object.__setattr__(self, "_background", _texture(rng, h, w, 24.0, 60, 140))
        # target: an irregular 7-gon, about 18% of the frame height in radius
        n = 7
        ang = np.sort(rng.uniform(0, 2 * np.pi, n)) + np.linspace(0, 0.3, n)
        rad = rng.uniform(0.7, 1.0, n) * 0.18 * h
        poly = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
        object.__setattr__(self, "_target", poly)
        object.__setattr__(self, "_target_tex", _texture(rng, h, w, 6.0, 170, 255))
        dis = []
        for _ in range(2):
            m = rng.integers(3, 6)
            a = np.sort(rng.uniform(0, 2 * np.pi, m))
            r = rng.uniform(0.5, 1.0, m) * 0.12 * h
            dis.append((np.stack([r * np.cos(a), r * np.sin(a)], axis=1), rng.uniform(0, 2 * np.pi)))
        object.__setattr__(self, "_distractors", dis)
        object.__setattr__(self, "_distractor_tex", _texture(rng, h, w, 10.0, 0, 70))

    def alpha(self, t: int) -> np.ndarray:
        """True transform (ux, uy, theta, s) of the target at frame t, (4,) float64."""
        w, h = self.width, self.height
        phase = 2 * np.pi * t / max(self.period, 2)
        ux = w / 2 + 0.30 * w * np.sin(phase)
        uy = h / 2 + 0.18 * h * np.sin(2 * phase)
        theta = 0.25 * np.sin(phase)
        s = 1.0 + 0.15 * np.sin(phase + 1.0)
        return np.array([ux, uy, theta, s])

    def truth_box(self, t: int) -> tuple[float, float, float, float]:
        """Bounding box (x, y, w, h) of the target at frame t."""
        p = similarity.apply(self.alpha(t), self._target)
        x0, y0 = p.min(axis=0)
        x1, y1 = p.max(axis=0)
        return float(x0), float(y0), float(x1 - x0 + 1), float(y1 - y0 + 1)

    def render(self, t: int) -> np.ndarray:
        """Frame t, (height, width, 3) uint8 BGR."""
        if not 0 <= t < self.n_frames:
            raise IndexError(f"frame {t} outside the scene's {self.n_frames} frames")
        img = self._background.copy()
        w, h = self.width, self.height
        for i, (poly, ph) in enumerate(self._distractors):
            x = (w * (0.1 + 0.8 * ((t / max(self.period, 1) + 0.5 * i + ph / 6.3) % 1.0)))
            y = h * (0.25 + 0.5 * i)
            pts = (poly + [x, y]).round().astype(np.int32)
            mask = np.zeros((h, w), np.uint8)
            cv2.fillPoly(mask, [pts], 255)
            img[mask > 0] = self._distractor_tex[mask > 0]
        pts = similarity.apply(self.alpha(t), self._target)
        mask = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask, [np.round(pts * 16).astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=4)
        a = (mask.astype(np.float32) / 255.0)[..., None]
        img = (img * (1 - a) + self._target_tex * a)
        noise = np.random.default_rng([self.seed, t]).normal(0.0, self.noise, size=img.shape)
        return np.clip(img + noise, 0, 255).astype(np.uint8)
