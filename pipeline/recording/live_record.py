"""What a recording says about a live source: frames captured, sent and skipped, the gaps of
its reconnects, how it ended, and the latency from capture to estimate.

A live source publishes a :class:`~stages.messages.Capture` for every frame it sends (always
recorded): the camera's frame number of each ``seq``, the frames skipped before it and the
seconds lost to a reconnect. Its heartbeats count the frames decoded (``captured``), skipped
and the reconnects; its reports (``reconnected``, ``stream_ended``) are on the errors topic.

Latency is the recorder's log time of each estimate minus the capture stamp its header carries
(the host clock when the frame was read): capture to estimate, as the recorder saw it. On one
host both clocks are the same clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stages.messages import (NOTICE_KINDS, Capture, ErrorReport, Estimate, MessageError, PoseEstimate, StageStatus,
                             decode)

from pipeline.io.mcap_io import iter_records

__all__ = ["LiveSummary", "live_summary", "latency_percentiles", "LIVE_REPORTS"]

#: the kinds of the reports a live source makes on the errors topic (news, not errors)
LIVE_REPORTS = NOTICE_KINDS


def latency_percentiles(latencies_ms) -> tuple[float, float, float]:
    """(p50, p99, max) in ms of a sequence of latencies (NaNs when it is empty)."""
    a = np.asarray(list(latencies_ms), dtype=np.float64)
    if a.size == 0:
        return float("nan"), float("nan"), float("nan")
    return float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.max())


@dataclass
class LiveSummary:
    """A live run, from its recording.

    frames : {seq: camera frame number} of the frames sent.
    captured : frames decoded since the source opened (its last heartbeat, or at least the
        frames accounted for by the captures).
    skipped : frames decoded and not sent (the newest frame wins).
    gaps : (camera frame after the gap, seconds) of each reconnect.
    reports : the source's reconnect and end-of-stream reports, in order.
    latency_ms : capture to recorded estimate, one per estimate.
    """

    frames: dict[int, int] = field(default_factory=dict)
    captured: int = 0
    skipped: int = 0
    reconnects: int = 0
    gaps: list[tuple[int, float]] = field(default_factory=list)
    reports: list[tuple[str, str]] = field(default_factory=list)
    latency_ms: list[float] = field(default_factory=list)
    tracking_s: float = 0.0  # from the first estimate to the last, the reconnects' waits left out

    @property
    def sent(self) -> int:
        return len(self.frames)

    @property
    def tracked(self) -> int:
        """Frames sent that have an estimate."""
        return len(self.latency_ms)

    def lines(self) -> list[str]:
        """What to tell the user: frames, skips, gaps, latency, how the stream ended. The frames
        captured add up: tracked + skipped + those in flight when the run stopped (decoded and not
        yet sent, or sent and not yet tracked)."""
        p50, p99, worst = latency_percentiles(self.latency_ms)
        flight = max(0, self.captured - self.tracked - self.skipped)
        out = [f"live source: {self.captured} frames captured, {self.tracked} tracked, {self.skipped} skipped "
               f"(the newest frame wins)" + (f", {flight} in flight when the run stopped" if flight else "")
               + (f", {self.reconnects} reconnect(s)" if self.reconnects else "")]
        if self.latency_ms:
            out.append(f"latency, capture to estimate: p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {worst:.1f} ms "
                       f"({len(self.latency_ms)} estimates)")
        out += [f"{kind}: {msg}" for kind, msg in self.reports]
        return out

    def to_json(self) -> dict:
        p50, p99, worst = latency_percentiles(self.latency_ms)
        return {"captured": self.captured, "sent": self.sent, "tracked": self.tracked, "skipped": self.skipped,
                "in_flight": max(0, self.captured - self.tracked - self.skipped), "reconnects": self.reconnects,
                "gaps": [{"frame": f, "seconds": s} for f, s in self.gaps],
                "reports": [{"kind": k, "message": m} for k, m in self.reports],
                "latency_ms": {"p50": p50, "p99": p99, "max": worst, "n": len(self.latency_ms)}}


def live_summary(path: str | Path, stream: str | None = None) -> LiveSummary | None:
    """The live-source figures of a recording (None when it has no Capture: not a live run)."""
    s = LiveSummary()
    skipped_before_sent = 0  # the captures' count; the heartbeats also count those after the last frame sent
    stamps: dict[int, int] = {}
    est_log: list[tuple[int, int]] = []  # (capture stamp, log time) of each estimate
    for r in iter_records(path):
        if stream and not r.topic.startswith(f"gflow/{stream}/"):
            continue
        if r.type not in ("Capture", "Estimate", "PoseEstimate", "StageStatus", "ErrorReport"):
            continue
        try:
            m = decode(r.data)
        except MessageError:
            continue
        if isinstance(m, Capture):
            s.frames[m.header.seq] = m.frame
            stamps[m.header.seq] = m.header.stamp_ns
            skipped_before_sent += m.skipped
            if m.gap_s > 0:
                s.gaps.append((m.frame, m.gap_s))
        elif isinstance(m, (Estimate, PoseEstimate)):
            est_log.append((m.header.stamp_ns, r.log_ns))
        elif isinstance(m, StageStatus) and m.captured:
            s.captured = max(s.captured, m.captured)
            s.reconnects = max(s.reconnects, m.reconnects)
            s.skipped = max(s.skipped, m.skipped)
        elif isinstance(m, ErrorReport) and m.kind in LIVE_REPORTS:
            s.reports.append((m.kind, m.message))
    if not s.frames:
        return None
    s.skipped = max(s.skipped, skipped_before_sent)
    s.captured = max(s.captured, max(s.frames.values()) + 1)
    s.reconnects = max(s.reconnects, len(s.gaps))
    live_stamps = set(stamps.values())
    s.latency_ms = [(log - st) / 1e6 for st, log in est_log if st in live_stamps]
    logs = [log for st, log in est_log if st in live_stamps]
    if len(logs) > 1:  # the time spent tracking, without the waits for a lost stream to come back
        s.tracking_s = max(0.0, (max(logs) - min(logs)) / 1e9 - sum(g for _, g in s.gaps))
    return s
