"""The lost guard's state (:mod:`.lost`) as the flat fields of a filter's snapshot, with the same
names in every filter that runs the guard (the contour filter's, G-flow's): ``anchor`` (th, tw, 4)
and ``anchor_colour`` (N_BINS,) arrays, the moments ``lost_target``, ``lost_clutter``,
``lost_ctarget``, ``lost_cclutter`` (m1, m2, n), ``lost_runs`` (found frames, consecutive lost
frames) and ``held``."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import colour
from ..visibility import ChiSquare
from .lost import Anchor, LostState

__all__ = ["moments", "guard_fields", "anchor_of", "lost_of"]


def moments(c: ChiSquare) -> tuple[float, float, int]:
    """(m1, m2, n) of a distance distribution."""
    return (c.m1, c.m2, c.n)


def guard_fields(anchor: Anchor | None, lost: LostState) -> dict[str, Any]:
    """The snapshot fields of a guard's anchor (None: no anchor arrays) and state."""
    return dict(anchor=None if anchor is None else anchor.channels,
                anchor_colour=None if anchor is None or anchor.colour is None else anchor.colour,
                lost_target=moments(lost.target), lost_clutter=moments(lost.clutter),
                lost_ctarget=moments(lost.ctarget), lost_cclutter=moments(lost.cclutter),
                lost_runs=(lost.found, lost.lost_run), held=lost.held)


def anchor_of(ch: np.ndarray | None, hist: np.ndarray | None, size: tuple[float, float]) -> Anchor | None:
    """The anchor of a box of ``size`` (w, h) from its (th, tw, 4) channels and (N_BINS,) colour
    histogram (None without channels). Raises ``ValueError`` naming what is wrong with them."""
    if ch is None:
        return None
    if ch.ndim != 3 or ch.shape[2] != 4:
        raise ValueError(f"lost guard anchor of shape {ch.shape}, not (th, tw, 4)")
    if hist is not None and hist.shape != (colour.N_BINS,):
        raise ValueError(f"colour histogram of shape {hist.shape}, not ({colour.N_BINS},)")
    return Anchor(channels=ch, size=(float(size[0]), float(size[1])), res=(ch.shape[1], ch.shape[0]), colour=hist)


def lost_of(target: tuple[float, float, int], clutter: tuple[float, float, int], runs: tuple[int, int],
            held: tuple[float, ...] | None, ctarget: tuple[float, float, int],
            cclutter: tuple[float, float, int]) -> LostState:
    """The guard's state from its snapshot fields."""
    return LostState(target=ChiSquare(*target), clutter=ChiSquare(*clutter), found=runs[0], lost_run=runs[1],
                     held=None if held is None else tuple(float(v) for v in held),
                     ctarget=ChiSquare(*ctarget), cclutter=ChiSquare(*cclutter))
