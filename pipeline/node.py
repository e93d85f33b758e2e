"""One stage as its own OS process on zenoh: ``python -m pipeline.node PLAN.json STAGE``.

Start-up handshake: every node publishes a heartbeat (:class:`StageStatus`) on
``gflow/<stream>/_status/<stage>`` twice a second, after declaring its subscribers. A node
publishes data only once it has heard a heartbeat from every other node of the graph: the
heartbeat came over the direct peer link after that node's subscriber declarations, so
no early message can miss a subscriber. Sources additionally wait for the launcher's
``start`` on ``gflow/<stream>/_control``.

Shutdown: SIGINT or SIGTERM makes a stage abandon what is queued, publish end of stream
on its outputs and exit 0; the recorder closes its MCAP file properly. A Python exception
exits 1 with the traceback on stderr (the launcher shows its last line).
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import sys
import threading
import time
from pathlib import Path

import psutil

from stages.messages import Control, Header, StageStatus, decode, encode
from stages.source import SourceStage

from .build import make_stage
from .graph import Plan, RecorderParams, recorded_topic_filter
from .host import StageHost
from .recorder import McapRecorder
from .sources import open_reader
from .transport import Bus, ZenohSettings, open_session

__all__ = ["main", "run_node"]

log = logging.getLogger("gflow.node")

FLOW_STALL_S = 1.0


class Node:
    def __init__(self, plan: Plan, name: str) -> None:
        self.plan = plan
        self.name = name
        self.sp = plan.stages[name]
        self.stop = threading.Event()
        self._hb_stop = threading.Event()
        self.started = threading.Event()
        self.peers_ready = threading.Event()
        self.seen: set[str] = set()
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.state = "starting"
        self.steps = 0
        self.proc = psutil.Process()
        self.session = open_session(ZenohSettings.from_json(plan.zenoh))
        self.bus = Bus(self.session, plan.drop_topics())
        self._status_pub = self.bus.publisher(plan.status_topic(name))
        self.host: StageHost | None = None
        self.recorder: McapRecorder | None = None
        # flow control (sources only): how far each worker stage has got
        self.flow_window = int(self.sp.params.get("max_ahead", 0)) if self.sp.is_source() else 0
        self.flow_stages = {n for n, s in plan.stages.items() if s.kind != "recorder" and not s.is_source()}
        self.progress_of: dict[str, int] = {}
        self.first_pid: dict[str, int] = {}
        self.progress_changed = threading.Event()
        self._last_status = 0.0
        self._reported_steps = 0
        # every worker reports progress quickly when some source applies flow control
        self.flow_stages_waiting = any(s.is_source() and s.params.get("max_ahead", 0) for s in plan.stages.values())

    # -- handshake ---------------------------------------------------------------------------
    def _on_status(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        other = key.rsplit("/", 1)[-1]
        if self.flow_window and other in self.flow_stages:
            try:
                st = decode(payload)
                if isinstance(st, StageStatus):
                    first_pid = self.first_pid.setdefault(other, st.pid)
                    if st.state == "done" or (st.pid != first_pid and st.last_seq < 0):
                        # finished, or restarted and not yet caught up: do not hold the source back
                        self.progress_of[other] = 1 << 60
                    else:
                        self.progress_of[other] = st.last_seq
                    self.progress_changed.set()
            except ValueError:
                pass
        if other not in self.seen:
            self.seen.add(other)
            if self.seen >= set(self.plan.stages):
                self.peers_ready.set()

    def _on_control(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        try:
            msg = decode(payload)
        except ValueError:
            return
        if isinstance(msg, Control):
            if msg.command == "start":
                self.started.set()
            elif msg.command == "stop":
                self.stop.set()

    def _on_data(self, key: str, payload: bytes, pub_ns: int, seq: int, type_name: str = "") -> None:
        self.inbox.put((key, payload, pub_ns, seq, type_name))

    def publish(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        if not self.peers_ready.is_set():
            while not self.peers_ready.wait(5.0):
                missing = sorted(set(self.plan.stages) - self.seen)
                log.warning("[%s] still waiting to hear from %s before publishing", self.name, ", ".join(missing))
                if self.stop.is_set():
                    return
        self.bus.publish(topic, payload, seq, type_name)

    def status(self) -> StageStatus:
        h = self.host
        dropped = dict(h.join.gaps) if h else {}
        fps = h.stats.fps() if h else 0.0
        errors = h.stats.errors if h else 0
        last = h.stats.last_error if h else ""
        steps = h.stats.steps if h else self.steps
        if self.recorder is not None:
            steps = self.recorder.messages
        last_seq = h.join.done_below if h else -1
        return StageStatus(header=Header(self.plan.stream, steps, time.time_ns()), stage=self.name, pid=os.getpid(),
                           state=self.state, steps=steps, fps=round(fps, 2), dropped=dropped, errors=errors,
                           last_error=last[-300:], rss_mb=round(self.proc.memory_info().rss / 2**20, 1),
                           last_seq=last_seq, queued=self.inbox.qsize(),
                           busy_ms=round(h.stats.busy_ns / h.stats.steps / 1e6, 3) if h and h.stats.steps else 0.0)

    def send_status(self, min_interval: float = 0.0) -> None:
        now = time.monotonic()
        if now - self._last_status >= min_interval:
            self._last_status = now
            st = self.status()
            self.bus.publish(self.plan.status_topic(self.name), encode(st), st.header.seq, "StageStatus")

    def _heartbeat(self) -> None:
        while not self._hb_stop.is_set():
            try:
                self.send_status()
            except Exception:  # session closing
                return
            self._hb_stop.wait(0.5)

    # -- run ---------------------------------------------------------------------------------
    def run(self) -> int:
        plan, sp = self.plan, self.sp
        self.bus.subscribe(f"gflow/{plan.stream}/_status/*", self._on_status)
        self.bus.subscribe(plan.control_topic, self._on_control)
        if sp.kind == "recorder":
            keep = recorded_topic_filter(sp.params, plan.stream)  # --record-topics
            self.bus.subscribe(f"gflow/{plan.stream}/**", lambda k, *a: keep(k) and self._on_data(k, *a), with_type=True)
        else:
            stage = make_stage(plan, self.name)
            self.host = StageHost(stage, sp.inputs, sp.outputs, plan.error_topic, self.publish,
                                  sp.snapshot_every, plan.snapshot_topic(self.name))
            for topic in sp.inputs.values():
                self.bus.subscribe(topic, self._on_data, with_type=True)
        hb = threading.Thread(target=self._heartbeat, daemon=True)
        hb.start()
        self.state = "ready"
        try:
            if sp.kind == "recorder":
                return self._run_recorder()
            if isinstance(self.host.stage, SourceStage):  # type: ignore[union-attr]
                return self._run_source()
            return self._run_stage()
        finally:
            self.state = "done" if self.state != "stopped" else "stopped"
            self._hb_stop.set()
            hb.join(timeout=1.0)
            try:
                self.send_status()  # the final heartbeat says "done"; best effort
            except Exception as e:  # the session may already be closing on interrupt
                log.debug("[%s] final heartbeat not sent: %s", self.name, e)
            time.sleep(0.1)  # let the last samples leave before the session closes
            self.session.close()

    def _run_source(self) -> int:
        host = self.host
        assert host is not None
        stage: SourceStage = host.stage  # type: ignore[assignment]
        while not (self.started.is_set() and self.peers_ready.is_set()):
            if self.stop.wait(0.01):
                self.state = "stopped"
                return 0
        self.state = "running"
        p = stage.params
        t0 = time.monotonic()
        first: int | None = None
        for raw in open_reader(p, self.plan.base_dir):  # type: ignore[arg-type]
            if self.stop.is_set():
                host.close("interrupted")
                self.state = "stopped"
                return 0
            if p.realtime:  # type: ignore[attr-defined]
                first = raw.index if first is None else first
                due = t0 + (raw.index - first) / p.fps  # type: ignore[attr-defined]
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            self._flow_wait(raw.index)
            outs = stage.emit(raw)
            host._flush_reports()
            host._emit(outs)
            host.stats.steps += len(outs)
            now = time.perf_counter_ns()
            host.stats.first_step_ns = host.stats.first_step_ns or now
            host.stats.last_step_ns = now
        host.close("end")
        return 0

    def _flow_wait(self, index: int) -> None:
        """Stay at most ``max_ahead`` frames in front of the slowest stage. A stage that makes
        no progress for FLOW_STALL_S (it lost frames while restarting, say, and waits for a
        later one to tell it so) does not hold the source back forever."""
        stalled_since = time.monotonic()
        last = None
        while self.flow_window and not self.stop.is_set():
            slowest = min((self.progress_of.get(n, -1) for n in self.flow_stages), default=1 << 60)
            if index - slowest <= self.flow_window:
                return
            if slowest != last:
                last, stalled_since = slowest, time.monotonic()
            elif time.monotonic() - stalled_since > FLOW_STALL_S:
                log.warning("[%s] flow control: no progress past frame %d for %.1f s; sending frame %d anyway",
                            self.name, slowest, FLOW_STALL_S, index)
                return
            self.progress_changed.clear()
            self.progress_changed.wait(0.05)

    def _run_stage(self) -> int:
        host = self.host
        assert host is not None
        self.state = "running"
        while not host.closed:
            if self.stop.is_set():
                host.close("interrupted")
                self.state = "stopped"
                return 0
            try:
                key, payload, _, _, _ = self.inbox.get(timeout=0.1)
            except queue.Empty:
                continue
            host.deliver(key, payload)
            if self.flow_stages_waiting:
                self.send_status(0.02)
            if host.stats.steps != self._reported_steps and self.inbox.empty():
                # idle after work: say how far we got at once (replay --lockstep waits for it)
                self._reported_steps = host.stats.steps
                self.send_status()
        return 0

    def _run_recorder(self) -> int:
        plan = self.plan
        rp = RecorderParams(**self.sp.params)
        path = os.environ.get("GFLOW_RECORDING") or plan.recording_path()
        assert path is not None
        from .graph import Plan as _P  # noqa: F401  (metadata helpers live on Plan)

        meta = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
                "gflow.config": plan.config_metadata()}
        self.recorder = rec = McapRecorder(path, flush_interval=rp.flush_interval, compression=rp.compression,
                                           chunk_size=rp.chunk_size, metadata=meta).open()
        log.info("[%s] recording to %s", self.name, path)
        self.state = "running"
        try:
            while True:
                try:
                    key, payload, pub_ns, seq, type_name = self.inbox.get(timeout=0.05)
                except queue.Empty:
                    rec.maybe_flush()
                    if self.stop.is_set():
                        break
                    continue
                rec.write(key, payload, seq, publish_ns=pub_ns, type_name=type_name)
            # keep what is still arriving until the network goes quiet (at most 2 s), then close
            quiet_until = time.monotonic() + 0.3
            deadline = time.monotonic() + 2.0
            while time.monotonic() < min(quiet_until, deadline):
                try:
                    key, payload, pub_ns, seq, type_name = self.inbox.get(timeout=0.05)
                except queue.Empty:
                    continue
                rec.write(key, payload, seq, publish_ns=pub_ns, type_name=type_name)
                if "/_status/" not in key:
                    quiet_until = time.monotonic() + 0.3
        finally:
            rec.close()
            self.state = "stopped" if self.state == "stopped" else "done"
        return 0


def run_node(plan_path: str, name: str) -> int:
    threads = os.environ.get("GFLOW_CV_THREADS")
    if threads:  # set by the launcher: one compute thread per stage process by default
        import cv2

        cv2.setNumThreads(int(threads))
    plan = Plan.from_json(Path(plan_path).read_text())
    if name not in plan.stages:
        print(f"gflow node: no stage {name!r} in {plan_path}", file=sys.stderr)
        return 2
    node = Node(plan, name)

    def _signal(signum, frame) -> None:
        node.stop.set()

    signal.signal(signal.SIGINT, _signal)
    signal.signal(signal.SIGTERM, _signal)
    return node.run()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: python -m pipeline.node PLAN.json STAGE", file=sys.stderr)
        return 2
    logging.basicConfig(level=os.environ.get("GFLOW_LOG", "WARNING"), format="%(levelname)s %(message)s",
                        stream=sys.stderr)
    return run_node(argv[0], argv[1])


if __name__ == "__main__":
    sys.exit(main())
