"""A stage process that runs a stage (a source or a worker): the stage behind its
:class:`~pipeline.runtime.stage_host.StageHost`, checkpoints, and the end of its outputs.

* Resume, not restart: a stage the graph restarts writes a checkpoint after every step (in
  the run folder's ``state/``: its snapshot, the last frame done, its last outputs). Started
  again (the plan's ``restarts`` > 0), it restores the checkpoint and resumes from the next
  frame it has not consumed (the source from the frame after the last one it sent, any other
  stage after catching up from the recording: :mod:`pipeline.runtime.worker_node`), and first
  sends again what its last step published.
* Every stage rejects messages more than the flow-control window ahead of the last frame a
  source announced (so a frame up to 4 past it still passes), and images of another size than
  the source's.
* Nothing lost at the end: after a normal end the stage waits until what it sent has arrived
  (:mod:`pipeline.runtime.drain`), at most the plan's ``drain_s`` seconds.
"""

from __future__ import annotations

import abc
import logging
import time
from pathlib import Path
from typing import Any

import msgspec

from gflow_msgs.messages import StageStatus

from pipeline.runtime.build import make_stage
from pipeline.runtime.checkpoint import Checkpoint, read_checkpoint, write_checkpoint
from pipeline.runtime.drain import FINISHED, consumers_of, recorder_needs
from pipeline.runtime.node_base import NodeBase
from pipeline.runtime.node_plan import NodePlan
from pipeline.runtime.stage_host import StageHost
from pipeline.runtime.trace import mark

__all__ = ["StageNode"]

log = logging.getLogger("gflow.node")


class StageNode(NodeBase):
    """A node that hosts a stage; its role (:meth:`work`) is a source's or a worker's."""

    host: StageHost | None

    def __init__(self, node_plan: NodePlan) -> None:
        super().__init__(node_plan)
        self.host = None
        self.resumed_after = -1  # the last frame a restarted stage had done (-1: a first start)
        self.resend: list[tuple[str, bytes, int, str]] = []
        state_dir = node_plan.state_dir
        self.checkpoint_path = (Path(state_dir) / f"{self.name}.ckpt"
                                if state_dir and self.sp.restart == "on-failure" else None)

    def declare(self) -> None:
        sp = self.sp
        stage = make_stage(self.plan, self.name)
        mark(f"node {self.name} stage built")
        lag = 2 * self.window + 4 if self.window else 0
        self.host = StageHost(stage, sp.inputs, sp.outputs, self.plan.error_topic, self.publish,
                              sp.snapshot_every, self.plan.snapshot_topic(self.name), lag=lag,
                              window=self.window or (1 << 40), on_step=self.checkpoint,
                              cv_threads=self.node_plan.cv_threads)
        for topic in sp.inputs.values():
            self.bus.subscribe(topic, self._on_data, with_type=True)
        self.resumed_after = self._restore()
        self._update_hold()

    @abc.abstractmethod
    def work(self, resumed_after: int) -> int:
        """The role's work, from the frame after ``resumed_after``; the exit status."""

    def serve(self) -> int:
        rc = self.work(self.resumed_after)
        self._drain()
        return rc

    # -- what the peers say ------------------------------------------------------------------
    def heard(self, other: str, st: StageStatus) -> None:
        if other in self.sources and self.host is not None:
            h = self.host
            h.source_seq = max(h.source_seq, st.last_seq)
            h.join.horizon = h.source_seq
            if len(st.frame_shape) >= 2 and h.frame_shape is None:
                h.frame_shape = (int(st.frame_shape[0]), int(st.frame_shape[1]))

    def hold(self, on: bool) -> None:
        if self.host is not None:
            self.host.hold = self.host.join.hold = on

    # -- heartbeat ---------------------------------------------------------------------------
    def report(self) -> dict[str, Any]:
        h = self.host
        if h is None:
            return {"steps": 0}
        s = h.stats
        return {"steps": s.total_steps(), "fps": round(s.fps(), 2), "dropped": dict(h.join.gaps), "errors": s.errors,
                "last_error": s.last_error[-300:], "last_seq": h.join.done_below,
                "busy_ms": round(s.busy_ns / s.steps / 1e6, 3) if s.steps else 0.0, "lost": s.lost,
                "waiting": h.waiting() if not h.closed else ""}

    def rejected(self) -> dict[str, int]:
        return dict(self.host.stats.rejected) if self.host is not None else {}

    # -- checkpoints -------------------------------------------------------------------------
    def checkpoint(self, seq: int) -> None:
        """Write what a restart resumes from (atomically: a kill leaves the previous one)."""
        path = self.checkpoint_path
        if path is None:
            return
        h = self.host
        data = h.stage.snapshot() if h is not None and not self.sp.is_source() else None
        write_checkpoint(path, Checkpoint(seq=seq, data=data, max_out=dict(h.max_out) if h else {},
                                          sent=list(h.last_sent) if h is not None else [],
                                          steps=h.stats.total_steps() if h is not None else 0))

    def _restore(self) -> int:
        """Load the checkpoint of a restarted stage; return the last frame it had done (-1: none)."""
        path = self.checkpoint_path
        if path is None or self.restarts == 0 or not path.is_file() or self.host is None:
            return -1
        h = self.host
        try:
            ck = read_checkpoint(path)
            if ck.data is not None:
                h.stage.restore(ck.data)
        except (msgspec.DecodeError, ValueError, TypeError) as e:
            log.warning("[%s] checkpoint %s unusable (%s); starting afresh", self.name, path, e)
            return -1
        h.max_out.update(ck.max_out)
        h.stats.resumed_steps = ck.steps
        self.resend = list(ck.sent)  # the last step's outputs may not have left: sent again on resuming
        h.join.done_below = ck.seq
        h.join.resumed = True
        log.warning("[%s] restart %d: resumed after frame %d", self.name, self.restarts, ck.seq)
        return ck.seq

    def resend_last(self) -> None:
        """Publish again what the step before a kill published (a consumer that had it ignores the
        byte-identical repeat: :meth:`StageHost.deliver`)."""
        for topic, payload, seq, type_name in self.resend:
            self.publish(topic, payload, seq, type_name)
        self.resend = []

    # -- the end -----------------------------------------------------------------------------
    def _drain(self) -> None:
        """After a normal end, wait until what this stage sent has arrived (see ``pipeline.runtime.drain``)."""
        if self.host is None or self.state == "stopped" or self.stop.is_set():
            return
        from gflow_msgs.foxglove import FOXGLOVE_SCHEMAS

        h = self.host
        consumers = consumers_of(self.plan, self.name)
        eos = [t for p, t in h.topics_out.items() if h.stage.outputs.get(p) not in FOXGLOVE_SCHEMAS]
        rec, need = recorder_needs(self.plan, eos)
        self.state = "draining"
        self.send_status()
        deadline = time.monotonic() + self.node_plan.drain_s
        waiting: list[str] = []
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
            log.warning("[%s] finished, but its last messages were not confirmed within %.0f s (by %s)", self.name,
                        self.node_plan.drain_s, ", ".join(waiting))
