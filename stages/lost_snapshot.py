"""The lost guard's state (:mod:`gflow_core.m2.lost`) in a filter stage's snapshot, as flat fields
with the same names in every stage that runs the guard (``particle.filter`` for chamfer and m2,
``gflow.filter``): ``anchor`` (th, tw, 4) and ``anchor_colour`` (N_BINS,) arrays, and the moments
``lost_target``, ``lost_clutter``, ``lost_ctarget``, ``lost_cclutter`` (m1, m2, n), ``lost_runs``
(found frames, consecutive lost frames) and ``held``."""

from __future__ import annotations

from typing import Any

from gflow_core import colour
from gflow_core.m2.lost import Anchor, LostState
from gflow_core.visibility import ChiSquare

from .messages import MessageError, NDArray

__all__ = ["moments", "pack_guard", "unpack_anchor", "unpack_lost"]


def moments(c: ChiSquare) -> tuple[float, float, int]:
    """(m1, m2, n) of a distance distribution."""
    return (c.m1, c.m2, c.n)


def pack_guard(anchor: Anchor | None, lost: LostState) -> dict[str, Any]:
    """The snapshot fields of a guard's anchor (None: no anchor arrays) and state."""
    return dict(anchor=None if anchor is None else NDArray.of(anchor.channels),
                anchor_colour=None if anchor is None or anchor.colour is None else NDArray.of(anchor.colour),
                lost_target=moments(lost.target), lost_clutter=moments(lost.clutter),
                lost_ctarget=moments(lost.ctarget), lost_cclutter=moments(lost.cclutter),
                lost_runs=(lost.found, lost.lost_run), held=lost.held)


def unpack_anchor(channels: NDArray | None, hist: NDArray | None, size: tuple[float, float]) -> Anchor | None:
    """The anchor of a box of ``size`` (w, h) from its snapshot arrays (None without channels). Raises
    ``ValueError`` naming what is wrong with them."""
    if channels is None:
        return None
    try:
        ch = channels.array().copy()
        h = None if hist is None else hist.array().copy()
    except MessageError as e:
        raise ValueError(str(e)) from None
    if ch.ndim != 3 or ch.shape[2] != 4:
        raise ValueError(f"lost guard anchor of shape {ch.shape}, not (th, tw, 4)")
    if h is not None and h.shape != (colour.N_BINS,):
        raise ValueError(f"colour histogram of shape {h.shape}, not ({colour.N_BINS},)")
    return Anchor(channels=ch, size=(float(size[0]), float(size[1])), res=(ch.shape[1], ch.shape[0]), colour=h)


def unpack_lost(target: tuple[float, float, int], clutter: tuple[float, float, int], runs: tuple[int, int],
                held: tuple[float, ...] | None, ctarget: tuple[float, float, int],
                cclutter: tuple[float, float, int]) -> LostState:
    """The guard's state from its snapshot fields."""
    return LostState(target=ChiSquare(*target), clutter=ChiSquare(*clutter), found=runs[0], lost_run=runs[1],
                     held=None if held is None else tuple(float(v) for v in held),
                     ctarget=ChiSquare(*ctarget), cclutter=ChiSquare(*cclutter))
