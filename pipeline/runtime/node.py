"""One stage as its own OS process on zenoh: ``python -m pipeline.runtime.node PLAN.json STAGE``.

Start-up handshake: every node publishes a heartbeat (:class:`StageStatus`) on
``gflow/<stream>/_status/<stage>`` twice a second and at every change of state, after
declaring its subscribers. A worker's report of each step it finished (what flow control
needs) goes on ``gflow/<stream>/@progress/<stage>`` instead, which only the sources
subscribe to: every message costs every process that receives it ~150-280 us of CPU, and
no worker needs another's per-step progress. A node
publishes data only once it has heard a heartbeat from every other node of the graph: the
heartbeat came over the direct peer link after that node's subscriber declarations, so
no early message can miss a subscriber. Sources additionally wait for the launcher's
``start`` on ``gflow/<stream>/_control``.

Shutdown: SIGINT or SIGTERM makes a stage abandon what is queued, publish end of stream
on its outputs and exit 0; the recorder closes its MCAP file properly. A Python exception
exits 1 with the traceback on stderr (the launcher shows its last line).

Faults:

* Nothing outlives the launcher: on Linux every node asks for SIGTERM when its parent dies
  (``prctl(PR_SET_PDEATHSIG)``), and a watchdog thread also checks the parent pid; an
  orphaned node stops at once (the recorder closes its file first), removes the run's
  temporary folder (``GFLOW_RUN_DIR``) and leaves with ``os._exit``: its session is not
  closed (zenoh-python's callback threads would hold the interpreter's teardown) and its
  stdout/stderr are pipes to the dead launcher.
* Resume, not restart: a stage the graph restarts writes a checkpoint after every step
  (``GFLOW_STATE_DIR``: its snapshot, the last frame done, its last outputs). Started
  again (``GFLOW_RESTARTS`` > 0), it restores the checkpoint and resumes from the next frame
  it has not consumed: the source from the frame after the last one it sent; any other
  stage first takes the inputs it missed from the recording (every message that reached
  the recorder while it was down, read up to the recorder's last flush), then goes on live,
  so its outputs are those of an undisturbed run. Inputs that are in no recording are
  given up (a filter coasts on them, or re-seeds from its own restored state on the first
  frame whose driver inputs are here).
* The cycle never deadlocks: an input that does not come is given up when the stream is
  ``lag`` frames further on (twice the flow-control window, plus 4) or once its frame has
  been the next one to step for ``GFLOW_LATE_S`` seconds (default 3) while the source is
  ahead; the stage then coasts. (Counted from when its first input came, a G-flow proposal
  stage whose frames arrive a window ahead of its cycle gave inputs up on a loaded machine,
  and the multi-process result then differed from --inline.)
* The source announces its position (its heartbeat's ``last_seq`` and ``frame_shape``)
  before sending a frame: the first frame, then every ``window // 2`` frames (at most 4;
  every announcement wakes every process of the graph, ~1-2 ms of CPU a frame over them
  all on caviar1); every stage rejects messages more than the flow-control window ahead of
  the last announced frame (so a frame up to 4 past it still passes), and images of
  another size.
* A live source (``kind: live``) opens its stream or camera while the node starts, before its
  first heartbeat, so a source that cannot be opened stops the run during start-up with one
  line naming it and what FFmpeg said (exit status 2, not restarted), and an ``--init`` box
  outside its frames is refused the same way. It then runs with ``live_ahead`` as its window
  and takes the newest frame each time the window has room (``_run_live``): frames decoded
  meanwhile are skipped and counted (heartbeat ``captured`` / ``skipped`` / ``reconnects``).
  A stage that joins frame t + 1 with its input of frame t (``input_offsets`` -1 on the frames:
  a proposal that knows when the next frame was taken) has consumed frame t + 1 when it
  reports t, so flow control counts it one frame further on.
* Every node holds a zenoh liveliness token ``gflow/<stream>/_alive/<stage>``, which
  vanishes within milliseconds of the process's death. The source waits while the
  recorder's token is gone, so a recorder restart loses no more than the frames in flight.
"""

from __future__ import annotations

from pipeline.runtime.trace import mark

mark("node begin")  # before the imports: bench/bench_startup.py tells interpreter start from imports

import ctypes  # noqa: E402
import dataclasses
import logging
import os
import queue
import shutil
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import psutil
import zenoh

from stages.messages import Control, Header, StageStatus, decode, encode
from stages.source import SourceStage

