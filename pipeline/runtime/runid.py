"""Run ids: every run gets its own stream, so two runs on one network never mix.

Topics are ``gflow/<stream>/<topic>``. By default a run's stream is the graph's ``stream``
followed by a fresh run id (``demo-3f9c2a``); ``--stream NAME`` chooses it. A graph placed on
several hosts needs the same stream on every host: there the default is the graph's own
``stream`` (every host reads the same file), and a second run of it on the same network is
refused while the first one holds the stream (see ``Launcher``'s check of liveliness tokens);
``--stream`` gives two runs of one placed graph their own streams.
"""

from __future__ import annotations

import secrets

from pipeline.runtime.graph import GraphError, Plan
from pipeline.runtime.transport import topic_key

__all__ = ["new_run_id", "choose_stream"]


def new_run_id() -> str:
    """Six hex digits from the OS's random source (not a seeded draw: it only names the run)."""
    return secrets.token_hex(3)


def choose_stream(plan: Plan, stream: str | None, placed: bool) -> str:
    """Set and return ``plan.stream``: ``stream`` if given, the graph's own for a placed run,
    else the graph's stream with a new run id. The graph's own stream stays the plan's ``camera``:
    stages seed their random draws with it, so a run's results do not depend on its run id."""
    plan.camera = plan.camera or plan.stream
    if stream:
        try:
            topic_key(stream, "x")
        except ValueError as e:
            raise GraphError(f"--stream: {e}") from None
        plan.stream = stream
    elif not placed:
        plan.stream = f"{plan.stream}-{new_run_id()}"
    _retopic(plan)
    return plan.stream


def _retopic(plan: Plan) -> None:
    """Rewrite every stage's topic keys for ``plan.stream`` (they were resolved on the graph's)."""
    for sp in plan.stages.values():
        sp.inputs = {p: _move(t, plan.stream) for p, t in sp.inputs.items()}
        sp.outputs = {p: _move(t, plan.stream) for p, t in sp.outputs.items()}
    plan.external = [_move(t, plan.stream) for t in plan.external]


def _move(key: str, stream: str) -> str:
    parts = key.split("/", 2)
    return topic_key(stream, parts[2]) if len(parts) == 3 and parts[0] == "gflow" else key
