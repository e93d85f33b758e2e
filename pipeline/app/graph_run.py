"""Running a placed graph, inline or as processes (:func:`run_graph`), and what the application
layer takes from it while it runs: the :class:`EstimateSink`, and :class:`RunStop` to end it early.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable

from gflow_msgs.messages import Estimate, MessageError, PoseEstimate, decode

from pipeline.app.failures import FailureLog, error_report
from pipeline.runtime.graph import Plan
from pipeline.runtime.run_metadata import run_metadata
from pipeline.runtime.transport import SessionError, ZenohSettings, free_port
from pipeline.app.request import RequestError
from pipeline.app.recording_target import temporary_recording
from pipeline.app.network import DEFAULT_ENDPOINT, default_listen, default_zenoh

__all__ = ["run_graph", "place", "EstimateSink", "RunStop", "default_listen", "default_zenoh", "DEFAULT_ENDPOINT"]

# -- running a graph --------------------------------------------------------------------------------


def place(plan: Plan, hosts: tuple[str, ...], inline: bool, stream: str | None) -> tuple[str, ...]:
    """Check ``hosts`` against the whole graph and choose the run's stream (see
    :mod:`pipeline.runtime.runid`); return the host labels this process runs."""
    from pipeline.runtime.placement import local_stages
    from pipeline.runtime.runid import choose_stream

    local_stages(plan, hosts)  # an unknown label: one line naming the graph's labels
    if hosts and inline:
        raise RequestError("--host runs the stages placed on this host as processes; it cannot be combined with "
                           "--inline")
    if inline and not stream:
        return hosts  # one process, no network: nothing to mix with
    choose_stream(plan, stream, placed=bool(hosts))
    return hosts


def _startup_failure(plan: Plan, launcher, message: str) -> str:
    """What to tell the user when a run could not start. A live source that cannot be opened says
    so itself, in one line naming it and what FFmpeg said; the recording, which holds nothing but
    the start-up's heartbeats, is removed."""
    from pipeline.runtime.node_plan import EXIT_BAD_SOURCE

    src = next((n for n, s in plan.stages.items() if s.is_source()), None)
    exit_ = launcher.exits.get(src)
    if exit_ is None or exit_.returncode != EXIT_BAD_SOURCE or not exit_.last_error:
        return message
    if launcher.recording and plan.recorder() is not None:
        Path(launcher.recording).unlink(missing_ok=True)
    return f"cannot track {exit_.last_error}"


Tap = Callable[[str, bytes, int, str], None]


def _run_inline(plan: Plan, recording: str | None, total: int | None, quiet: bool, sink: EstimateSink | None,
                stop: RunStop | None):
    """:func:`run_graph` in this process: its progress line as a process run's (the first a
    second in, in place on a terminal), ending on the final count when one was shown."""
    from pipeline.runtime.inline import run_inline
    from pipeline.runtime.progress import Console

    console = Console(sys.stderr, not quiet)
    last = [time.monotonic(), 0.0]  # when the last line was shown (the first a second in), any shown

    def line(n: int) -> str:
        return f"  {n}" + (f"/{total}" if total else "") + " frames"

    def progress(n: int) -> None:
        now = time.monotonic()
        if console.enabled and now - last[0] >= 1.0:
            last[:] = [now, 1.0]
            console.progress(line(n))

    md = run_metadata(plan)
    failures = _failure_log(plan)

    def tap(topic: str, payload: bytes, seq: int, type_name: str) -> None:
        failures.tap(topic, payload, seq, type_name)
        if sink is not None:
            sink(topic, payload, seq, type_name)

    try:
        r = run_inline(plan, progress=progress, recording=recording, metadata=md, tap=tap,
                       stop=stop.event if stop is not None else None)
        if last[1]:  # the line shown last is the final count, not a count the run went past
            console.progress(line(r.frames))
    finally:
        if last[1]:
            console.end()
    bad = {n: e for n, e in r.errors.items() if e}
    if r.interrupted:  # as a multi-process run's Ctrl-C: what was tracked is kept
        print("interrupted: stages closed, recording closed", file=sys.stderr)
    return r.recording, r.seconds, r.frames, {"mode": "inline", "steps": r.steps, "errors": bad,
                                              "interrupted": r.interrupted, "last_sent": r.last_sent,
                                              "failures": failures.summary(r.frames)}


