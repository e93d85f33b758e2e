"""A small scene for the dcf search's tests: a textured background and a textured target (h, w) = (36, 30)
centred at (130, 100), and a track that holds it there while it is hidden (not a test module)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from gflow_core.dcf import tracker as tr
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.tracker import TRACKER
from gflow_core.visibility import ChiSquare

H, W = 200, 260
BOX = (30.0, 36.0)
_RNG = np.random.default_rng(3)


def _texture(h: int, w: int, cell: float) -> np.ndarray:
    small = _RNG.uniform(0, 255, size=(max(2, int(h / cell)), max(2, int(w / cell)))).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


BG = _texture(H, W, 10.0)
TARGET = _texture(36, 30, 5.0)


def frame(with_target: bool) -> np.ndarray:
    """(H, W) uint8: the background, with the target centred at (130, 100) if ``with_target``."""
    img = BG.copy()
    if with_target:
        img[82:118, 115:145] = TARGET
    return np.clip(img, 0, 255).astype(np.uint8)


def usual(mean: float, sd: float, n: int = 30) -> ChiSquare:
    """A distance distribution learnt from ``n`` samples of that mean and spread."""
    return ChiSquare(mean, mean * mean + sd * sd, n)


def hidden(p: DCFParams, run: int = 5) -> tr.DCFState:
    """A target held at (130, 100), hidden for ``run`` frames: its filter's distances usual at 0.5, the
    clutter's at 0.9."""
    st = tr.initialise(TRACKER.observe(p, frame(True)), (115.5, 82.5, *BOX), p, np.random.default_rng(0))
    return dataclasses.replace(st, target=usual(0.5, 0.05), clutter=usual(0.9, 0.03), hidden_run=run)
