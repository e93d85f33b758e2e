"""What every stage process does, whatever its role: join zenoh, shake hands, send heartbeats,
obey the launcher, and never outlive it.

* Start-up handshake: every node publishes a heartbeat (:class:`StageStatus`) on
  ``gflow/<stream>/_status/<stage>`` twice a second and at every change of state, after
  declaring its subscribers. A node publishes data only once it has heard a heartbeat from
  every other node of the graph: the heartbeat came over the direct peer link after that
  node's subscriber declarations, so no early message can miss a subscriber. A restarted node
  waits only for the peers the launcher saw running, for at most 3 s.
* Control: ``start`` (sources wait for it) and ``stop`` (the recorder's cue to close) on
  ``gflow/<stream>/_control``; anything else there is counted and ignored.
* Liveliness: every node holds a zenoh liveliness token ``gflow/<stream>/_alive/<stage>``,
  which vanishes within milliseconds of the process's death. While a peer's token is gone (and
  it has not finished: it is restarting) no input is given up for lateness.
* Nothing outlives the launcher: on Linux every node asks for SIGTERM when its parent dies
  (``prctl(PR_SET_PDEATHSIG)``, :func:`pipeline.runtime.node.die_with_parent`), and a watchdog
  thread also checks the parent pid; an orphaned node stops at once (the recorder closes its
  file first), removes the run's temporary folder (the plan's ``run_dir``) and leaves with
  ``os._exit``: its session is not closed (zenoh-python's callback threads would hold the
  interpreter's teardown) and its stdout/stderr are pipes to the dead launcher.

The roles (:mod:`pipeline.runtime.source_node`, :mod:`pipeline.runtime.worker_node`,
:mod:`pipeline.runtime.recorder_node`) fill in :meth:`NodeBase.declare` (their own
subscribers), :meth:`NodeBase.serve` (their work) and :meth:`NodeBase.report` (their part of
the heartbeat).
"""

from __future__ import annotations

import abc
import logging
import os
import queue
import shutil
import sys
import threading
import time
from pathlib import Path
from typing import Any

import psutil
import zenoh

from gflow_msgs.messages import Control, Header, StageStatus, decode, encode

from pipeline.runtime.inbox import BoundedInbox
from pipeline.runtime.node_plan import NodePlan
from pipeline.runtime.security import Signer
from pipeline.runtime.trace import mark
from pipeline.runtime.transport import Bus, open_session

__all__ = ["NodeBase", "exit_now"]

log = logging.getLogger("gflow.node")

#: seconds a restarted node waits at most for the peers the launcher saw running
RESTART_READY_S = 3.0


