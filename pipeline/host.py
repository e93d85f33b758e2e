"""Host one stage: decode payloads, join by seq, call ``step``, encode and publish outputs.

The host is transport-free: it is given a ``publish(topic, payload, seq, type_name)`` callable. The
inline executor and the zenoh node process both use it, so a stage behaves identically
in-process, over zenoh, and when fed from an MCAP recording.
"""

from __future__ import annotations

import logging
import time
import traceback
from dataclasses import dataclass, field
from typing import Callable

from stages.base import Stage, StageInputError
from stages.messages_foxglove import FOXGLOVE_SCHEMAS
from stages.messages import EndOfStream, ErrorReport, Header, MessageError, Snapshot, decode, encode

__all__ = ["StageHost", "Publish"]

log = logging.getLogger("gflow.host")

Publish = Callable[[str, bytes, int, str], None]


@dataclass
class HostStats:
    steps: int = 0
    errors: int = 0
    last_error: str = ""
    first_step_ns: int = 0
    last_step_ns: int = 0
    busy_ns: int = 0
    received: dict[str, int] = field(default_factory=dict)

    def fps(self) -> float:
        if self.steps < 2 or self.last_step_ns <= self.first_step_ns:
            return 0.0
        return (self.steps - 1) * 1e9 / (self.last_step_ns - self.first_step_ns)


class StageHost:
    """Runs one :class:`~stages.base.Stage` behind topics.

    Parameters
    ----------
    stage : the stage instance.
    topics_in : {port: topic} for every input port.
    topics_out : {port: topic} for every output port.
    error_topic : where :class:`ErrorReport` messages go.
    publish : ``publish(topic, payload, seq, type_name)``.
    """

    def __init__(self, stage: Stage, topics_in: dict[str, str], topics_out: dict[str, str], error_topic: str,
                 publish: Publish, snapshot_every: int = 0, snapshot_topic: str = "") -> None:
        from .join import SeqJoin

        self.stage = stage
        self.name = stage.ctx.name
        self.topics_in = dict(topics_in)
        self.port_of = {t: p for p, t in topics_in.items()}
        self.topics_out = dict(topics_out)
        self.error_topic = error_topic
        self.publish = publish
        self.join = SeqJoin(tuple(stage.inputs), stage.driver_ports())
        self.stats = HostStats()
        self.closed = False
        self.max_out: dict[str, int] = {}
        self.snapshot_every = snapshot_every
        self.snapshot_topic = snapshot_topic

    # -- errors ------------------------------------------------------------------------------
    def report(self, kind: str, message: str, seq: int = -1, topic: str = "") -> None:
        self.stats.errors += 1
        self.stats.last_error = f"{kind}: {message}"
        log.warning("[%s] %s: %s", self.name, kind, message)
        err = ErrorReport(header=Header(self.stage.ctx.stream, max(seq, 0), 0), stage=self.name, kind=kind,
                          message=message, topic=topic)
        self.publish(self.error_topic, encode(err), max(seq, 0), "ErrorReport")

    def _flush_reports(self) -> None:
        for kind, message, seq in self.stage.drain_reports():
            self.report(kind, message, seq)

    def _emit(self, outputs, seq: int = -1) -> None:
        for port, msg in outputs:
            topic = self.topics_out.get(port)
            if topic is None:
                raise RuntimeError(f"stage {self.name} produced output on unknown port {port!r}")
            # gflow messages carry their frame in the header; Foxglove ones take the step's
            s = msg.header.seq if hasattr(msg, "header") else seq
            self.publish(topic, encode(msg), s, type(msg).__name__)
            self.max_out[port] = max(self.max_out.get(port, -1), s)

    # -- input -------------------------------------------------------------------------------
    def deliver(self, topic: str, payload: bytes) -> None:
        """Take one payload that arrived on ``topic``; run every step that became ready."""
        if self.closed:
            return
        port = self.port_of.get(topic)
        if port is None:
            return
        self.stats.received[port] = self.stats.received.get(port, 0) + 1
        try:
            msg = decode(payload)
        except MessageError as e:
            self.report("malformed_message", f"on {topic}: {e}", topic=topic)
            return
        offset = self.stage.input_offsets.get(port, 0)
        if isinstance(msg, EndOfStream):
            self.join.end(port, msg.header.seq + offset)
        else:
            want = self.stage.inputs[port]
            if not isinstance(msg, want):
                self.report("wrong_type", f"on {topic}: expected {want.__name__}, got {type(msg).__name__}",
                            msg.header.seq if hasattr(msg, "header") else -1, topic)
                return
            if msg.header.seq < 0:
                self.report("bad_header", f"on {topic}: negative seq {msg.header.seq}", topic=topic)
                return
            self.join.push(port, msg.header.seq + offset, msg)
        self.pump()

    def pump(self) -> None:
        for seq, inputs in self.join.ready(self.stage.required):
            t0 = time.perf_counter_ns()
            try:
                outputs = self.stage.step(seq, inputs)
            except StageInputError as e:
                self._flush_reports()
                self.report("bad_input", str(e), seq)
                continue
            except Exception as e:  # a bug in a stage must not take the pipeline down
                self._flush_reports()
                self.report("stage_exception", f"frame {seq}: {type(e).__name__}: {e}", seq)
                log.debug("%s", traceback.format_exc())
                continue
            t1 = time.perf_counter_ns()
            self._flush_reports()
            self._emit(outputs, seq)
            if self.snapshot_every and seq % self.snapshot_every == 0:
                self._snapshot(seq)
            st = self.stats
            st.steps += 1
            st.busy_ns += t1 - t0
            st.last_step_ns = t1
            if st.first_step_ns == 0:
                st.first_step_ns = t1
        if self.join.finished:
            self.close("end")

    def _snapshot(self, seq: int) -> None:
        data = self.stage.snapshot()
        if data is None:
            return
        snap = Snapshot(header=Header(self.stage.ctx.stream, seq, 0), stage=self.name, kind=self.stage.kind, data=data)
        self.publish(self.snapshot_topic, encode(snap), seq, "Snapshot")

    def close(self, reason: str = "end") -> None:
        """Finish the stage and publish an end of stream on each output (once)."""
        if self.closed:
            return
        self.closed = True
        try:
            self._emit(self.stage.finish())
        except Exception as e:
            self.report("stage_exception", f"finish: {type(e).__name__}: {e}")
        self._flush_reports()
        for port, topic in self.topics_out.items():
            if self.stage.outputs.get(port) in FOXGLOVE_SCHEMAS:
                continue  # viewer topics stay pure Foxglove JSON; no gflow stage consumes them
            end = self.max_out.get(port, -1) + 1
            eos = EndOfStream(header=Header(self.stage.ctx.stream, end, 0), reason=reason)
            self.publish(topic, encode(eos), end, "EndOfStream")
