"""Progress: what a launcher hears from its stages, the progress line, and stall detection.

The launcher subscribes to every stage's heartbeat (``gflow/<stream>/_status/*``), the errors
topic and each estimate topic. This module keeps what they say (zenoh's threads hand it over
under a lock and never block), writes the progress line (rewritten in place on a terminal) and
the error lines, and names a stage that makes no progress for ``stall_timeout`` seconds while
the source is ahead of it, it waits for an input, or the sources have finished
(:class:`Stalled`).
"""

from __future__ import annotations

import collections
import os
import threading
import time
from typing import Callable, TextIO

from gflow_msgs.messages import NOTICE_KINDS, ErrorReport, StageStatus, decode

from pipeline.runtime.graph import Plan
from pipeline.runtime.transport import Bus

__all__ = ["Console", "ProgressMonitor", "Stalled", "LATENCY_WINDOW"]

#: estimates whose capture-to-estimate latency the progress line summarises (a live source)
LATENCY_WINDOW = 250
#: error reports printed before the rest are only counted
PRINTED_ERRORS = 20


class Stalled(Exception):
    """No stage made progress for ``stall_timeout`` seconds while the source was ahead."""


class Console:
    """The launcher's output: one line at a time, and a progress line that a terminal shows in
    place (nothing at all when ``enabled`` is false)."""

    def __init__(self, out: TextIO, enabled: bool) -> None:
        self.out = out
        self.enabled = enabled

    def say(self, text: str, always: bool = False) -> None:
        """One line (``always``: even when the console is off, as damaged input is said with -q)."""
        if self.enabled or always:
            if self.out.isatty():
                self.out.write("\r\033[K")
            self.out.write(text + "\n")
            self.out.flush()

    def progress(self, line: str) -> None:
        if not self.enabled:
            return
        if self.out.isatty():
            cols = os.get_terminal_size(self.out.fileno()).columns  # 0 when the terminal does not say
            self.out.write("\r\033[K" + (line[: cols - 1] if cols > 1 else line))
        else:
            self.out.write(line + "\n")
        self.out.flush()

    def end(self) -> None:
        """End the progress line a terminal shows in place."""
        if self.enabled and self.out.isatty():
            self.out.write("\n")


