"""Running a :class:`~pipeline.app.request.TrackPlan`: :func:`run` yields its estimates while it
runs, :func:`track` runs it to its end; both come to a :class:`TrackResult`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Generator

from gflow_msgs.messages import Estimate, PoseEstimate

from pipeline.recording.live_record import LiveSummary
from pipeline.recording.results import RunOutcome, estimate_columns, renumber, run_outcome, write_boxes
from pipeline.app.request import Box, TrackPlan
from pipeline.app.recording_target import RecordingTarget
from pipeline.app.graph_run import EstimateSink, RunStop, default_zenoh, place, run_graph

__all__ = ["TrackResult", "run", "track"]

@dataclass
class TrackResult:
    """What one run of a :class:`TrackPlan` came to: its estimates by frame and how it went."""

    estimates: dict[int, Any]
    recording: str | None
    seconds: float
    frames: int
    info: dict
    kept: str = ""  # what the user is told about the recording
    temporary: bool = False  # no_record: no recording kept
    lines: list[str] = field(default_factory=list)  # what is missing, coasted, restarted
    incomplete: str = ""  # why the run is incomplete, or ""
    live: LiveSummary | None = None  # a live source's figures: skipped, gaps, latency
    #: wall time from the first frame published to the last estimate, read from the recording with
    #: the estimates (None without a recording, or when it holds no such span)
    tracking_seconds: float | None = None

    @property
    def frame_of(self) -> dict[int, int]:
        """{sequence number: camera frame} of a live run (empty otherwise: rows are the sequence numbers)."""
        return self.live.frames if self.live is not None else {}

    def columns(self) -> tuple[dict[int, Box], dict[int, float], dict[int, str]]:
        """The CSV's columns by frame: boxes, confidences, target states."""
        boxes, confidence, states = estimate_columns(self.estimates)
        frame_of = self.frame_of
        return renumber(boxes, frame_of), renumber(confidence, frame_of), renumber(states, frame_of)

    def points(self) -> dict:
        """G-flow's face: {frame: (landmark ids (n,), points (n, 2))}, by the reference landmark each vertex came from."""
        frame_of = self.frame_of
        return {frame_of.get(k, k): (v.landmarks.array(), v.mean_points.array()) for k, v in self.estimates.items()
                if getattr(v, "landmarks", None) is not None}

    def write_csv(self, path: str | Path, new: bool = False) -> None:
        """The boxes CSV: frame,x,y,w,h,confidence,state (and a live source's input: ok / damaged). ``new``:
        written beside ``path`` and moved there once complete, never over a file (:func:`write_boxes`)."""
        boxes, confidence, states = self.columns()
        write_boxes(path, boxes, confidence, states, self.live.inputs(boxes) if self.live is not None else None,
                    new=new)


def run(tp: TrackPlan) -> Generator[Estimate | PoseEstimate, None, TrackResult]:
    """Run a plan (inline or as processes) and yield each estimate as the :class:`EstimateSink`
    takes it from the run, while the run goes on (the graph runs on a thread of its own); at the
    end, any the sink lost that the recording holds, in frame order. The generator's return value
    is the :class:`TrackResult`, whatever happened to the run.

    Closing the generator early (``break`` out of a ``for`` loop, ``close()``) stops the run (as
    :class:`RunStop` says: the stages close, the recording is closed properly) and returns once it
    has stopped; an error of the run is raised from the generator."""
    import queue
    import threading

    items: queue.SimpleQueue = queue.SimpleQueue()
    end = object()
    stop = RunStop()
    outcome: dict[str, Any] = {}

    def work() -> None:
        try:
            outcome["result"] = _execute(tp, items.put, stop)
        except BaseException as e:  # noqa: BLE001 (raised again in the consumer's thread)
            outcome["error"] = e
        finally:
            items.put(end)

    runner = threading.Thread(target=work, name="gflow-run")
    runner.start()
    seen: set[int] = set()
    try:
        while (item := items.get()) is not end:
            seen.add(item.header.seq)
            yield item
    finally:
        if runner.is_alive():  # the consumer stopped early (or was interrupted): end the run
            stop.set()
        runner.join()
    if "error" in outcome:
        raise outcome["error"]
    result: TrackResult = outcome["result"]
    yield from (e for k, e in result.estimates.items() if k not in seen)  # filled in from the recording
    return result


def _execute(tp: TrackPlan, on_estimate: Callable[[Estimate | PoseEstimate], None] | None = None,
             stop: RunStop | None = None) -> TrackResult:
    """Run a plan in this thread: what it came to (``on_estimate``: told of each estimate as the
    sink takes it; ``stop``: ends the run early)."""
    from pipeline.runtime.live_plan import listen_early, live_source, prepare_live
    from pipeline.recording.live_record import live_summary

    req, plan = tp.request, tp.plan
    rec = plan.recorder()
    if rec is not None:  # recordings/track-TIME-RUNID.mcap, named when the run starts (Plan.recording_path)
        rec.params["path"] = "recordings/track-{time}.mcap"
    is_live = live_source(plan) is not None
    # a live run's camera frames and figures are read from its recording (a temporary one with no_record)
    target = RecordingTarget(plan, req.record, req.no_record, req.record_topics, None,
                             needed=("estimate",) if is_live else ())
    prepare_live(plan)  # after the recording: its topics may ask for the skipped frames
    network = req.network
    live = None
    # a UDP source's port, bound before anything starts (what a sender sends first is kept)
    listeners = listen_early(plan, say=None if req.quiet else lambda line: print(line, file=sys.stderr))
    try:
        hosts = place(plan, (), req.inline, req.stream)  # the run's stream names its topics
        sink = EstimateSink((t for s in plan.stages.values() for p, t in s.outputs.items() if p == "estimate"),
                            plan.error_topic, on_estimate)
        path, secs, frames, info = run_graph(plan, inline=req.inline, zenoh=lambda: network or default_zenoh(),
                                             listen_given=req.listen_given, recording=target.path, total=tp.total,
                                             hosts=hosts, quiet=req.quiet, strict=False, sink=sink,
                                             no_record=req.no_record, stop=stop)
        target.written(path)
        out: RunOutcome = run_outcome(path, plan, info, req.start, heard=sink.estimates, reported=sink.reported)
        if is_live and path:
            live = live_summary(path)
    finally:
        target.cleanup()
        for relay in listeners:
            relay.close()
    return TrackResult(estimates=dict(sorted(out.estimates.items())), recording=path, seconds=secs, frames=frames,
                       info=info, kept=target.kept, temporary=target.temporary or path is None,
                       lines=list(out.lines) + (live.lines() if live else []) + [x for r in listeners for x in r.lines()],
                       incomplete=out.why if out.incomplete else "", live=live, tracking_seconds=out.tracking_seconds)


def track(tp: TrackPlan) -> TrackResult:
    """Run a plan to its end in this thread (``gflow track``: Ctrl-C stops it as :func:`run` says)
    and return what it came to."""
    return _execute(tp)
