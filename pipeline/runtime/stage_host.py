"""Host one stage: decode payloads, join by seq, call ``step``, encode and publish outputs.

The host is transport-free: it is given a ``publish(topic, payload, seq, type_name)`` callable. The
inline executor and the zenoh node process both use it, so a stage behaves identically
in-process, over zenoh, and when fed from an MCAP recording.

Every input is checked before it is joined (:meth:`StageHost.check`): its type, its
sequence number (not behind what was consumed, not a duplicate, not more than the
flow-control window ahead of the source when the source's position is known), its arrays
(shape, size and dtype consistent before anything is allocated from them; images no
larger than the frame size the source declared) and, for particles, finite values. A
message that fails is counted per kind (``HostStats.rejected``, sent in the heartbeat),
reported on the error topic, and never joined.
One of a port's last :data:`REPEAT_MEMORY` messages again, byte for byte (a restarted producer
resends its last step's outputs, then steps again from its checkpoint), is no error: it is counted (``HostStats.repeats``) and ignored.

Preparing ahead (``ahead``, on in a stage process, off in ``--inline``): a message on one of
the stage's ``prepare_ports`` is handed, once joined, to ``stage.prepare`` on a second
thread, so that the per-frame work of frame t+1 that needs nothing but its own input (the
appearance filter's orientation channels of the whole frame) runs while ``step`` works on
frame t or waits for its proposals. numpy and OpenCV release the GIL, so the two threads
use two cores. The step then takes the result (``Stage.prepared``) or, when nothing was
prepared, computes it itself: the outputs are the same bits either way. At most
``AHEAD_LIMIT`` results wait at once (the source runs up to ``max_ahead`` frames ahead, and
``gflow rerun`` feeds a recording as fast as it reads it), so memory stays bounded.
"""

from __future__ import annotations

import logging
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

if TYPE_CHECKING:
    from concurrent.futures import ThreadPoolExecutor

from stages.base import Stage, StageInputError
from gflow_msgs.foxglove import FOXGLOVE_SCHEMAS
from gflow_msgs.messages import (NOTICE_KINDS, EndOfStream, ErrorReport, Features, Frame, Header, MessageError, NDArray,
                             Particles, Snapshot, decode, encode)

__all__ = ["StageHost", "Publish", "AHEAD_LIMIT"]

log = logging.getLogger("gflow.host")

Publish = Callable[[str, bytes, int, str], None]

#: prepared results a host holds at most (each may be a frame's features: 1.8 MB at 384x288x4 float32)
AHEAD_LIMIT = 4
#: messages per port remembered to tell a restarted producer's repeats (byte for byte) from errors:
#: the step before its checkpoint and the step it was killed in
REPEAT_MEMORY = 3


@dataclass
class HostStats:
    steps: int = 0
    errors: int = 0
    last_error: str = ""
    first_step_ns: int = 0
    last_step_ns: int = 0
    busy_ns: int = 0
    received: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)  # bad input messages, by kind
    lost: int = 0  # frames stepped with nothing, or given up, after a fault
    repeats: int = 0  # a port's last message again, byte for byte (a restarted producer resends it)
    resumed_steps: int = 0  # steps done by the processes before a restart (from the checkpoint)

    def total_steps(self) -> int:
        """Steps of this stage over the run: this process's and, restarted, those before it."""
        return self.steps + self.resumed_steps

    def fps(self) -> float:
        if self.steps < 2 or self.last_step_ns <= self.first_step_ns:
            return 0.0
        return (self.steps - 1) * 1e9 / (self.last_step_ns - self.first_step_ns)


def set_compute_threads(threads: int = 1) -> None:
    """Give OpenCV the thread count of a stage (1 unless a stage process's plan says otherwise).

    Some OpenCV results depend on the number of threads: Canny with per-frame thresholds
    marks a few pixels differently where its parallel stripes meet (measured on crossing:
    up to 34 of 86400 pixels between 1 and 2 threads). Every way of running a stage --
    as a process, ``--inline``, ``gflow rerun``, ``gflow step`` -- builds a StageHost, so
    setting it here makes them compute with the same bits.
    """
    import cv2

    cv2.setNumThreads(threads)


