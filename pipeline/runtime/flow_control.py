"""Flow control: a source stays at most ``max_ahead`` frames (a live source ``live_ahead``) in
front of the slowest stage, which bounds memory and latency.

Each worker reports the last frame it finished on ``gflow/<stream>/@progress/<stage>`` (and
in its heartbeat); the source waits before a frame while the slowest stage is more than the
window behind it. A stage that joins frame t + k with its input of frame t (``input_offsets``
-k on a port fed by the source's frames: a proposal that knows when the next frame was taken)
has consumed frame t + k when it reports t, so flow control counts it k frames further on. A
stage that has finished, or a restarted one that has not yet caught up, does not hold the
source back, nor does one that makes no progress for ``FLOW_STALL_S`` (it lost frames while
restarting, say, and waits for a later one to tell it so).
"""

from __future__ import annotations

import logging
import threading
import time

from gflow_msgs.messages import StageStatus

from pipeline.runtime.drain import FINISHED
from pipeline.runtime.graph import Plan

__all__ = ["FlowControl", "frames_lead", "FLOW_STALL_S"]

log = logging.getLogger("gflow.node")

#: seconds without progress of the slowest stage after which the source sends its next frame anyway
FLOW_STALL_S = 1.0
#: how far ahead a stage that does not hold the source back counts
_UNBOUNDED = 1 << 60


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


class FlowControl:
    """Source ``name`` of ``plan`` with a window of ``window`` frames (0: no flow control)."""

    def __init__(self, plan: Plan, name: str, window: int) -> None:
        self.name = name
        self.window = window
        self.stages = {n for n, s in plan.stages.items() if s.kind != "recorder" and not s.is_source()}
        self.lead = frames_lead(plan, name, self.stages) if window else {}
        self.progress_of: dict[str, int] = {}
        self.first_pid: dict[str, int] = {}
        self.changed = threading.Event()

    def heard(self, other: str, st: StageStatus) -> None:
        """A heartbeat or progress report of stage ``other``."""
        if not self.window or other not in self.stages:
            return
        first_pid = self.first_pid.setdefault(other, st.pid)
        if st.state in FINISHED or (st.pid != first_pid and st.last_seq < 0):
            # finished, or restarted and not yet caught up: do not hold the source back
            self.progress_of[other] = _UNBOUNDED
        else:
            self.progress_of[other] = st.last_seq + self.lead.get(other, 0)
        self.changed.set()

    def wait(self, index: int, stop: threading.Event) -> None:
        """Return once frame ``index`` is at most the window in front of the slowest stage (or
        that stage has not moved for ``FLOW_STALL_S``, or ``stop`` is set)."""
        stalled_since = time.monotonic()
        last = None
        while self.window and not stop.is_set():
            slowest = min((self.progress_of.get(n, -1) for n in self.stages), default=_UNBOUNDED)
            if index - slowest <= self.window:
                return
            if slowest != last:
                last, stalled_since = slowest, time.monotonic()
            elif time.monotonic() - stalled_since > FLOW_STALL_S:
                log.warning("[%s] flow control: no progress past frame %d for %.1f s; sending frame %d anyway",
                            self.name, slowest, FLOW_STALL_S, index)
                return
            self.changed.clear()
            self.changed.wait(0.05)
