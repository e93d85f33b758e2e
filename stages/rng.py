"""Explicit random streams: frame ``t`` of stage ``purpose`` draws from
``np.random.default_rng([seed, stream_hash, t, purpose])`` and nothing else, so a stage's
outputs depend only on its configuration, its seed and the ordered inputs it consumed."""

from __future__ import annotations

import zlib

import numpy as np

from gflow_core.tracker import FrameRng

__all__ = ["stream_hash", "frame_rng", "tracker_rng"]


def stream_hash(stream: str) -> int:
    """A stable 32-bit hash of a stream id (CRC-32; Python's ``hash`` is salted per process)."""
    return zlib.crc32(stream.encode("utf-8"))


def frame_rng(seed: int, stream: str, seq: int, purpose: int) -> np.random.Generator:
    """The generator for one frame of one stage. ``purpose`` separates draws inside a stage."""
    if seed < 0 or seq < 0:
        raise ValueError(f"seed and seq must be non-negative, got seed={seed}, seq={seq}")
    return np.random.default_rng([seed, stream_hash(stream), seq, purpose])


def tracker_rng(seed: int, stream: str, seq: int) -> FrameRng:
    """The draws of one frame for a tracker of :mod:`gflow_core.tracker`: ``FrameRng(seed,
    stream_hash(stream), seq)``, whose ``stream(purpose)`` is :func:`frame_rng`'s generator."""
    return FrameRng(int(seed), stream_hash(stream), int(seq))