class StageHost:
    """Runs one :class:`~stages.base.Stage` behind topics.

    Parameters
    ----------
    stage : the stage instance.
    topics_in : {port: topic} for every input port.
    topics_out : {port: topic} for every output port.
    error_topic : where :class:`ErrorReport` messages go.
    publish : ``publish(topic, payload, seq, type_name)``.
    cv_threads : OpenCV threads (a stage process's plan says how many; 1 everywhere else).
    """

    def __init__(self, stage: Stage, topics_in: dict[str, str], topics_out: dict[str, str], error_topic: str,
                 publish: Publish, snapshot_every: int = 0, snapshot_topic: str = "", lag: int = 0,
                 window: int = 0, on_step: Callable[[int], None] | None = None, ahead: bool = True,
                 cv_threads: int = 1) -> None:
        from pipeline.runtime.join import SeqJoin

        set_compute_threads(cv_threads)
        self.last_sent: list[tuple[str, bytes, int, str]] = []  # what the last step published
        stage.check_prepare()
        self.stage = stage
        self.name = stage.ctx.name
        self.topics_in = dict(topics_in)
        self.port_of = {t: p for p, t in topics_in.items()}
        self.topics_out = dict(topics_out)
        self.error_topic = error_topic
        self.publish = publish
        self.join = SeqJoin(tuple(stage.inputs), stage.driver_ports(), lag=lag, fill_gaps=len(stage.inputs) > 1)
        self.window = window  # flow-control window: how far ahead of the source a message may be
        self.source_seq = -1  # the last frame the source announced (-1: not known, no check)
        self.frame_shape: tuple[int, int] | None = None  # (H, W) the source declared
        self.on_step = on_step
        self.replayed_upto: dict[str, int] = {}  # after a restart: inputs already taken from the recording
        # port -> the last payloads that came on it (a restarted producer resends its last step's
        # outputs, then steps again from its checkpoint: both may have arrived before the kill)
        self.last_in: dict[str, deque[bytes]] = {}
        self.hold = False  # a peer is restarting: do not give inputs up for lateness (see tick)
        self._head: tuple[int, float] = (-1, 0.0)  # (lowest pending seq, when tick first saw it lowest)
        self.stats = HostStats()
        self.closed = False
        self.max_out: dict[str, int] = {}
        self.snapshot_every = snapshot_every
        self.snapshot_topic = snapshot_topic
        # preparing ahead: a thread of its own, started at the first message there is to prepare
        self.ahead = ahead and bool(stage.prepare_ports)
        self._pool: ThreadPoolExecutor | None = None
        self._unprepared: deque[tuple[str, Any]] = deque()  # joined, waiting for room to be prepared
        # inputs a little ahead of the source's last announcement, held until the next one covers
        # them: the announcement and the input travel on different links, so either may come first
        self.early: dict[str, deque[tuple[str, int, Any]]] = {}  # port -> (topic, seq, msg), in order

    # -- errors ------------------------------------------------------------------------------
    def report(self, kind: str, message: str, seq: int = -1, topic: str = "") -> None:
        if kind in NOTICE_KINDS:  # a live stream's reconnect or end: news, not an error
            # (damaged input is said: what it held is lost; a process run's console says every notice)
            (log.warning if kind == "damaged_input" else log.info)("[%s] %s: %s", self.name, kind, message)
        else:
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
        self.last_sent = []
        for port, msg in outputs:
            topic = self.topics_out.get(port)
            if topic is None:
                raise RuntimeError(f"stage {self.name} produced output on unknown port {port!r}")
            # gflow messages carry their frame in the header; Foxglove ones take the step's
            s = msg.header.seq if hasattr(msg, "header") else seq
            payload = encode(msg)
            self.publish(topic, payload, s, type(msg).__name__)
            self.last_sent.append((topic, payload, s, type(msg).__name__))
            self.max_out[port] = max(self.max_out.get(port, -1), s)

    def reject(self, kind: str, message: str, seq: int = -1, topic: str = "") -> None:
        """Count and report one input message that is not joined."""
        self.stats.rejected[kind] = self.stats.rejected.get(kind, 0) + 1
        self.report(kind, message, seq, topic)

    # -- checks --------------------------------------------------------------------------------
    def check(self, port: str, seq: int, msg: Any) -> str:
        """'' if ``msg`` (already of the port's type, ``seq`` already offset) may be joined,
        else ``"kind: why"``."""
        why = self.join.accepts(port, seq)
        if why:
            last = self.join.high.get(port, -1)
            return (f"{why}_seq: frame {seq} on a port at {last}, consumed up to {self.join.done_below}")
        for name in getattr(msg, "__struct_fields__", ()):
            arr = getattr(msg, name)
            if isinstance(arr, NDArray):
                bad = self._check_array(name, arr, isinstance(msg, (Frame, Features)))
                if bad:
                    return f"bad_array: {type(msg).__name__}.{name}: {bad}"
        if isinstance(msg, Particles):
            try:
                alpha, log_w = msg.alpha.array(), msg.log_w.array()
                ok = (np.isfinite(alpha).all() and not np.isnan(log_w).any() and not np.isposinf(log_w).any()
                      and alpha.shape[:1] == log_w.shape[:1])
            except (MessageError, ValueError, TypeError) as e:
                return f"bad_array: Particles: {e}"
            if not ok:
                return "bad_values: particles with NaN or inf, or alpha and log_w of different lengths"
        # last, so that an input held for being early is otherwise sound
        if self._ahead_of_source(seq):
            return (f"future_seq: frame {seq} is more than {self.window} frames ahead of the source "
                    f"(at {self.source_seq})")
        return ""

    def _ahead_of_source(self, seq: int) -> bool:
        return self.source_seq >= 0 and seq > self.source_seq + self.window + 1

    def _check_array(self, name: str, arr: NDArray, image: bool) -> str:
        """Shape against size and the declared frame, in Python integers (no overflow, no allocation)."""
        shape = arr.shape
        if len(shape) > 4 or any((not isinstance(d, int)) or not 0 <= d < 2**31 for d in shape):
            return f"shape {shape} is not a shape (at most 4 dimensions, each below 2^31)"
        try:
            itemsize = np.dtype(arr.dtype).itemsize
        except TypeError:
            return f"dtype {arr.dtype!r} is unknown"
        n = 1
        for d in shape:
            n *= d
        if n * itemsize != len(arr.data):
            return f"shape {shape} of {arr.dtype} needs {n * itemsize} bytes, got {len(arr.data)}"
        if image and self.frame_shape is not None and len(shape) >= 2 and tuple(shape[:2]) != self.frame_shape:
            return f"image shape {shape} is not the source's frame size {self.frame_shape}"
        return ""

    def waiting(self) -> str:
        """What the stage waits for, for a stall report: '' when it waits for nothing."""
        w = self.join.waiting(self.stage.required)
        if w is None:
            return ""
        seq, ports = w
        have = sorted(self.join.pending.get(seq, {}))
        return (f"frame {seq}: waiting for {', '.join(ports) or 'nothing'}"
                + (f" (has {', '.join(have)})" if have else ""))

    def tick(self, wait_s: float) -> None:
        """Wall-time rule: the lowest pending frame has waited ``wait_s`` since it became the
        next frame to step (not since its first input came: inputs that run ahead, like the
        frames of a cycle-bound G-flow proposal stage, arrive a whole flow-control window early)
        while the source is ahead of it (or a driver port has ended): give up its missing inputs
        and go on."""
        j = self.join
        if not self.closed and self.release_early():
            self.pump()
        if self.closed or not j.pending or self.hold:
            return
        seq, now = min(j.pending), time.monotonic()
        if self._head[0] != seq:
            self._head = (seq, now)
        if now - max(j.since.get(seq, now), self._head[1]) < wait_s:
            return
        ahead = self.source_seq > seq or bool(j.eos) or j.top() > seq
        if not ahead:
            return
        w = j.waiting(self.stage.required)
        # the topics given up go in the report's ``topic`` (comma-separated): `gflow rerun` replays
        # the give-up from them (pipeline/recording/rerun.py)
        missing = ",".join(self.topics_in[p] for p in w[1] if p in self.topics_in) if w and w[0] == seq else ""
        self.report("late_input", f"frame {seq}: no {', '.join(w[1]) if w else 'input'} after {wait_s:.1f} s "
                    "while the stream is ahead; going on without", seq, topic=missing)
        self.give_up(seq)

    def give_up(self, seq: int) -> None:
        """Step every frame up to ``seq`` with what it has (its missing inputs given up)."""
        self.join.force_below = max(self.join.force_below, seq)
        self.pump()

    # -- input -------------------------------------------------------------------------------
    def frame_of(self, topic: str, seq: int) -> int:
        """The frame an input of header ``seq`` on ``topic`` joins (the port's ``input_offsets``
        applied): a re-run from a snapshot at frame S skips the inputs of frames <= S, which
        the restored stage consumed before the snapshot (fed, each is an ``old_seq`` rejection)."""
        port = self.port_of.get(topic)
        return seq + (self.stage.input_offsets.get(port, 0) if port is not None else 0)

    def deliver(self, topic: str, payload: bytes, pump: bool = True) -> None:
        """Take one payload that arrived on ``topic``; run every step that became ready
        (with ``pump=False``, only store it: a batch is then released by :meth:`pump`)."""
        if self.closed:
            return
        port = self.port_of.get(topic)
        if port is None:
            return
        self.stats.received[port] = self.stats.received.get(port, 0) + 1
        recent = self.last_in.setdefault(port, deque(maxlen=REPEAT_MEMORY))
        if payload in recent:
            # a message before, byte for byte: a restarted producer sends its last step's outputs
            # again (they may not have left before it was killed) and then steps again from its
            # checkpoint, written after the step before the kill; what the first copy did stands
            self.stats.repeats += 1
            return
        recent.append(payload)
        try:
            msg = decode(payload)
        except MessageError as e:
            self.reject("malformed_message", f"on {topic}: {e}", topic=topic)
            return
        offset = self.stage.input_offsets.get(port, 0)
        self.release_early()
        if isinstance(msg, EndOfStream):
            self.join.end(port, msg.header.seq + offset)
        else:
            want: type[Any] = self.stage.inputs[port]  # a message class: the check narrows msg to a message
            if not isinstance(msg, want):
                self.reject("wrong_type", f"on {topic}: expected {want.__name__}, got {type(msg).__name__}",
                            msg.header.seq if hasattr(msg, "header") else -1, topic)
                return
            if msg.header.seq < 0:
                self.reject("bad_header", f"on {topic}: negative seq {msg.header.seq}", topic=topic)
                return
            if msg.header.seq + offset <= self.replayed_upto.get(port, -1):
                return  # the live copy of an input already replayed from the recording
            self._accept(port, topic, msg.header.seq + offset, msg)
        if pump:
            self.pump()

    def _accept(self, port: str, topic: str, seq: int, msg: Any, held: bool = False) -> None:
        """Check one decoded input (``seq`` offset) and join it, hold it as early, or reject it."""
        bad = self.check(port, seq, msg)
        if bad.startswith("future_seq") and not held and self._hold_early(port, topic, seq, msg):
            return
        if bad:
            kind, _, why = bad.partition(": ")
            self.reject(kind, f"on {topic}: {why}", msg.header.seq, topic)
            return
        self.join.push(port, seq, msg)
        if self.ahead and port in self.stage.prepare_ports:
            self._prepare_ahead(port, msg)

    def _hold_early(self, port: str, topic: str, seq: int, msg: Any) -> bool:
        """Hold an input at most one more window past the flow-control limit, and at most a
        window of them per port, until the source's next announcement covers it (True: held)."""
        q = self.early.setdefault(port, deque())
        if seq > self.source_seq + 2 * (self.window + 1) or len(q) >= self.window + 1:
            return False
        q.append((topic, seq, msg))
        return True

    def release_early(self, force: bool = False) -> bool:
        """Join the held inputs the source's announcements now cover (with ``force``, check
        them all again as they are); True if any was taken out of hold."""
        released = False
        for port, q in self.early.items():
            while q and (force or not self._ahead_of_source(q[0][1])):
                topic, seq, msg = q.popleft()
                self._accept(port, topic, seq, msg, held=True)
                released = True
        return released

    def _prepare_ahead(self, port: str, msg: Any) -> None:
        """Queue ``stage.prepare(port, msg)`` for the host's second thread."""
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"prepare-{self.name}")
        self._unprepared.append((port, msg))
        self._submit_prepare()

    def _submit_prepare(self) -> None:
        """Start the oldest queued preparations while fewer than AHEAD_LIMIT results wait (a
        message whose frame was stepped or given up meanwhile is dropped from the queue)."""
        pending, queued = self.stage.ahead, self._unprepared
        while queued and len(pending) < AHEAD_LIMIT:
            port, msg = queued.popleft()
            if msg.header.seq + self.stage.input_offsets.get(port, 0) <= self.join.done_below:
                continue
            assert self._pool is not None  # made before the first message was queued
            pending[(port, msg.header.seq)] = self._pool.submit(self.stage.prepare, port, msg).result

    def _forget_prepared(self, upto: int) -> None:
        """Drop what was prepared for frames stepped or given up (a step that did not ask for
        it), and start preparing what waited for room."""
        pending = self.stage.ahead
        for key in [k for k in pending if k[1] + self.stage.input_offsets.get(k[0], 0) <= upto]:
            del pending[key]
        self._submit_prepare()

    def pump(self) -> None:
        for seq, inputs in self.join.ready(self.stage.required):
            t0 = time.perf_counter_ns()
            nothing = all(v is None for v in inputs.values())
            try:
                outputs = self.stage.step(seq, inputs)
            except Exception as e:
                if self.ahead:
                    self._forget_prepared(seq)
                if not nothing:
                    self._step_failed(seq, e)
                    continue
                # a frame nothing arrived for (lost while a stage was down): this stage cannot use it
                self._flush_reports()
                self.stats.lost += 1
                self.report("lost_frame", f"frame {seq}: no input arrived for it; skipped", seq)
                continue
            if nothing:
                self.stats.lost += 1
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
            if self.on_step is not None:  # the checkpoint, which counts this step
                self.on_step(seq)
            if self.ahead:
                self._forget_prepared(seq)
        if self.join.finished:
            self.close("end")

    def _step_failed(self, seq: int, e: Exception) -> None:
        self._flush_reports()
        if isinstance(e, StageInputError):
            self.report("bad_input", str(e), seq)
        else:  # a bug in a stage must not take the pipeline down
            self.report("stage_exception", f"frame {seq}: {type(e).__name__}: {e}", seq)
            log.debug("%s", traceback.format_exc())

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
        self.release_early(force=True)  # what the source never covered is rejected as future_seq
        self.closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self.stage.ahead.clear()
            self._unprepared.clear()
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
