"""Shutdown: the stages of a run stopped in order, so that the recording keeps everything.

The sources and the other stages go first: SIGINT (each publishes end of stream on its outputs
and exits), then SIGKILL for any still there after a grace period. The recorder goes last, told
by a ``stop`` on the control topic once the others are gone, so it records what they sent
until the end; SIGINT and then SIGKILL only if it does not close its file in time.
"""

from __future__ import annotations

import signal
import time

from gflow_msgs.messages import Control, Header, encode

from pipeline.runtime.graph import Plan
from pipeline.runtime.supervision import Supervisor
from pipeline.runtime.transport import Bus

__all__ = ["control", "stop_stages", "stop_recorder"]

#: seconds a stage has to finish after SIGINT (and the recorder after ``stop``, then after SIGINT)
GRACE_S = 10.0


def control(bus: Bus, plan: Plan, command: str) -> None:
    """Publish ``command`` (``start`` or ``stop``) on the graph's control topic."""
    bus.publish(plan.control_topic, encode(Control(header=Header(plan.stream, 0, time.time_ns()), command=command)), 0)


def stop_stages(supervisor: Supervisor, names: list[str], grace: float = GRACE_S) -> None:
    """Ask the stages ``names`` to finish (SIGINT); kill those still running after ``grace`` s."""
    supervisor.signal(names, signal.SIGINT)
    if not supervisor.wait(names, grace):
        supervisor.signal(names, signal.SIGKILL)


def stop_recorder(supervisor: Supervisor, bus: Bus, plan: Plan, names: list[str]) -> None:
    """Tell the recorder to close its file (``stop``), then insist (SIGINT, SIGKILL)."""
    control(bus, plan, "stop")
    if not supervisor.wait(names, GRACE_S):
        stop_stages(supervisor, names, GRACE_S)
