"""Trackers that ``gflow track`` can run: each module builds the overrides of its graph."""

from __future__ import annotations

from . import chamfer

TRACKERS = {m.NAME: m for m in (chamfer,)}

__all__ = ["TRACKERS"]
