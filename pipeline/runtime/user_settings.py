"""The environment variables a user sets to tune a run, read by the launcher when it is made.

The launcher reads them once and hands their values to the stage processes in their plans
(:class:`pipeline.runtime.node_plan.NodePlan`); no stage process reads them.

* ``GFLOW_LATE_S``: seconds before a stage gives up an input that does not come (3; 10 in a
  run placed on hosts).
* ``GFLOW_DRAIN_S``: seconds a finished stage waits at most for what it sent to arrive (30).
* ``GFLOW_STALL_S``: seconds without progress before the launcher stops a stalled run (30).
* ``GFLOW_RUN_PARENT``: where the run's temporary folder goes (default: /dev/shm when it has room).
"""

from __future__ import annotations

import math
import os

__all__ = ["seconds"]


def seconds(name: str, default: float) -> float:
    """The number of seconds in the environment variable ``name`` (``default`` when it is unset
    or empty); a ValueError naming the variable when it is not a number >= 0."""
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value >= 0 or math.isinf(value):
        raise ValueError(f"{name} must be a number of seconds >= 0, got {text!r}")
    return value
