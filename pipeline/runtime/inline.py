"""Run a whole graph in one process with the same stage code and no zenoh.

Every payload is encoded and decoded exactly as over zenoh, and delivered in a fixed,
deterministic order (breadth-first from each source frame), so ``--inline`` and the
multi-process run give identical estimates, and the difference in speed between them is
the transport's overhead.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from stages.source import SourceStage

from pipeline.runtime.build import make_stage
from pipeline.runtime.graph import Plan, RecorderParams, recorded_topic_filter
from pipeline.runtime.stage_host import StageHost
from pipeline.runtime.memory import keep_freed_memory
from pipeline.io.recorder import McapRecorder
from pipeline.io.frame_readers import open_reader

__all__ = ["run_inline", "InlineResult"]

log = logging.getLogger("gflow.inline")


@dataclass
class InlineResult:
    frames: int
    seconds: float
    recording: str | None
    steps: dict[str, int] = field(default_factory=dict)
    errors: dict[str, int] = field(default_factory=dict)
    messages: int = 0
    interrupted: bool = False  # Ctrl-C ended the source early
    last_sent: int = -1  # the last frame the source sent (its sequence number; -1: none)

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0


def run_inline(plan: Plan, progress: Callable[[int], None] | None = None, recording: str | None = None,
               metadata: dict[str, dict[str, str]] | None = None,
               tap: Callable[[str, bytes, int, str], None] | None = None,
               stop: threading.Event | None = None) -> InlineResult:
    """Run ``plan`` to the end of its source (or until ``stop`` is set, or Ctrl-C: the source ends
    there, and every stage closes as at its end; ``interrupted`` says it was Ctrl-C). Returns
    counts, wall time and the recording path.

    ``tap(topic, payload, seq, type name)`` sees every message of the run, in the order it is
    delivered (an estimate sink: :class:`pipeline.app.EstimateSink`)."""
    keep_freed_memory()  # as every stage process does (pipeline/runtime/memory.py)
    queue: deque[tuple[str, bytes, int, str]] = deque()

    def publish(topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        queue.append((topic, payload, seq, type_name))

    hosts: dict[str, StageHost] = {}
    source_name = None
    for name, sp in plan.stages.items():
        if sp.kind == "recorder":
            continue
        stage = make_stage(plan, name)
        # one thread: nothing is prepared ahead (Stage.prepare), every step computes what it needs
        hosts[name] = StageHost(stage, sp.inputs, sp.outputs, plan.error_topic, publish,
                                sp.snapshot_every, plan.snapshot_topic(name), ahead=False)
        if isinstance(stage, SourceStage):
            source_name = name
    assert source_name is not None
    subscribers: dict[str, list[StageHost]] = {}
    for h in hosts.values():
        for topic in h.topics_in.values():
            subscribers.setdefault(topic, []).append(h)

    rec_plan = plan.recorder()
    rec: McapRecorder | None = None
    path = recording or plan.recording_path()
    keep = recorded_topic_filter(rec_plan.params if rec_plan else {}, plan.stream)
    if rec_plan is not None and path:
        rp = RecorderParams(**rec_plan.params)
        rec = McapRecorder(path, flush_interval=rp.flush_interval, compression=rp.compression,
                           chunk_size=rp.chunk_size, metadata=metadata or {}).open()
    src_host = hosts[source_name]
    src_stage = src_host.stage
    assert isinstance(src_stage, SourceStage)  # the one stage class of kind "source"

    def drain() -> None:
        while queue:
            topic, payload, seq, type_name = queue.popleft()
            if tap is not None:
                tap(topic, payload, seq, type_name)
            if rec is not None and keep(topic):
                rec.write(topic, payload, seq, publish_ns=time.time_ns(), type_name=type_name)
            for h in subscribers.get(topic, ()):
                h.deliver(topic, payload)

    t0 = time.perf_counter()
    frames = 0
    last_sent = -1
    interrupted = False
    opened = False  # the source gave something: before that, a failure is its opening's (removed below)
    try:
        try:
            for raw in open_reader(src_stage.params, plan.base_dir):
                opened = True
                if stop is not None and stop.is_set():
                    break
                outs = src_stage.emit(raw)
                src_host._flush_reports()
                src_host._emit(outs)
                sent = [m.header.seq for port, m in outs if port == "frames"]  # not a live source's captures
                frames += len(sent)
                last_sent = max([last_sent, *sent])
                drain()
                if progress is not None:
                    progress(frames)
        except KeyboardInterrupt:  # Ctrl-C: the frames so far are the run, which ends as at its source's end
            interrupted = True
            queue.clear()  # what the step cut short was sending
        src_host.close("end")
        drain()
        for h in hosts.values():  # stages whose drivers never ended (a broken graph) still close
            if not h.closed:
                h.close("end")
        drain()
    except BaseException:
        if rec is not None and path and not opened:
            # a source that cannot be opened (a camera that is not there, a stream that refuses): the
            # recording holds nothing but its metadata, and is removed, as a process run's is
            rec.close()
            rec = None
            Path(path).unlink(missing_ok=True)
        raise
    finally:
        if rec is not None:
            rec.close()
    dt = time.perf_counter() - t0
    return InlineResult(frames=frames, seconds=dt, recording=path if rec else None,
                        steps={n: h.stats.steps for n, h in hosts.items()},
                        errors={n: h.stats.errors for n, h in hosts.items()}, interrupted=interrupted,
                        messages=rec.messages if rec else 0, last_sent=last_sent)