from pipeline.runtime.build import make_stage
from pipeline.runtime.drain import FINISHED, consumers_of, recorder_needs
from pipeline.runtime.graph import Plan, RecorderParams, recorded_topic_filter
from pipeline.runtime.stage_host import StageHost
from pipeline.runtime.inbox import BoundedInbox
from pipeline.runtime.memory import keep_freed_memory
from pipeline.runtime.transport import Bus, ZenohSettings, open_session
from pipeline.runtime.security import Signer
from pipeline.runtime.signals import StopSignals

if TYPE_CHECKING:
    from pipeline.io.recorder import McapRecorder

__all__ = ["main", "run_node"]

log = logging.getLogger("gflow.node")

FLOW_STALL_S = 1.0
RECORDER_INBOX_BYTES = 32 * 2**20  # what the recorder holds unwritten before the publishers wait (pipeline/runtime/inbox.py)
REPORT_EVERY_S = 0.02  # a worker's progress heartbeats: at most 50 a second (measured: ~130 us of CPU per receiver each)
PR_SET_PDEATHSIG = 1
EXIT_DISK_FULL = 28  # the recorder's exit status when its disk is full (ENOSPC): not worth a restart
EXIT_BAD_SOURCE = 2  # a live source that cannot be opened, or an --init box outside its frames


class Checkpoint(msgspec.Struct, frozen=True):
    """What a restarted stage resumes from: its snapshot after frame ``seq`` (None for a
    stateless stage), the last seq it sent on each output port, and the messages that step
    published ((topic, payload, seq, type name)): a kill can come before zenoh has put them
    on the wire, so a restarted stage sends them again (downstream counts a duplicate)."""

    seq: int
    data: bytes | None
    max_out: dict[str, int]
    sent: list[tuple[str, bytes, int, str]] = []