def exit_now() -> None:
    """Leave at once, without the interpreter's teardown. stdout/stderr may be pipes to a
    dead launcher, so flushing them may raise."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(0)


class NodeBase(abc.ABC):
    """One stage process on zenoh (see the module doc). ``run()`` declares, then serves."""

    def __init__(self, node_plan: NodePlan) -> None:
        self.node_plan = node_plan
        self.plan = plan = node_plan.graph
        self.name = name = node_plan.stage
        self.sp = plan.stages[name]
        self.stop = threading.Event()
        self._hb_stop = threading.Event()
        self.started = threading.Event()
        self.peers_ready = threading.Event()
        self.declared = threading.Event()  # every subscriber of this node is declared
        self.seen: set[str] = set()
        self.inbox: queue.SimpleQueue | BoundedInbox = self.make_inbox()
        self.state = "starting"
        self.proc = psutil.Process()
        mark(f"node {name} opening session")
        self.session = open_session(node_plan.zenoh)
        mark(f"node {name} session")
        self.bus = Bus(self.session, plan.drop_topics(), signer=Signer.of(node_plan.zenoh.security))
        self._last_status = 0.0
        self.sources = {n for n, s in plan.stages.items() if s.is_source()}
        #: the widest flow-control window of the graph's sources (0: no flow control)
        self.window = max([int(plan.stages[n].params.get("max_ahead", 8)) for n in self.sources] or [0])
        self.recorders = {n for n, s in plan.stages.items() if s.kind == "recorder"}
        self.recorder_alive = threading.Event()  # the recorder's liveliness token is there
        self.alive_peers: set[str] = set()  # stages whose liveliness token is there
        self.ever_alive: set[str] = set()
        self.peer_done: set[str] = set()  # stages that said they finished
        self.peer_state: dict[str, str] = {}  # the last heartbeat state of every other stage
        self.recorder_ended: set[str] = set()  # topics whose end of stream the recorder has recorded
        self.drained = threading.Event()
        self.orphaned = threading.Event()
        self.parent = node_plan.launcher_pid
        self.restarts = node_plan.restarts
        self.bad_control = 0
        self._published = False  # for the start-up trace only
        # who must be heard from before publishing: every stage; a restarted stage only those
        # the launcher saw running when it restarted it (the others may have finished), for at most 3 s
        peers = node_plan.peers
        self.required_peers = (set(plan.stages) if not self.restarts or peers is None
                               else {p for p in peers if p in plan.stages} | {name})
        self.ready_deadline = time.monotonic() + RESTART_READY_S
        for other in node_plan.finished:  # restarted after they finished: they will not say so again
            if other in plan.stages and other != name:
                self.peer_state[other] = "done"
                self.peer_done.add(other)

    # -- what a role fills in ------------------------------------------------------------------
    def make_inbox(self) -> queue.SimpleQueue | BoundedInbox:
        """The queue between zenoh's threads and this node's work."""
        return queue.SimpleQueue()

    def declare(self) -> None:
        """Declare this role's subscribers and get ready (before the first heartbeat)."""

    @abc.abstractmethod
    def serve(self) -> int:
        """Do this role's work; the process's exit status."""

    def report(self) -> dict[str, Any]:
        """This role's fields of the heartbeat (:class:`StageStatus`), with at least ``steps``."""
        return {"steps": 0}

    def heard(self, other: str, st: StageStatus) -> None:
        """Another node's heartbeat (or progress report) arrived: ``st``."""

    def hold(self, on: bool) -> None:
        """A peer is restarting (``on``): no input is given up for lateness meanwhile."""

    def finishing(self) -> bool:
        """Whether this node must finish something (a recording) before an orphan leaves."""
        return False

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
        if st is not None:
            self.heard(other, st)
        if other not in self.seen:
            self.seen.add(other)
            if self.seen >= self.required_peers:
                if not self.peers_ready.is_set():
                    mark(f"node {self.name} heard all")
                self.peers_ready.set()
            self._answer_newcomer()

    def _note_state(self, other: str, st: StageStatus) -> None:
        """Remember each peer's heartbeat state (and the recorder's recorded ends of stream)."""
        self.peer_state[other] = st.state
        if other in self.recorders:
            self.recorder_ended = set(st.ended)
        if self.state == "draining":
            self.drained.set()

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
        self.hold(bool(down))

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
        """Publish on ``topic``, once every peer has been heard from (see the module doc)."""
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

    # -- heartbeats ----------------------------------------------------------------------------
    def status(self) -> StageStatus:
        fields = self.report()
        steps, fps = fields.pop("steps"), fields.pop("fps", 0.0)
        return StageStatus(header=Header(self.plan.stream, steps, time.time_ns()), stage=self.name, pid=os.getpid(),
                           state=self.state, steps=steps, fps=fps, rss_mb=round(self.proc.memory_info().rss / 2**20, 1),
                           queued=self.inbox.qsize(), rejected=self._rejected(), **fields)

    def rejected(self) -> dict[str, int]:
        """This role's rejected input messages, by kind."""
        return {}

    def _rejected(self) -> dict[str, int]:
        out = self.rejected()
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

    # -- the launcher's death ----------------------------------------------------------------
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
        while self.finishing() or time.monotonic() < deadline:
            time.sleep(0.05)
        self.cleanup_if_orphaned()
        exit_now()

    def cleanup_if_orphaned(self) -> None:
        """The launcher died: nobody else will remove the run's temporary folder."""
        if self.parent and os.getppid() != self.parent:
            run_dir = self.node_plan.run_dir
            if run_dir and Path(run_dir).name.startswith("gflow-run-"):
                shutil.rmtree(run_dir, ignore_errors=True)

    # -- run ---------------------------------------------------------------------------------
    def run(self) -> int:
        plan = self.plan
        self.bus.subscribe(f"gflow/{plan.stream}/_status/*", self._on_status)
        self.bus.subscribe(plan.control_topic, self._on_control)
        alive = f"gflow/{plan.stream}/_alive"
        self._token = self.session.liveliness().declare_token(f"{alive}/{self.name}")
        self._alive_sub = self.session.liveliness().declare_subscriber(f"{alive}/*", self._on_alive, history=True)
        self.declare()
        self.declared.set()
        mark(f"node {self.name} declared")
        hb = threading.Thread(target=self._heartbeat, daemon=True)
        hb.start()
        threading.Thread(target=self._watch_parent, daemon=True).start()
        self.state = "ready"
        try:
            return self.serve()
        finally:
            self.state = "done" if self.state != "stopped" else "stopped"
            self._hb_stop.set()
            if self.orphaned.is_set():
                # the launcher (this host's router) is gone: nobody to say goodbye to, and a
                # session closing towards a vanished router can take seconds; run_node exits
                # at once (the recorder has closed its file, checkpoints are written atomically)
                self.cleanup_if_orphaned()
            else:
                hb.join(timeout=1.0)
                try:
                    self.send_status()  # the final heartbeat says "done"; best effort
                except Exception as e:  # the session may already be closing on interrupt
                    log.debug("[%s] final heartbeat not sent: %s", self.name, e)
                time.sleep(0.1)  # let the last samples leave before the session closes
                self.session.close()
                self.cleanup_if_orphaned()
