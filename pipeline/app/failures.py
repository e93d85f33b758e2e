"""What a run's frames came to: how many failed, in which stage and why (:class:`RunFailures`),
gathered from the run's own messages (:class:`FailureLog`) so that a run whose every frame failed
(a parameter a tracker's checks let through, a box a stage cannot use) does not end as though it
tracked: ``gflow run``, ``demo`` and ``track`` say it in one line and exit 3, ``benchmark`` notes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from gflow_msgs.messages import NOTICE_KINDS, ErrorReport, MessageError, decode

__all__ = ["RunFailures", "FailureLog", "error_report", "EVERY_FRAME_FAILED"]

#: the status a command exits with when every frame of its run failed (as ``gflow track``'s incomplete run)
EVERY_FRAME_FAILED = 3


@dataclass(frozen=True)
class RunFailures:
    """The failures of a run's frames.

    frames : the frames the source sent.
    failed : of them, those that failed: without an estimate (in a graph with none, those a stage reported).
    reports : the error reports of the run (not a live stream's notices, nor damaged input: news, not errors).
    stages : the stages that reported, in the order of their first report's frame.
    first : the message of the first report (of the lowest frame), ``frame 0: ValueError: ...``.
    """

    frames: int = 0
    failed: int = 0
    reports: int = 0
    stages: tuple[str, ...] = ()
    first: str = ""

    @property
    def every(self) -> bool:
        """Every frame sent failed, and a stage said why."""
        return self.frames > 0 and self.failed >= self.frames and self.reports > 0

    def where(self) -> str:
        return f"stage {self.stages[0]}" if len(self.stages) == 1 else f"stages {', '.join(self.stages)}"

    def line(self) -> str:
        """``every one of the 20 frames failed in stage filter: frame 0: ...`` when every frame failed, else how many
        failed and the first reason ('' when no stage reported an error)."""
        if not self.reports:
            return ""
        if self.every:
            return f"every one of the {self.frames} frames failed in {self.where()}: {self.first}"
        return (f"errors reported: {self.reports} by {self.where()}, {self.failed} of the {self.frames} frames "
                f"without an estimate; the first: {self.first}")


def error_report(payload: bytes) -> ErrorReport | None:
    """The :class:`ErrorReport` a message on a run's errors topic holds (None: another message, or none at all)."""
    try:
        msg = decode(payload)
    except MessageError:
        return None
    return msg if isinstance(msg, ErrorReport) else None


class FailureLog:
    """The error reports and the frames with an estimate of a run, taken from its messages: as an inline run
    publishes them (:meth:`tap`) or as a process run's launcher heard them (:meth:`take`)."""

    def __init__(self, error_topic: str, estimate_topics: Iterable[str]) -> None:
        self.error_topic = error_topic
        self.estimate_topics = frozenset(estimate_topics)
        self.reports: list[ErrorReport] = []
        self.estimated: set[int] = set()

    def tap(self, topic: str, payload: bytes, seq: int, type_name: str) -> None:
        if topic in self.estimate_topics and type_name in ("Estimate", "PoseEstimate") and seq >= 0:
            self.estimated.add(seq)
        elif topic == self.error_topic and (report := error_report(payload)) is not None:
            self.take([report])

    def take(self, reports: Iterable[ErrorReport], estimated: Iterable[int] = ()) -> None:
        self.reports.extend(r for r in reports if r.kind not in NOTICE_KINDS)
        self.estimated.update(estimated)

    def summary(self, frames: int) -> RunFailures:
        """What the run's ``frames`` sent came to."""
        if not self.reports:
            return RunFailures(frames=frames)
        ordered = sorted(self.reports, key=lambda r: r.header.seq)  # stable: of one frame, the first said
        failed = (frames - len(self.estimated) if self.estimate_topics
                  else len({r.header.seq for r in self.reports}))
        return RunFailures(frames=frames, failed=max(failed, 0), reports=len(self.reports),
                           stages=tuple(dict.fromkeys(r.stage for r in ordered)),
                           first=" ".join(ordered[0].message.split()))  # one line, whatever the library wrote
