"""A worker's stage process (preprocess, proposal, filter, render...): inputs from zenoh, joined
by sequence number, stepped, outputs published.

* It reports how far it got (on the progress key that only the sources hear) after its work,
  at most every ``REPORT_EVERY_S``: every heartbeat wakes every process of the graph.
* The cycle never deadlocks: an input that does not come is given up when the stream is
  ``lag`` frames further on (twice the flow-control window, plus 4) or once its frame has been
  the next one to step for the plan's ``late_s`` seconds (default 3) while the source is
  ahead; the stage then coasts. (Counted from when its first input came, a G-flow proposal
  stage whose frames arrive a window ahead of its cycle gave inputs up on a loaded machine,
  and the multi-process result then differed from --inline.)
* Restarted, it first takes the inputs it missed from the recording (every message that
  reached the recorder while it was down, read up to the recorder's last flush), then goes on
  live, so its outputs are those of an undisturbed run. Inputs that are in no recording are
  given up (a filter coasts on them, or re-seeds from its own restored state on the first
  frame whose driver inputs are here).
* SIGINT or SIGTERM makes it abandon what is queued, publish end of stream on its outputs
  and exit 0.
"""

from __future__ import annotations

import logging
import queue
import time
from pathlib import Path

from pipeline.runtime.node_plan import NodePlan
from pipeline.runtime.stage_node import StageNode

__all__ = ["WorkerNode", "REPORT_EVERY_S"]

log = logging.getLogger("gflow.node")

REPORT_EVERY_S = 0.02  # a worker's progress heartbeats: at most 50 a second (measured: ~130 us of CPU per receiver each)


class WorkerNode(StageNode):
    """A stage with inputs."""

    def __init__(self, node_plan: NodePlan) -> None:
        super().__init__(node_plan)
        self._reported_steps = 0
        # every worker reports progress quickly when some source applies flow control
        self.flow_stages_waiting = any(s.is_source() and s.params.get("max_ahead", 0) for s in self.plan.stages.values())

    def work(self, resumed_after: int) -> int:
        host = self.host
        assert host is not None
        self.state = "running"
        if resumed_after >= 0:
            self.resend_last()
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
                host.tick(self.node_plan.late_s)
                continue
            host.deliver(key, payload)
            if self.flow_stages_waiting and self.send_status(REPORT_EVERY_S, progress=True):
                self._reported_steps = host.stats.steps
        return 0

    def _catch_up(self, after: int) -> None:
        """Feed the inputs after frame ``after`` that reached the recording while this stage
        was down (live copies of them are then ignored as already replayed)."""
        h = self.host
        path = self.node_plan.recording
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
