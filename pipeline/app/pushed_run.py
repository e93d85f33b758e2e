"""A request's graph run in this process on frames pushed one at a time (:class:`PushedRun`).
"""

from __future__ import annotations

from typing import Any

from gflow_msgs.messages import ErrorReport, Estimate, PoseEstimate, decode

from pipeline.app.request import RequestError, TrackRequest, _graph_plan

__all__ = ["PushedRun"]

class PushedRun:
    """The graph of a request run in this process on frames pushed one at a time (the Python API's
    :class:`gflow.Tracker` for a tracker that is not on the protocol), exactly as ``--inline``
    runs it: every message encoded and decoded, delivered in the same order. The source stage
    only validates and stamps the frames it is given (media time at ``request.fps``); no recorder
    runs.

    problems : ``(frame, "stage: kind: message")`` of every error report, in order.
    """

    def __init__(self, request: TrackRequest, tracker: Any) -> None:
        from collections import deque

        from pipeline.runtime.build import make_stage
        from pipeline.runtime.stage_host import StageHost
        from stages.source import SourceStage

        plan = _graph_plan(request, tracker, {"kind": "synthetic", "fps": request.fps, "start": 0, "stop": None})
        self.queue: deque[tuple[str, bytes, int, str]] = deque()
        self.hosts: dict[str, StageHost] = {}
        for name, sp in plan.stages.items():
            if sp.kind == "recorder":
                continue
            try:
                stage = make_stage(plan, name)
            except (OSError, ValueError) as e:
                raise RequestError(f"stage {name}: {e}") from None
            self.hosts[name] = StageHost(stage, sp.inputs, sp.outputs, plan.error_topic, self._publish, ahead=False)
            if isinstance(stage, SourceStage):
                self.source, self.source_stage = self.hosts[name], stage
        self.subscribers: dict[str, list[StageHost]] = {}
        for h in self.hosts.values():
            for topic in h.topics_in.values():
                self.subscribers.setdefault(topic, []).append(h)
        self.estimate_topics = {t for s in plan.stages.values() for p, t in s.outputs.items() if p == "estimate"}
        self.error_topic = plan.error_topic
        self.problems: list[tuple[int, str]] = []

    def _publish(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        self.queue.append((topic, payload, seq, type_name))

    def _drain(self) -> list[Estimate | PoseEstimate]:
        """Deliver what was published, in order; the estimates among it."""
        out: list[Estimate | PoseEstimate] = []
        while self.queue:
            topic, payload, seq, type_name = self.queue.popleft()
            if topic in self.estimate_topics or topic == self.error_topic:
                msg = decode(payload)
                if isinstance(msg, (Estimate, PoseEstimate)):
                    out.append(msg)
                elif isinstance(msg, ErrorReport):
                    self.problems.append((seq, f"{msg.stage}: {msg.kind}: {msg.message}"))
            for h in self.subscribers.get(topic, ()):
                h.deliver(topic, payload)
        return out

    def push(self, image: Any, t: int) -> list[Estimate | PoseEstimate]:
        """Frame ``t`` (an image, or None: no frame) through the graph; the estimates it produced."""
        from stages.source import RawFrame

        if image is not None:
            src = self.source
            outs = self.source_stage.emit(RawFrame(t, image))
            src._flush_reports()
            src._emit(outs)
        return self._drain()

    def finish(self) -> list[Estimate | PoseEstimate]:
        """End of the frames: every stage closes; the estimates that produced."""
        for h in self.hosts.values():
            h.close("end")
        return self._drain()
