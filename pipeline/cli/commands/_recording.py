"""Where a command's run records, from its options (:class:`Recording`; ``common`` hands it on)."""

from __future__ import annotations

from pipeline.app import RecordingTarget
from pipeline.runtime.graph import Plan

__all__ = ["Recording"]


class Recording(RecordingTarget):
    """Where a run records, from ``--record / --no-record / --record-topics``
    (:class:`pipeline.app.RecordingTarget`)."""

    def __init__(self, plan: Plan, args, default: str | None, needed: tuple[str, ...] = ()) -> None:
        super().__init__(plan, getattr(args, "record", None), getattr(args, "no_record", False),
                         getattr(args, "record_topics", None) or (), default, needed)
