"""The lost guard's snapshot fields (:mod:`gflow_core.m2.lost_state`) with their arrays as message
arrays (:class:`~gflow_msgs.messages.NDArray`), for a stage whose snapshot Struct holds those."""

from __future__ import annotations

from typing import Any

import numpy as np

from gflow_core.m2.lost import Anchor, LostState
from gflow_core.m2.lost_state import anchor_of, guard_fields, lost_of, moments

from gflow_msgs.messages import MessageError, NDArray

__all__ = ["moments", "pack_guard", "unpack_anchor", "unpack_lost"]

unpack_lost = lost_of


def pack_guard(anchor: Anchor | None, lost: LostState) -> dict[str, Any]:
    """The snapshot fields of a guard's anchor (None: no anchor arrays) and state."""
    return {k: NDArray.of(v) if isinstance(v, np.ndarray) else v for k, v in guard_fields(anchor, lost).items()}


def unpack_anchor(channels: NDArray | None, hist: NDArray | None, size: tuple[float, float]) -> Anchor | None:
    """The anchor of a box of ``size`` (w, h) from its snapshot arrays (None without channels). Raises
    ``ValueError`` naming what is wrong with them."""
    try:
        ch = None if channels is None else channels.array().copy()
        h = None if hist is None or channels is None else hist.array().copy()
    except MessageError as e:
        raise ValueError(str(e)) from None
    return anchor_of(ch, h, size)