def die_with_parent() -> None:
    """Ask Linux to send SIGTERM when the parent (the launcher) dies. A no-op elsewhere."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError) as e:  # the watchdog thread still notices
        log.debug("prctl(PR_SET_PDEATHSIG) unavailable: %s", e)


class Node:
    def __init__(self, plan: Plan, name: str) -> None:
        self.plan = plan
        self.name = name
        self.sp = plan.stages[name]
        self.stop = threading.Event()
        self._hb_stop = threading.Event()
        self.started = threading.Event()
        self.peers_ready = threading.Event()
        self.declared = threading.Event()  # every subscriber of this node is declared
        self.seen: set[str] = set()
        # the recorder is outside flow control: its inbox is bounded, and a full one holds the publishers back
        self.inbox: queue.SimpleQueue | BoundedInbox = (BoundedInbox(RECORDER_INBOX_BYTES) if self.sp.kind == "recorder"
                                                        else queue.SimpleQueue())
        self.state = "starting"
        self.steps = 0
        self.proc = psutil.Process()
        # the handshake below waits for every peer's heartbeat: opening need not wait for them too
        settings = dataclasses.replace(ZenohSettings.from_json(plan.zenoh), connect_scouted=False)
        mark(f"node {name} opening session")
        self.session = open_session(settings)
        mark(f"node {name} session")
        self.bus = Bus(self.session, plan.drop_topics(), signer=Signer.of(settings.security))
        self._status_pub = self.bus.publisher(plan.status_topic(name))
        self.host: StageHost | None = None
        self.recorder: McapRecorder | None = None
        # flow control (sources only): how far each worker stage has got
        self.live = self.sp.is_source() and self.sp.params.get("kind") == "live"
        self.flow_window = int(self.sp.params.get("max_ahead", 0)) if self.sp.is_source() else 0
        if self.live:
            self.flow_window = int(self.sp.params.get("live_ahead", 1))
        self.flow_stages = {n for n, s in plan.stages.items() if s.kind != "recorder" and not s.is_source()}
        self.lead = frames_lead(plan, self.name, self.flow_stages) if self.flow_window else {}
        self.capture = None  # a live source's LiveCapture
        self.progress_of: dict[str, int] = {}
        self.first_pid: dict[str, int] = {}
        self.progress_changed = threading.Event()
        self._last_status = 0.0
        self._reported_steps = 0
        # every worker reports progress quickly when some source applies flow control
        self.flow_stages_waiting = any(s.is_source() and s.params.get("max_ahead", 0) for s in plan.stages.values())
        self.sources = {n for n, s in plan.stages.items() if s.is_source()}
        self.window = max([int(plan.stages[n].params.get("max_ahead", 8)) for n in self.sources] or [0])
        self.recorders = {n for n, s in plan.stages.items() if s.kind == "recorder"}
        self.recorder_alive = threading.Event()  # the recorder's liveliness token is there
        self.alive_peers: set[str] = set()  # stages whose liveliness token is there
        self.ever_alive: set[str] = set()
        self.peer_done: set[str] = set()  # stages that said they finished
        self.peer_state: dict[str, str] = {}  # the last heartbeat state of every other stage
        self.recorder_ended: set[str] = set()  # topics whose end of stream the recorder has recorded
        self.ended: set[str] = set()  # the recorder: the same, for its own heartbeat
        self.drained = threading.Event()
        self.announced = -1  # sources: the last frame announced
        self.frame_shape: tuple[int, ...] = ()
        self.late_s = float(os.environ.get("GFLOW_LATE_S", "3.0"))
        self.orphaned = threading.Event()
        self.parent = int(os.environ.get("GFLOW_LAUNCHER_PID", "0") or 0)
        self.restarts = int(os.environ.get("GFLOW_RESTARTS", "0") or 0)
        self.bad_control = 0
        self._published = False  # for the start-up trace only
        # who must be heard from before publishing: every stage; a restarted stage only those
        # the launcher saw running when it restarted it (the others may have finished), for at most 3 s
        peers = os.environ.get("GFLOW_PEERS")
        self.required_peers = (set(plan.stages) if not self.restarts or peers is None
                               else {p for p in peers.split(",") if p in plan.stages} | {name})
        self.ready_deadline = time.monotonic() + 3.0
        state_dir = os.environ.get("GFLOW_STATE_DIR", "")
        self.resend: list[tuple[str, bytes, int, str]] = []
        self.checkpoint_path = (Path(state_dir) / f"{name}.ckpt"
                                if state_dir and self.sp.restart == "on-failure" else None)

    # -- handshake ---------------------------------------------------------------------------
    def _on_status(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        other = key.rsplit("/", 1)[-1]
        st = None  # decoded once: every use below reads the same StageStatus
        if other != self.name:
            try:
                st = decode(payload)
            except ValueError:
                st = None
            if not isinstance(st, StageStatus):
                st = None
        if st is not None:
            self._note_state(other, st)
        if other not in self.peer_done and st is not None and st.state == "done":
            self.peer_done.add(other)  # finished: its token going away is no fault
            self._update_hold()
        if other in self.sources and self.host is not None and st is not None:
            h = self.host
            h.source_seq = max(h.source_seq, st.last_seq)
            h.join.horizon = h.source_seq
            if len(st.frame_shape) >= 2 and h.frame_shape is None:
                h.frame_shape = (int(st.frame_shape[0]), int(st.frame_shape[1]))
        if self.flow_window and other in self.flow_stages and st is not None:
            first_pid = self.first_pid.setdefault(other, st.pid)
            if st.state in FINISHED or (st.pid != first_pid and st.last_seq < 0):
                # finished, or restarted and not yet caught up: do not hold the source back
                self.progress_of[other] = 1 << 60
            else:
                self.progress_of[other] = st.last_seq + self.lead.get(other, 0)
            self.progress_changed.set()
        if other not in self.seen:
            self.seen.add(other)
            if self.seen >= self.required_peers:
                if not self.peers_ready.is_set():
                    mark(f"node {self.name} heard all")
                self.peers_ready.set()
            self._answer_newcomer()

    def _answer_newcomer(self) -> None:
        """A peer was heard for the first time: send a heartbeat now rather than at the next
        tick (up to 0.5 s), so that it hears from everyone as soon as everyone is there. Only
        once this node's own subscribers are declared (the heartbeat promises they are)."""
        if self.declared.is_set():
            try:
                self.send_status()
            except Exception as e:  # the session is closing
                log.debug("[%s] heartbeat to a newcomer not sent: %s", self.name, e)

    def _on_alive(self, sample) -> None:
        other = str(sample.key_expr).rsplit("/", 1)[-1]
        gone = sample.kind == zenoh.SampleKind.DELETE
        if other in self.recorders:
            if gone:
                self.recorder_alive.clear()
            else:
                self.recorder_alive.set()
        if gone:
            self.alive_peers.discard(other)
        else:
            self.alive_peers.add(other)
            self.ever_alive.add(other)
        self._update_hold()

    def _update_hold(self) -> None:
        """While a peer is down (its liveliness token gone, not finished: it is restarting), no
        input is given up for lateness: what it would have sent comes when it is back."""
        down = {n for n in self.ever_alive - self.alive_peers if n != self.name and n not in self.peer_done}
        if self.host is not None:
            self.host.hold = self.host.join.hold = bool(down)

    def _on_control(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        try:
            msg = decode(payload)
        except ValueError as e:
            self.bad_control += 1  # counted in the heartbeat's rejected["bad_control"]
            log.warning("[%s] garbage on the control topic ignored: %s", self.name, str(e)[:100])
            return
        if isinstance(msg, Control):
            if msg.command == "start":
                if not self.started.is_set():
                    mark(f"node {self.name} got start")
                self.started.set()
            elif msg.command == "stop":
                self.stop.set()
            else:
                self.bad_control += 1
                log.warning("[%s] unknown control command %r ignored", self.name, msg.command[:40])
        else:
            self.bad_control += 1
            log.warning("[%s] a %s on the control topic ignored", self.name, type(msg).__name__)

    def _on_data(self, key: str, payload: bytes, pub_ns: int, seq: int, type_name: str = "") -> None:
        self.inbox.put((key, payload, pub_ns, seq, type_name))

    def publish(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        if not self.peers_ready.is_set():
            warn_at = time.monotonic() + 5.0
            while not self.peers_ready.wait(0.2):
                if self.stop.is_set():  # stopped before everyone was there (a source that could not open)
                    return
                if self.restarts and time.monotonic() > self.ready_deadline:
                    self.peers_ready.set()  # restarted: a peer may have finished meanwhile
                    break
                if not self.restarts and time.monotonic() > warn_at:
                    warn_at = time.monotonic() + 5.0
                    missing = sorted(self.required_peers - self.seen)
                    log.warning("[%s] still waiting to hear from %s before publishing", self.name, ", ".join(missing))
        if not self._published:
            self._published = True
            mark(f"node {self.name} first publish {topic.rsplit('/', 1)[-1]}")
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
        if self.sp.is_source():
            last_seq = self.announced
        cap = self.capture
        return StageStatus(header=Header(self.plan.stream, steps, time.time_ns()), stage=self.name, pid=os.getpid(),
                           state=self.state, steps=steps, fps=round(fps, 2), dropped=dropped, errors=errors,
                           last_error=last[-300:], rss_mb=round(self.proc.memory_info().rss / 2**20, 1),
                           last_seq=last_seq, queued=self.inbox.qsize(),
                           busy_ms=round(h.stats.busy_ns / h.stats.steps / 1e6, 3) if h and h.stats.steps else 0.0,
                           rejected=self._rejected(), lost=h.stats.lost if h else 0,
                           waiting=h.waiting() if h and not h.closed and not self.sp.is_source() else "",
                           frame_shape=self.frame_shape, ended=tuple(sorted(self.ended)),
                           captured=cap.captured if cap else 0, skipped=cap.skipped if cap else 0,
                           reconnects=cap.reconnects if cap else 0)

    def _rejected(self) -> dict[str, int]:
        out = dict(self.host.stats.rejected) if self.host is not None else {}
        if self.bad_control:
            out["bad_control"] = self.bad_control
        if self.bus.foreign:  # samples not signed with the run key: from outside the run
            out["unsigned"] = sum(self.bus.foreign.values())
        return out

    def send_status(self, min_interval: float = 0.0, progress: bool = False) -> bool:
        """Publish this node's heartbeat (unless one went out less than ``min_interval`` s ago);
        with ``progress``, on the progress key that only sources and lockstep tools hear."""
        now = time.monotonic()
        if now - self._last_status >= min_interval:
            self._last_status = now
            st = self.status()
            topic = self.plan.progress_topic(self.name) if progress else self.plan.status_topic(self.name)
            self.bus.publish(topic, encode(st), st.header.seq, "StageStatus")
            return True
        return False

    def _heartbeat(self) -> None:
        while not self._hb_stop.is_set():
            try:
                self.send_status()
            except Exception:  # session closing
                return
            self._hb_stop.wait(0.5)

    def _watch_parent(self) -> None:
        """Stop when the launcher is gone (backs up the parent-death signal)."""
        while not self._hb_stop.is_set():
            if self.parent and os.getppid() != self.parent:
                self.orphaned.set()
                self.stop.set()
                self._force_exit_when_orphaned()
                return
            self._hb_stop.wait(0.2)

    def _force_exit_when_orphaned(self, grace_s: float = 1.0) -> None:
        """The launcher is gone and the main thread was told to stop; if it is stuck (a signal
        handler cannot run while it waits inside zenoh, e.g. in a blocking put towards the
        vanished router), leave after ``grace_s`` anyway -- except while a recording is open:
        the recorder goes only once its file is closed."""
        deadline = time.monotonic() + grace_s
        while True:
            rec = self.recorder
            recording = rec is not None and rec.is_open
            if not recording and time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        self._cleanup_if_orphaned()
        _exit_now()

    # -- checkpoints -----------------------------------------------------------------------
    def _checkpoint(self, seq: int) -> None:
        """Write what a restart resumes from (atomically: a kill leaves the previous one)."""
        path = self.checkpoint_path
        if path is None:
            return
        h = self.host
        data = h.stage.snapshot() if h is not None and not self.sp.is_source() else None
        ck = Checkpoint(seq=seq, data=data, max_out=dict(h.max_out) if h else {},
                        sent=list(h.last_sent) if h is not None else [])
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(msgspec.msgpack.encode(ck))
        os.replace(tmp, path)

    def _restore(self) -> int:
        """Load the checkpoint of a restarted stage; return the last frame it had done (-1: none)."""
        path = self.checkpoint_path
        if path is None or self.restarts == 0 or not path.is_file() or self.host is None:
            return -1
        h = self.host
        try:
            ck = msgspec.msgpack.decode(path.read_bytes(), type=Checkpoint)
            if ck.data is not None:
                h.stage.restore(ck.data)
        except (msgspec.DecodeError, ValueError, TypeError) as e:
            log.warning("[%s] checkpoint %s unusable (%s); starting afresh", self.name, path, e)
            return -1
        h.max_out.update(ck.max_out)
        self.resend = list(ck.sent)  # the last step's outputs may not have left: sent again on resuming
        h.join.done_below = ck.seq
        h.join.resumed = True
        log.warning("[%s] restart %d: resumed after frame %d", self.name, self.restarts, ck.seq)
        return ck.seq

    def _catch_up(self, after: int) -> None:
        """Feed the inputs after frame ``after`` that reached the recording while this stage
        was down (live copies of them are then ignored as already replayed)."""
        h = self.host
        path = os.environ.get("GFLOW_RECORDING", "")
        if h is None or not path or not Path(path).is_file():
            return
        rec = self.plan.recorder()
        flush = float(rec.params.get("flush_interval", 0.5)) if rec is not None else 0.5
        time.sleep(flush + 0.3)  # what came before our subscribers reaches the file at the next flush
        from pipeline.io.mcap_io import iter_records

        topics = sorted(h.topics_in.values())
        n = 0
        for r in iter_records(path, topics=topics):
            port = h.port_of[r.topic]
            if r.seq + h.stage.input_offsets.get(port, 0) <= after and r.type != "EndOfStream":
                continue
            h.deliver(r.topic, r.data, pump=False)  # all of it first: the recorder's order is not causal
            h.replayed_upto[port] = max(h.replayed_upto.get(port, -1), h.join.high.get(port, -1))
            n += 1
        h.pump()
        log.warning("[%s] caught up on %d input message(s) from the recording", self.name, n)

    # -- run ---------------------------------------------------------------------------------
    def run(self) -> int:
        plan, sp = self.plan, self.sp
        self.bus.subscribe(f"gflow/{plan.stream}/_status/*", self._on_status)
        if self.flow_window:  # flow control: how far each worker has got, step by step
            self.bus.subscribe(plan.progress_topic("*"), self._on_status)
        self.bus.subscribe(plan.control_topic, self._on_control)
        alive = f"gflow/{plan.stream}/_alive"
        self._token = self.session.liveliness().declare_token(f"{alive}/{self.name}")
        self._alive_sub = self.session.liveliness().declare_subscriber(f"{alive}/*", self._on_alive, history=True)
        if sp.kind == "recorder":
            keep = recorded_topic_filter(sp.params, plan.stream)  # --record-topics
            self.bus.subscribe(f"gflow/{plan.stream}/**", lambda k, *a: keep(k) and self._on_data(k, *a), with_type=True)
        else:
            stage = make_stage(plan, self.name)
            mark(f"node {self.name} stage built")
            lag = 2 * self.window + 4 if self.window else 0
            self.host = StageHost(stage, sp.inputs, sp.outputs, plan.error_topic, self.publish,
                                  sp.snapshot_every, plan.snapshot_topic(self.name), lag=lag,
                                  window=self.window or (1 << 40), on_step=self._checkpoint)
            for topic in sp.inputs.values():
                self.bus.subscribe(topic, self._on_data, with_type=True)
            resumed_after = self._restore()
            self._update_hold()
            if self.live:
                bad = self._open_live()
                if bad:  # nothing was sent: leave at once (closing the session took seconds)
                    print(bad, file=sys.stderr, flush=True)
                    os._exit(EXIT_BAD_SOURCE)
        self.declared.set()
        mark(f"node {self.name} declared")
        hb = threading.Thread(target=self._heartbeat, daemon=True)
        hb.start()
        threading.Thread(target=self._watch_parent, daemon=True).start()
        self.state = "ready"
        try:
            if sp.kind == "recorder":
                return self._run_recorder()
            if self.live:
                rc = self._run_live(resumed_after)
            elif isinstance(self.host.stage, SourceStage):  # type: ignore[union-attr]
                rc = self._run_source(resumed_after)
            else:
                rc = self._run_stage(resumed_after)
            self._drain()
            return rc
        finally:
            self.state = "done" if self.state != "stopped" else "stopped"
            self._hb_stop.set()
            if self.orphaned.is_set():
                # the launcher (this host's router) is gone: nobody to say goodbye to, and a
                # session closing towards a vanished router can take seconds; run_node exits
                # at once (the recorder has closed its file, checkpoints are written atomically)
                self._cleanup_if_orphaned()
            else:
                hb.join(timeout=1.0)
                try:
                    self.send_status()  # the final heartbeat says "done"; best effort
                except Exception as e:  # the session may already be closing on interrupt
                    log.debug("[%s] final heartbeat not sent: %s", self.name, e)
                time.sleep(0.1)  # let the last samples leave before the session closes
                self.session.close()
                self._cleanup_if_orphaned()

    def _note_state(self, other: str, st: StageStatus) -> None:
        """Remember each peer's heartbeat state (and the recorder's recorded ends of stream)."""
        self.peer_state[other] = st.state
        if other in self.recorders:
            self.recorder_ended = set(st.ended)
        if self.state == "draining":
            self.drained.set()

    def _drain(self) -> None:
        """After a normal end, wait until what this stage sent has arrived (see ``pipeline.runtime.drain``)."""
        if self.host is None or self.state == "stopped" or self.stop.is_set():
            return
        from stages.messages_foxglove import FOXGLOVE_SCHEMAS

        h = self.host
        consumers = consumers_of(self.plan, self.name)
        eos = [t for p, t in h.topics_out.items() if h.stage.outputs.get(p) not in FOXGLOVE_SCHEMAS]
        rec, need = recorder_needs(self.plan, eos)
        self.state = "draining"
        self.send_status()
        deadline = time.monotonic() + float(os.environ.get("GFLOW_DRAIN_S", "30"))
        while not self.stop.is_set() and time.monotonic() < deadline:
            # a peer that never held a token here (another host, not yet heard) counts as there
            waiting = [c for c in consumers if self.peer_state.get(c) not in FINISHED
                       and not (c in self.ever_alive and c not in self.alive_peers)]
            if rec is not None and need - self.recorder_ended and not (rec in self.ever_alive
                                                                       and rec not in self.alive_peers):
                waiting.append(rec)
            if not waiting:
                return
            self.drained.clear()
            self.drained.wait(0.05)
        if not self.stop.is_set():
            log.warning("[%s] finished, but its last messages were not confirmed within GFLOW_DRAIN_S", self.name)

    def _cleanup_if_orphaned(self) -> None:
        """The launcher died: nobody else will remove the run's temporary folder."""
        if self.parent and os.getppid() != self.parent:
            run_dir = os.environ.get("GFLOW_RUN_DIR", "")
            if run_dir and Path(run_dir).name.startswith("gflow-run-"):
                shutil.rmtree(run_dir, ignore_errors=True)

    def _run_source(self, resumed_after: int = -1) -> int:
        host = self.host
        assert host is not None
        stage: SourceStage = host.stage  # type: ignore[assignment]
        if resumed_after >= 0:  # restarted: go on from the frame after the last one sent
            p0 = stage.params
            if p0.stop is not None and resumed_after + 1 >= p0.stop:  # type: ignore[attr-defined]
                host.close("end")
                return 0
            stage.params = msgspec.structs.replace(p0, start=max(p0.start, resumed_after + 1))  # type: ignore[arg-type]
            self.announced = resumed_after
        while not (self.started.is_set() and self.peers_ready.is_set()):
            if self.stop.wait(0.01):
                self.state = "stopped"
                return 0
        self.state = "running"
        self._resend_last()
        p = stage.params
        t0 = time.monotonic()
        first: int | None = None
        next_announce = -1
        from pipeline.io.frame_readers import open_reader  # the source's own import (cv2, the readers)

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
            next_announce = self._send(raw, next_announce)
        host.close("end")
        return 0

    def _send(self, raw, next_announce: int) -> int:
        """Emit one decoded frame: announce it (and its size) before sending it, every few
        frames; publish; checkpoint. Returns the frame to announce next."""
        host = self.host
        assert host is not None
        stage: SourceStage = host.stage  # type: ignore[assignment]
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
            self._checkpoint(raw.index)
            host.stats.steps += 1
        now = time.perf_counter_ns()
        host.stats.first_step_ns = host.stats.first_step_ns or now
        host.stats.last_step_ns = now
        return next_announce

    def _open_live(self) -> str:
        """Open the live source (before the first heartbeat); '' or the one-line reason it cannot run."""
        from pipeline.io.frame_readers import open_live  # the source's own import (cv2, FFmpeg)
        from pipeline.io.live_capture import LiveSourceError
        from pipeline.runtime.preflight import PreflightError, check_box_in_image

        p = self.host.stage.params  # type: ignore[union-attr]
        try:
            self.capture = open_live(p)  # type: ignore[arg-type]
        except LiveSourceError as e:
            return str(e)
        h, w = self.capture.shape[:2]
        for sp in self.plan.stages.values():
            box = sp.params.get("init") if isinstance(sp.params, dict) else None
            if box is not None and len(box) == 4:
                try:
                    check_box_in_image(box, w, h)
                except PreflightError as e:
                    self.capture.close()
                    return f"{p.path}: {e}"  # type: ignore[attr-defined]
        return ""

    def _run_live(self, resumed_after: int = -1) -> int:
        """A live source: each time the window has room, send the newest frame decoded (the
        others are skipped and counted); end when the stream ends or is not back in time.
        Restarted, it goes on numbering the frames it sends after the last one it sent (the
        camera's frame numbers start again at 0: the stream was opened anew)."""
        from pipeline.io.frame_readers import read_live

        host, cap = self.host, self.capture
        assert host is not None and cap is not None
        stage: SourceStage = host.stage  # type: ignore[assignment]
        threading.Thread(target=lambda: (self.stop.wait(), cap.interrupt()), daemon=True).start()
        while not (self.started.is_set() and self.peers_ready.is_set()):
            if self.stop.wait(0.01):
                cap.close()
                self.state = "stopped"
                return 0
        self.state = "running"
        seq = resumed_after + 1
        frames = read_live(cap, stage.params, first_seq=seq)  # type: ignore[arg-type]
        next_announce = -1
        while True:
            self._flow_wait(seq)  # first room for a frame, then the newest frame there is
            raw = next(frames, None)
            if raw is None or self.stop.is_set():
                break
            next_announce = self._send(raw, next_announce)
            seq = raw.index + 1
        frames.close()
        if self.stop.is_set():
            host.close("interrupted")
            self.state = "stopped"
            return 0
        host.close("end")
        return 0

    def _flow_wait(self, index: int) -> None:
        """Stay at most ``max_ahead`` frames in front of the slowest stage. A stage that makes
        no progress for FLOW_STALL_S (it lost frames while restarting, say, and waits for a
        later one to tell it so) does not hold the source back forever."""
        stalled_since = time.monotonic()
        last = None
        warned = False
        while self.recorders and not self.stop.is_set() and not self.recorder_alive.wait(0.05):
            if not warned:  # the recorder is gone (restarting): nothing would be recorded
                log.warning("[%s] the recorder is not there: pausing before frame %d", self.name, index)
                warned = True
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

    def _resend_last(self) -> None:
        """Publish again what the step before a kill published (duplicates are counted downstream)."""
        for topic, payload, seq, type_name in self.resend:
            self.publish(topic, payload, seq, type_name)
        self.resend = []

    def _run_stage(self, resumed_after: int = -1) -> int:
        host = self.host
        assert host is not None
        self.state = "running"
        if resumed_after >= 0:
            self._resend_last()
            self._catch_up(resumed_after)  # what it missed, before what is queued live
        while not host.closed:
            if self.stop.is_set():
                host.close("interrupted")
                self.state = "stopped"
                return 0
            # idle after work: say how far we got (replay --lockstep waits for it), but at most
            # every REPORT_EVERY_S: every heartbeat wakes every process of the graph
            unreported = host.stats.steps != self._reported_steps
            wait = max(0.0, self._last_status + REPORT_EVERY_S - time.monotonic()) if unreported else 0.1
            try:
                key, payload, _, _, _ = self.inbox.get(timeout=wait) if wait > 0 else self.inbox.get_nowait()
            except queue.Empty:
                if unreported:
                    self._reported_steps = host.stats.steps
                    self.send_status(progress=True)
                host.tick(self.late_s)
                continue
            host.deliver(key, payload)
            if self.flow_stages_waiting and self.send_status(REPORT_EVERY_S, progress=True):
                self._reported_steps = host.stats.steps
        return 0

    def _run_recorder(self) -> int:
        from pipeline.io.recorder import DiskFull, McapRecorder  # the recorder's own import (mcap)

        plan = self.plan
        rp = RecorderParams(**self.sp.params)
        path = os.environ.get("GFLOW_RECORDING") or plan.recording_path()
        assert path is not None
        from pipeline.runtime.graph import Plan as _P  # noqa: F401  (metadata helpers live on Plan)

        meta = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
                "gflow.config": plan.config_metadata()}
        try:
            self.recorder = rec = McapRecorder(path, flush_interval=rp.flush_interval, compression=rp.compression,
                                               chunk_size=rp.chunk_size, metadata=meta).open()
        except DiskFull as e:
            print(f"recorder: {e.strerror}", file=sys.stderr)
            return EXIT_DISK_FULL
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
                if type_name == "EndOfStream":
                    self.ended.add(key)
                    self.send_status()  # the stage that sent it waits for this before it exits
            # keep what is still arriving until the network goes quiet (at most 2 s, or 0.5 s
            # when the launcher is gone and every process must be gone within 1 s), then close
            quick = self.orphaned.is_set()
            quiet_until = time.monotonic() + (0.15 if quick else 0.3)
            deadline = time.monotonic() + (0.5 if quick else 2.0)
            while time.monotonic() < min(quiet_until, deadline):
                try:
                    key, payload, pub_ns, seq, type_name = self.inbox.get(timeout=0.05)
                except queue.Empty:
                    continue
                rec.write(key, payload, seq, publish_ns=pub_ns, type_name=type_name)
                if "/_status/" not in key:
                    quiet_until = time.monotonic() + 0.3
            rec.close()
        except DiskFull as e:
            print(f"recorder: {e.strerror}", file=sys.stderr)
            self.state = "stopped"
            return EXIT_DISK_FULL
        finally:
            try:
                rec.close()  # after an exception; a no-op once closed
            except DiskFull:
                pass
            self.state = "stopped" if self.state == "stopped" else "done"
        return 0


def frames_lead(plan: Plan, source: str, stages: set[str]) -> dict[str, int]:
    """{stage: frames it is ahead of the seq it reports}: a stage that joins frame t + k with its
    inputs of frame t (``input_offsets`` -k on a port fed by ``source``'s frames) has taken
    frame t + k when it reports t. Flow control counts it k frames further on, or the source
    would wait for a report that waits for its next frame."""
    from stages.registry import get_stage_class

    frames = {plan.stages[source].outputs.get("frames")}
    out = {}
    for n in stages:
        sp = plan.stages[n]
        offsets = get_stage_class(sp.kind).input_offsets
        k = max([-offsets.get(port, 0) for port, topic in sp.inputs.items() if topic in frames] or [0])
        if k > 0:
            out[n] = k
    return out


def run_node(plan_path: str, name: str) -> int:
    keep_freed_memory()  # frame-sized buffers reused, not faulted in afresh every frame
    # Signals go to a thread of their own (pipeline/runtime/signals.py), never to a Python
    # handler that sets an Event: started before any other thread, so zenoh's inherit the mask.
    holder: list[Node] = []

    def _on_signal(signum: int) -> None:
        if not holder:  # before the node exists there is nothing to stop cleanly
            _exit_now()
        node = holder[0]
        if node.parent and os.getppid() != node.parent:
            node.orphaned.set()
        node.stop.set()

    StopSignals(_on_signal).start()
    die_with_parent()
    mark(f"node {name} imported")
    plan = Plan.from_json(Path(plan_path).read_text())
    if name not in plan.stages:
        print(f"gflow node: no stage {name!r} in {plan_path}", file=sys.stderr)
        return 2
    node = Node(plan, name)
    holder.append(node)
    if node.parent and os.getppid() != node.parent:  # the launcher died before we got here
        node.orphaned.set()
        node.stop.set()
    try:
        rc = node.run()
    finally:
        if node.orphaned.is_set():
            _exit_now()  # the session was left open: zenoh's callback threads would hold the teardown
    return rc


def _exit_now() -> None:
    """Leave at once, without the interpreter's teardown. stdout/stderr may be pipes to a
    dead launcher, so flushing them may raise."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(0)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: python -m pipeline.runtime.node PLAN.json STAGE", file=sys.stderr)
        return 2
    logging.basicConfig(level=os.environ.get("GFLOW_LOG", "WARNING"), format="%(levelname)s %(message)s",
                        stream=sys.stderr)
    return run_node(argv[0], argv[1])


if __name__ == "__main__":
    sys.exit(main())
