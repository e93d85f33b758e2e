"""What a recording says about a live source: frames captured, sent and skipped, the gaps of
its reconnects, how it ended, and the latency from capture to estimate.

A live source publishes a :class:`~gflow_msgs.messages.Capture` for every frame it sends (always
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

from gflow_msgs.messages import (NOTICE_KINDS, Capture, ErrorReport, Estimate, MessageError, PoseEstimate, StageStatus,
                             decode)

from pipeline.io.mcap_io import iter_records
from pipeline.recording.results import frame_ranges
from pipeline.io.run_sessions import RunSessions

__all__ = ["LiveSummary", "live_summary", "latency_percentiles", "LIVE_REPORTS"]

#: the kinds of the reports a live source makes on the errors topic (news, not errors)
LIVE_REPORTS = NOTICE_KINDS
#: reports of one kind listed in full before the rest are only counted
LISTED_REPORTS = 5


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
    gaps : (camera frame number of the first frame sent after the gap, seconds lost) of each
        reconnect (frames decoded after the gap and skipped before it are not named).
    reports : the source's reports (reconnects, frames missed, damaged input, the end), in order.
    latency_ms : capture to recorded estimate, one per estimate.
    missed : frames that never arrived (gaps in the stream's timestamps, reconnects).
    damaged : frames decoded from damaged data, sent or skipped.
    damaged_sent : the camera frame numbers of the frames sent that were damaged.
    """

    frames: dict[int, int] = field(default_factory=dict)
    captured: int = 0
    skipped: int = 0
    reconnects: int = 0
    gaps: list[tuple[int, float]] = field(default_factory=list)
    reports: list[tuple[str, str]] = field(default_factory=list)
    latency_ms: list[float] = field(default_factory=list)
    missed: int = 0
    damaged: int = 0
    damaged_sent: set[int] = field(default_factory=set)
    tracking_s: float = 0.0  # from the first estimate to the last, the reconnects' waits left out

    @property
    def sent(self) -> int:
        return len(self.frames)

    @property
    def tracked(self) -> int:
        """Frames sent that have an estimate."""
        return len(self.latency_ms)

    def inputs(self, frames) -> dict[int, str]:
        """The CSV's ``input`` column for these camera frames: ``damaged`` or ``ok``."""
        return {f: "damaged" if f in self.damaged_sent else "ok" for f in frames}

    def lines(self) -> list[str]:
        """What to tell the user: frames, skips, gaps, latency, how the stream ended. The frames
        captured add up: tracked + skipped + those in flight when the run stopped (decoded and not
        yet sent, or sent and not yet tracked)."""
        p50, p99, worst = latency_percentiles(self.latency_ms)
        flight = max(0, self.captured - self.tracked - self.skipped)
        out = [f"live source: {self.captured} frames captured, {self.tracked} tracked, {self.skipped} skipped "
               f"(the newest frame wins)" + (f", {flight} in flight when the run stopped" if flight else "")
               + (f", {self.reconnects} reconnect(s)" if self.reconnects else "")]
        if self.missed:
            out.append(f"{self.missed} frame(s) never arrived (the camera's frame numbers skip them: see the "
                       f"frames_missed and reconnected reports)")
        if self.damaged:
            out.append(f"{self.damaged} frame(s) decoded from damaged data, {len(self.damaged_sent)} of them tracked"
                       + (f" (frames {frame_ranges(self.damaged_sent)}; the CSV's input column says damaged)"
                          if self.damaged_sent else ""))
        if self.latency_ms:
            out.append(f"latency, capture to estimate: p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {worst:.1f} ms "
                       f"({len(self.latency_ms)} estimates)")
        shown: dict[str, int] = {}
        for kind, msg in self.reports:
            shown[kind] = shown.get(kind, 0) + 1
            if shown[kind] <= LISTED_REPORTS:
                out.append(f"{kind}: {msg}")
        out += [f"{kind}: {n - LISTED_REPORTS} more (gflow echo or the recording's errors topic has them all)"
                for kind, n in shown.items() if n > LISTED_REPORTS]
        return out

    def to_json(self) -> dict:
        p50, p99, worst = latency_percentiles(self.latency_ms)
        return {"captured": self.captured, "sent": self.sent, "tracked": self.tracked, "skipped": self.skipped,
                "in_flight": max(0, self.captured - self.tracked - self.skipped), "reconnects": self.reconnects,
                "missed": self.missed, "damaged": self.damaged, "damaged_sent": sorted(self.damaged_sent),
                "gaps": [{"frame": f, "seconds": s} for f, s in self.gaps],
                "reports": [{"kind": k, "message": m} for k, m in self.reports],
                "latency_ms": {"p50": p50, "p99": p99, "max": worst, "n": len(self.latency_ms)}}


def live_summary(path: str | Path, stream: str | None = None) -> LiveSummary | None:
    """The live-source figures of a recording (None when it has no Capture: not a live run)."""
    s = LiveSummary()
    skipped_before_sent = 0  # the captures' count; the heartbeats also count those after the last frame sent
    missed_before_sent = 0
    stamps: dict[int, int] = {}
    est_log: list[tuple[int, int, str, str]] = []  # (capture stamp, log time, topic, session) of each estimate
    sessions = RunSessions()
    for r in iter_records(path):
        if stream and not r.topic.startswith(f"gflow/{stream}/"):
            continue
        sessions.add(r)
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
            missed_before_sent += m.missed
            if m.damaged:
                s.damaged_sent.add(m.frame)
            if m.gap_s > 0:
                s.gaps.append((m.frame, m.gap_s))
        elif isinstance(m, (Estimate, PoseEstimate)):
            est_log.append((m.header.stamp_ns, r.log_ns, r.topic, r.source))
        elif isinstance(m, StageStatus) and m.captured:
            s.captured = max(s.captured, m.captured)
            s.reconnects = max(s.reconnects, m.reconnects)
            s.skipped = max(s.skipped, m.skipped)
            s.missed = max(s.missed, m.missed)
            s.damaged = max(s.damaged, m.damaged)
        elif isinstance(m, ErrorReport) and m.kind in LIVE_REPORTS:
            s.reports.append((m.kind, m.message))
    if not s.frames:
        return None
    s.skipped = max(s.skipped, skipped_before_sent)
    s.missed = max(s.missed, missed_before_sent)
    s.damaged = max(s.damaged, len(s.damaged_sent))
    s.captured = max(s.captured, s.sent + skipped_before_sent)  # frame numbers also count the frames missed
    s.reconnects = max(s.reconnects, len(s.gaps))
    live_stamps = set(stamps.values())
    own = [(st, log) for st, log, topic, source in est_log
           if st in live_stamps and sessions.is_own(topic, source)]  # the run's own estimates
    s.latency_ms = [(log - st) / 1e6 for st, log in own]
    logs = [log for _, log in own]
    if len(logs) > 1:  # the time spent tracking, without the waits for a lost stream to come back
        s.tracking_s = max(0.0, (max(logs) - min(logs)) / 1e9 - sum(g for _, g in s.gaps))
    return s
