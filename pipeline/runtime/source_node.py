"""A source's stage process: frames from a folder, a video, a recording or the synthetic scene
(:class:`SourceNode`), or from a live stream or camera (:class:`LiveSourceNode`).

* A source sends nothing before the launcher's ``start`` and every peer's heartbeat, and stays
  within the flow-control window (:mod:`pipeline.runtime.flow_control`). It waits while the
  recorder's liveliness token is gone, so a recorder restart loses no more than the frames in
  flight.
* It announces its position (its heartbeat's ``last_seq`` and ``frame_shape``) before sending
  a frame: the first frame, then every ``window // 2`` frames (at most 4; every announcement
  wakes every process of the graph, ~1-2 ms of CPU a frame over them all on caviar1).
* Restarted, it goes on from the frame after the last one it sent.
* A live source (``kind: live``) opens its stream or camera while the node starts, before its
  first heartbeat, so a source that cannot be opened stops the run during start-up with one
  line naming it and what FFmpeg said (exit status 2, not restarted), and an ``--init`` box
  outside its frames is refused the same way. It then runs with ``live_ahead`` as its window
  and takes the newest frame each time the window has room: frames decoded meanwhile are
  skipped and counted (heartbeat ``captured`` / ``skipped`` / ``reconnects``, and the frames that
  never arrived and those decoded from damaged data: ``missed`` / ``damaged``).
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

import msgspec

from gflow_msgs.messages import StageStatus
from stages.source import RawFrame, SourceParams, SourceStage

from pipeline.runtime.flow_control import FlowControl
from pipeline.runtime.node_plan import EXIT_BAD_SOURCE, NodePlan
from pipeline.runtime.stage_node import StageNode

if TYPE_CHECKING:
    from pipeline.io.live_capture import LiveCapture

__all__ = ["SourceNode", "LiveSourceNode"]

log = logging.getLogger("gflow.node")


class SourceNode(StageNode):
    """A source of recorded or synthetic frames."""

    def __init__(self, node_plan: NodePlan) -> None:
        super().__init__(node_plan)
        self.flow = FlowControl(self.plan, self.name, self.flow_window())
        self.announced = -1  # the last frame announced
        self.frame_shape: tuple[int, ...] = ()

    def flow_window(self) -> int:
        return int(self.sp.params.get("max_ahead", 0))

    @property
    def source(self) -> SourceStage:
        assert self.host is not None and isinstance(self.host.stage, SourceStage)
        return self.host.stage

    @property
    def params(self) -> SourceParams:
        p = self.source.params
        assert isinstance(p, SourceParams)
        return p

    def declare(self) -> None:
        if self.flow.window:  # flow control: how far each worker has got, step by step
            self.bus.subscribe(self.plan.progress_topic("*"), self._on_status)
        super().declare()

    def heard(self, other: str, st: StageStatus) -> None:
        super().heard(other, st)
        self.flow.heard(other, st)

    def report(self) -> dict[str, Any]:
        out = super().report()
        out.update(last_seq=self.announced, waiting="", frame_shape=self.frame_shape)
        return out

    def _await_start(self) -> bool:
        """Wait for the launcher's start and every peer; False when told to stop meanwhile."""
        while not (self.started.is_set() and self.peers_ready.is_set()):
            if self.stop.wait(0.01):
                self.state = "stopped"
                return False
        self.state = "running"
        return True

    def work(self, resumed_after: int) -> int:
        host = self.host
        assert host is not None
        stage = self.source
        if resumed_after >= 0:  # restarted: go on from the frame after the last one sent
            p0 = self.params
            if p0.stop is not None and resumed_after + 1 >= p0.stop:
                host.close("end")
                return 0
            stage.params = msgspec.structs.replace(p0, start=max(p0.start, resumed_after + 1))
            self.announced = resumed_after
        if not self._await_start():
            return 0
        self.resend_last()
        p = self.params
        t0 = time.monotonic()
        first: int | None = None
        next_announce = -1
        from pipeline.io.frame_readers import open_reader  # the source's own import (cv2, the readers)

        for raw in open_reader(p, self.plan.base_dir):
            if self.stop.is_set():
                host.close("interrupted")
                self.state = "stopped"
                return 0
            if p.realtime:
                first = raw.index if first is None else first
                due = t0 + (raw.index - first) / p.fps
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            self.wait_for_room(raw.index)
            next_announce = self.send(raw, next_announce)
        host.close("end")
        return 0

    def send(self, raw: RawFrame, next_announce: int) -> int:
        """Emit one decoded frame: announce it (and its size) before sending it, every few
        frames; publish; checkpoint. Returns the frame to announce next."""
        host = self.host
        assert host is not None
        stage = self.source
        outs = stage.emit(raw)
        host._flush_reports()
        if outs:
            self.announced = max(self.announced, raw.index)
            shape = stage._shape
            self.frame_shape = tuple(int(d) for d in shape[:2]) if shape else ()
            if raw.index >= next_announce:
                next_announce = raw.index + max(1, min(4, self.window // 2))
                self.send_status()
        host._emit(outs)
        if outs:
            host.stats.steps += 1
            self.checkpoint(raw.index)
        now = time.perf_counter_ns()
        host.stats.first_step_ns = host.stats.first_step_ns or now
        host.stats.last_step_ns = now
        return next_announce

    def wait_for_room(self, index: int) -> None:
        """Before frame ``index``: wait while the recorder is down, then for room in the window."""
        warned = False
        while self.recorders and not self.stop.is_set() and not self.recorder_alive.wait(0.05):
            if not warned:  # the recorder is gone (restarting): nothing would be recorded
                log.warning("[%s] the recorder is not there: pausing before frame %d", self.name, index)
                warned = True
        self.flow.wait(index, self.stop)


class LiveSourceNode(SourceNode):
    """A live stream or camera: the newest frame each time the window has room."""

    capture: LiveCapture | None = None

    def flow_window(self) -> int:
        return int(self.sp.params.get("live_ahead", 1))

    def declare(self) -> None:
        super().declare()
        bad = self._open()
        if bad:  # nothing was sent: leave at once (closing the session took seconds)
            print(bad, file=sys.stderr, flush=True)
            os._exit(EXIT_BAD_SOURCE)

    def _open(self) -> str:
        """Open the live source (before the first heartbeat); '' or the one-line reason it cannot run."""
        from pipeline.io.frame_readers import open_live  # the source's own import (cv2, FFmpeg)
        from pipeline.io.live_capture import LiveSourceError
        from pipeline.runtime.preflight import PreflightError, box_needs, check_box_in_image

        p = self.params
        try:
            self.capture = cap = open_live(p)
        except LiveSourceError as e:
            return str(e)
        h, w = cap.shape[:2]
        needs = box_needs(self.plan)
        for sp in self.plan.stages.values():
            box = sp.params.get("init") if isinstance(sp.params, dict) else None
            if box is not None and len(box) == 4:
                try:
                    check_box_in_image(box, w, h, needs=needs)
                except PreflightError as e:
                    cap.close()
                    return f"{p.path}: {e}"
        return ""

    def report(self) -> dict[str, Any]:
        out = super().report()
        cap = self.capture
        if cap is not None:
            out.update(captured=cap.captured, skipped=cap.skipped, reconnects=cap.reconnects, missed=cap.missed,
                       damaged=cap.damaged)
        return out

    def work(self, resumed_after: int) -> int:
        """Each time the window has room, send the newest frame decoded (the others are skipped
        and counted); end when the stream ends or is not back in time. Restarted, it goes on
        numbering the frames it sends after the last one it sent (the camera's frame numbers
        start again at 0: the stream was opened anew)."""
        from pipeline.io.frame_readers import read_live

        host, cap = self.host, self.capture
        assert host is not None and cap is not None
        def interrupt_when_stopped() -> None:  # a read waiting for the stream returns at once
            self.stop.wait()
            cap.interrupt()

        threading.Thread(target=interrupt_when_stopped, daemon=True).start()
        if not self._await_start():
            cap.close()
            return 0
        seq = resumed_after + 1
        frames = read_live(cap, self.params, first_seq=seq)
        next_announce = -1
        while True:
            self.wait_for_room(seq)  # first room for a frame, then the newest frame there is
            raw = next(frames, None)
            if raw is None or self.stop.is_set():
                break
            next_announce = self.send(raw, next_announce)
            seq = raw.index + 1
        frames.close()
        if self.stop.is_set():
            host.close("interrupted")
            self.state = "stopped"
            return 0
        host.close("end")
        return 0