def _failure_log(plan: Plan) -> FailureLog:
    """A :class:`pipeline.app.failures.FailureLog` of the run of ``plan``: its errors topic, its estimate topics."""
    return FailureLog(plan.error_topic, (t for s in plan.stages.values() if s.kind != "recorder"
                                         for p, t in s.outputs.items() if p == "estimate"))


def run_graph(plan: Plan, *, inline: bool, zenoh: Callable[[], ZenohSettings], listen_given: bool,
              recording: str | None, total: int | None, hosts: tuple[str, ...] = (), quiet: bool = False,
              strict: bool = True, sink: EstimateSink | None = None, no_record: bool = False,
              stop: RunStop | None = None):
    """Run a placed plan inline or as processes; return (recording path, seconds, frames, per-stage info).

    ``zenoh()`` gives the settings of a multi-process run (asked only for one); ``sink`` is fed
    the run's estimates as they are published (inline) or heard (processes), and its error
    reports; ``stop`` ends the run early when set from another thread; ``no_record``: the run
    keeps no recording (so ``gflow ps`` says). With ``strict=False`` a run that did not finish
    cleanly returns (``info["ok"]`` False) instead of raising, so the caller can keep what was
    tracked."""
    if inline:
        return _run_inline(plan, recording, total, quiet, sink, stop)
    from pipeline.runtime.launcher import Launcher
    from pipeline.runtime.running import announce
    from pipeline.runtime.zygote import preload

    preload(s.kind for s in plan.stages.values())  # the stage processes' zygote imports their modules (once)

    settings = zenoh()
    from pipeline.runtime.preflight import PreflightError, check_listen

    try:  # before the line that says where the run listens
        check_listen(settings.listen)
    except PreflightError as e:
        raise RequestError(str(e)) from None
    while True:
        launcher = Launcher(plan, zenoh=settings, recording=recording, progress=not quiet,
                            total_frames=total, hosts=hosts, say_recording=not temporary_recording(recording))
        if sink is not None:  # each estimate as the launcher hears it
            launcher.monitor.on_estimate = sink.take
        if stop is not None:
            stop.attach(launcher)
        endpoints = [e for e in launcher.zenoh.listen if not e.endswith(":0")]
        if not quiet:
            here = ", ".join(n for n in plan.stages if n in launcher.local)
            where = f"host {', '.join(hosts)} ({here}); " if hosts else ""
            reach = (f"a client of {', '.join(launcher.zenoh.connect)}" if launcher.zenoh.mode == "client"
                     else f"listening on {', '.join(endpoints)}")
            print(f"{plan.name}: {where}{reach} (stream {plan.stream}; gflow ps, topics, echo and hz find it)",
                  file=sys.stderr)
        rec = plan.recorder()
        with announce(plan.stream, endpoints, name=plan.name, stages=sorted(launcher.local, key=list(plan.stages).index),
                      camera=plan.seed_stream, no_record=no_record or temporary_recording(recording),
                      external=plan.external, graph=list(plan.stages),
                      recording=(launcher.recording if rec and rec.name in launcher.local
                                 and not temporary_recording(recording) else None)):
            try:
                res = launcher.run()
            except SessionError as e:  # 7447, free a moment ago, taken by a run started at the same time
                if listen_given or settings.listen != (DEFAULT_ENDPOINT,) or "in use" not in str(e):
                    raise RequestError(str(e)) from None
                settings = dataclasses.replace(settings, listen=(f"tcp/127.0.0.1:{free_port()}",))
                continue  # nothing had started: the session is the launcher's first step
            except RuntimeError as e:  # start-up: a stage died, a host did not come, the stream is taken
                raise RequestError(_startup_failure(plan, launcher, str(e))) from None
        break
    if res.interrupted:
        print("interrupted: stages stopped, recording closed", file=sys.stderr)
    from pipeline.runtime.zygote import STOPPED_BEFORE_START

    for n, ex in res.exits.items():
        # a stage that Ctrl-C stopped before its node started is the interruption just said, not a stage failing
        # ("stage filter exited with status 130: ", a line per stage, under "interrupted")
        if ex.returncode != 0 and not (res.interrupted and ex.returncode == STOPPED_BEFORE_START and not ex.last_error):
            print(f"stage {n} exited with status {ex.returncode}: {ex.last_error}", file=sys.stderr)
    src = next((n for n, s in plan.stages.items() if s.is_source()), None)  # a graph fed from outside has none
    frames = res.status[src].steps if src in res.status else 0
    from pipeline.recording.live_record import LIVE_REPORTS  # a live source's reconnects and end: not errors

    info = {"mode": "processes", "ok": res.ok, "pids": res.pids, "peak_rss_mb": res.peak_rss_mb,
            "errors": sum(e.kind not in LIVE_REPORTS for e in res.errors), "fps": {n: s.fps for n, s in res.status.items()},
            "interrupted": res.interrupted, "stall": res.stall,
            "restarts": {n: e.restarts for n, e in res.exits.items() if e.restarts}, "estimates": res.estimates,
            # the last frame the source sent (its heartbeat's last_seq): what a run without a recording expected
            "last_sent": res.status[src].last_seq if src in res.status else -1}
    failures = _failure_log(plan)
    failures.take(res.errors, res.estimates)
    info["failures"] = failures.summary(frames)
    if sink is not None:  # what the launcher heard of the run: its estimates and its error reports
        for seq, payload in sorted(res.estimates.items()):
            sink.take(payload)
        for report in res.errors:
            sink.reported.add(report.header.seq)
    if res.stall:
        print(res.stall, file=sys.stderr)
    unsigned = {n: st.rejected["unsigned"] for n, st in res.status.items() if st.rejected.get("unsigned")}
    if unsigned:  # --run-key: what came from outside the run was dropped; say so
        info["unsigned"] = unsigned
        print("ignored messages not signed with the run key (from outside the run), by stage: "
              + ", ".join(f"{n} {c}" for n, c in sorted(unsigned.items())), file=sys.stderr)
    if strict and not res.ok and not res.interrupted:
        raise RequestError("the pipeline did not finish cleanly (see the messages above)")
    return res.recording, res.seconds, frames, info