class ProgressMonitor:
    """What the stages of ``plan`` report, kept for the launcher.

    Parameters
    ----------
    plan : the graph.
    console : where error lines and the progress line go.
    total_frames : the frames the source will send, when known (shown as ``n/total``).
    live : the source is live: the progress line shows the capture-to-estimate latency.
    stall_timeout : seconds without progress before a stage is named as stalled (<= 0: never).
    """

    def __init__(self, plan: Plan, console: Console, total_frames: int | None = None, live: bool = False,
                 stall_timeout: float = 30.0) -> None:
        self.plan = plan
        self.console = console
        self.total_frames = total_frames
        self.live = live
        self.stall_timeout = stall_timeout
        self.status: dict[str, StageStatus] = {}
        self.errors: list[ErrorReport] = []
        self.estimates: dict[int, bytes] = {}  # every estimate payload of the run's stages heard, by frame
        self.on_estimate: Callable[[bytes], None] | None = None  # told of each as it is heard (pipeline.app.run)
        self.sessions: set[str] = set()  # the zenoh sessions of the run's stages (they beat)
        self.outside: dict[tuple[str, str], int] = {}  # (topic, session) -> estimates from outside the run
        self.peak_rss: dict[str, float] = {}
        self.latency_ms: collections.deque[float] = collections.deque(maxlen=LATENCY_WINDOW)
        self.stall = ""  # the stall report, when the run stopped for one
        self.lock = threading.Lock()
        self.heard = threading.Condition(self.lock)  # notified on every heartbeat
        self._progress_at: dict[str, tuple[tuple, float]] = {}
        self._last_line = 0.0
        self._shown = False  # a progress line was written: the run ends on its final one

    def subscribe(self, bus: Bus) -> None:
        """Listen to the heartbeats, the errors and the estimates of the graph."""
        plan = self.plan
        bus.subscribe(f"gflow/{plan.stream}/_status/*", self._on_status, with_source=True)
        bus.subscribe(plan.error_topic, self._on_error)
        for sp in plan.stages.values():
            if "estimate" in sp.outputs and sp.kind != "recorder":
                bus.subscribe(sp.outputs["estimate"], self._on_estimate, with_type=True, with_source=True)

    # -- zenoh callbacks (zenoh threads: hand over, never block) -----------------------------
    def _on_status(self, key: str, payload: bytes, pub_ns: int, seq: int, source: str = "") -> None:
        try:
            msg = decode(payload)
        except ValueError:
            return
        if isinstance(msg, StageStatus):
            with self.lock:
                if source:  # a stage process beats from its start, before it publishes anything else
                    self.sessions.add(source)
                old = self.status.get(msg.stage)
                if old is not None and old.pid == msg.pid and old.header.stamp_ns > msg.header.stamp_ns:
                    return  # an older heartbeat of the same process overtaken by its final one
                self.status[msg.stage] = msg
                self.peak_rss[msg.stage] = max(self.peak_rss.get(msg.stage, 0.0), msg.rss_mb)
                self.heard.notify_all()

    def _on_error(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        try:
            msg = decode(payload)
        except ValueError:
            return
        if isinstance(msg, ErrorReport):
            with self.lock:
                self.errors.append(msg)
                n = sum(e.kind not in NOTICE_KINDS for e in self.errors)
            # errors and damaged input are said with -q too (it drops progress, not what went wrong), as an
            # --inline run's log says them
            if msg.kind in NOTICE_KINDS:  # a live stream's reconnect or end: news, not an error
                self.console.say(f"{msg.stage}: {msg.message}", always=msg.kind == "damaged_input")
            elif n <= PRINTED_ERRORS:
                self.console.say(f"error from {msg.stage} [{msg.kind}] {msg.message}", always=True)
            elif n == PRINTED_ERRORS + 1:
                self.console.say("more errors: counting them without printing (see the recording's errors topic)",
                                 always=True)

    def _on_estimate(self, key: str, payload: bytes, pub_ns: int, seq: int, type_name: str, source: str = "") -> None:
        if source not in self.sessions:  # another zenoh session on the run's estimate topic: not the run's
            with self.lock:
                self.outside[(key, source)] = self.outside.get((key, source), 0) + 1
            return
        # a copy of every estimate: what the recording lost (a recorder restart) is still known
        if seq >= 0 and type_name in ("Estimate", "PoseEstimate"):
            self.estimates[seq] = payload
            if self.on_estimate is not None:
                self.on_estimate(payload)
            if self.live:
                now = time.time_ns()
                try:
                    self.latency_ms.append((now - decode(payload).header.stamp_ns) / 1e6)
                except (ValueError, AttributeError):
                    pass

    # -- what the launcher asks --------------------------------------------------------------
    def await_final(self, names: list[str], timeout: float) -> bool:
        """Wait up to ``timeout`` s for the final heartbeat (state ``done`` or ``stopped``) of
        every stage of ``names``, which their processes send just before they exit; whether all
        arrived. The counts a run reports at its end (messages rejected, frames skipped) are in it."""
        with self.heard:
            return self.heard.wait_for(
                lambda: all(n in self.status and self.status[n].state in ("done", "stopped") for n in names), timeout)

    def snapshot(self) -> dict[str, StageStatus]:
        """The last heartbeat of every stage heard so far."""
        with self.lock:
            return dict(self.status)

    def states(self) -> dict[str, str]:
        with self.lock:
            return {n: st.state for n, st in self.status.items()}

    def forget(self, name: str) -> None:
        """A new process of stage ``name`` starts: its stall clock starts again."""
        self._progress_at.pop(name, None)

    def line(self) -> str:
        """The progress line: every stage's steps, rate and drops (the recorder's messages)."""
        parts = []
        plan = self.plan
        with self.lock:
            # heartbeats arrive at different times: the source has sent at least what any stage did
            done = max((st.steps for n, st in self.status.items() if n in plan.stages
                        and plan.stages[n].kind != "recorder"), default=0)
            for name in plan.stages:
                st = self.status.get(name)
                if st is None:
                    parts.append(f"{name}: -")
                elif plan.stages[name].kind == "recorder":
                    parts.append(f"{name}: {st.steps} msgs")
                else:
                    drop = sum(st.dropped.values())
                    source = plan.stages[name].is_source()
                    steps = max(st.steps, done) if source else st.steps
                    parts.append(f"{name}: {steps}" + (f"/{self.total_frames}" if self.total_frames and source else "")
                                 + f" @{st.fps:.1f}fps" + (f" drop={drop}" if drop else "")
                                 + (f" skipped={st.skipped}" if st.captured else "")
                                 + (f" missed={st.missed}" if st.missed else "")
                                 + (f" damaged={st.damaged}" if st.damaged else ""))
            lat = sorted(self.latency_ms)
            outside = sum(self.outside.values())
        if outside:
            parts.append(f"outside the run: {outside} estimates ignored")
        if lat:  # capture to estimate, over the last LATENCY_WINDOW estimates
            parts.append(f"latency p50 {lat[len(lat) // 2]:.0f} ms p99 {lat[min(len(lat) - 1, int(0.99 * len(lat)))]:.0f} ms")
        return " | ".join(parts)

    def begin(self, now: float) -> None:
        """The stages were told to start: the first progress line comes a second later."""
        self._last_line = now

    def show(self, now: float) -> None:
        """Write the progress line, at most once a second."""
        if self.console.enabled and now - self._last_line >= 1.0:
            self.console.progress(self.line())
            self._last_line = now
            self._shown = True

    def show_final(self) -> None:
        """Once the stages' final heartbeats are in: write the progress line again when one was
        shown, so the run ends on its final counts, not on those of the last one-second tick."""
        if self.console.enabled and self._shown:
            self.console.progress(self.line())

    def check_stall(self, workers: list[str], alive: Callable[[str], bool], now: float) -> None:
        """Raise :class:`Stalled` when a live stage of ``workers`` has not moved for
        ``stall_timeout`` s while the source is ahead of it, it waits for an input, or the
        sources have finished."""
        if self.stall_timeout <= 0:
            return
        status = self.snapshot()
        sources = [n for n in workers if self.plan.stages[n].is_source()]
        src = max((status[n].last_seq for n in sources if n in status), default=-1)
        sources_done = bool(sources) and all(n in status and status[n].state == "done" for n in sources)
        stuck = []
        for n in workers:
            st = status.get(n)
            if st is None or n in sources or st.state in ("done", "stopped", "draining") or not alive(n):
                continue
            key = (st.pid, st.steps, st.last_seq)
            prev = self._progress_at.get(n)
            if prev is None or prev[0] != key:
                self._progress_at[n] = (key, now)
                continue
            if now - prev[1] >= self.stall_timeout and (src > st.last_seq or st.waiting or sources_done):
                stuck.append(f"{n} after frame {st.last_seq}" + (f" ({st.waiting})" if st.waiting else ""))
        if stuck:
            self.stall = (f"stalled: no progress for {self.stall_timeout:.0f} s while the source is at frame {src}: "
                          + "; ".join(stuck))
            raise Stalled(self.stall)