# -- gflow track ---------------------------------------------------------------------------------


class EstimateSink:
    """The estimates and error reports of a run, taken from its messages as they are published
    (inline: every message of the run; processes: what the launcher heard on the run's topics).

    estimates : {frame: Estimate | PoseEstimate} of the run's estimate topics.
    reported : the frames a stage reported a problem with (an ``ErrorReport``).
    on_estimate : called with each estimate the first time its frame's is taken (from the thread
        that runs the graph, or the launcher's zenoh thread).
    """

    def __init__(self, estimate_topics: Iterable[str] = (), error_topic: str = "",
                 on_estimate: Callable[[Estimate | PoseEstimate], None] | None = None) -> None:
        self.topics = set(estimate_topics)
        self.error_topic = error_topic
        self.on_estimate = on_estimate
        self.estimates: dict[int, Estimate | PoseEstimate] = {}
        self.reported: set[int] = set()

    def __call__(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        """One message of an inline run (the tap of :func:`pipeline.runtime.inline.run_inline`)."""
        if topic in self.topics:
            self.take(payload)
        elif topic == self.error_topic and (report := error_report(payload)) is not None:
            self.reported.add(report.header.seq)

    def take(self, payload: bytes) -> None:
        """An estimate message (anything else on an estimate topic, such as its end of stream, is left)."""
        try:
            m = decode(payload)
        except MessageError:
            return
        if isinstance(m, (Estimate, PoseEstimate)):
            new = m.header.seq not in self.estimates
            self.estimates[m.header.seq] = m
            if new and self.on_estimate is not None:
                self.on_estimate(m)


class RunStop:
    """Ends a run early, asked from another thread (:func:`run`'s consumer stopping): inline, the
    source ends before its next frame and every stage closes as at its end; as processes, the
    launcher stops the stages as on Ctrl-C. Either way the recording is closed properly."""

    def __init__(self) -> None:
        import threading

        self.event = threading.Event()
        self._lock = threading.Lock()
        self._launchers: list[Any] = []

    def attach(self, launcher: Any) -> None:
        """The launcher of a multi-process run (stopped at once when the stop came first)."""
        with self._lock:
            self._launchers.append(launcher)
            if self.event.is_set():
                launcher.request_stop()

    def set(self) -> None:
        with self._lock:
            self.event.set()
            for launcher in self._launchers:
                launcher.request_stop()
