"""One stage as its own OS process on zenoh: ``python -m pipeline.runtime.node NODE_PLAN.json STAGE``.

The launcher hands the process its node plan (:class:`pipeline.runtime.node_plan.NodePlan`):
the graph, how to join zenoh, and the run's state for this process. The process plays one of
three roles, each in a module of its own, on a base that every role shares:

* :mod:`pipeline.runtime.node_base`: join zenoh, the start-up handshake (a node publishes
  data only once it has heard every other node's heartbeat), heartbeats, the launcher's
  control, liveliness, never outliving the launcher;
* :mod:`pipeline.runtime.stage_node`: a stage behind its host, checkpoints and resuming after a
  restart, and waiting at the end until what it sent has arrived; with its two roles
  :mod:`pipeline.runtime.source_node` (frames, flow control, live sources) and
  :mod:`pipeline.runtime.worker_node` (inputs joined by sequence number, late inputs given up,
  catching up from the recording after a restart);
* :mod:`pipeline.runtime.recorder_node`: every message into one MCAP file.

Shutdown: SIGINT or SIGTERM makes a stage abandon what is queued, publish end of stream on its
outputs and exit 0; the recorder closes its MCAP file properly. A Python exception exits 1
with the traceback on stderr (the launcher shows its last line). Signals go to a thread of
their own (:mod:`pipeline.runtime.signals`), and Linux sends SIGTERM when the launcher dies
(:func:`die_with_parent`).
"""

from __future__ import annotations

from pipeline.runtime.trace import mark

mark("node begin")  # before the imports: bench/bench_startup.py tells interpreter start from imports

import ctypes  # noqa: E402
import logging  # noqa: E402
import os  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402

from pipeline.runtime.memory import keep_freed_memory  # noqa: E402
from pipeline.runtime.node_base import NodeBase, exit_now  # noqa: E402
from pipeline.runtime.node_plan import NodePlan, NodePlanError, read_node_plan  # noqa: E402
from pipeline.runtime.recorder_node import RecorderNode  # noqa: E402
from pipeline.runtime.signals import StopSignals  # noqa: E402
from pipeline.runtime.source_node import LiveSourceNode, SourceNode  # noqa: E402
from pipeline.runtime.worker_node import WorkerNode  # noqa: E402

__all__ = ["main", "run_node", "node_for"]

log = logging.getLogger("gflow.node")

PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """Ask Linux to send SIGTERM when the parent (the launcher) dies. A no-op elsewhere."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError) as e:  # the watchdog thread still notices
        log.debug("prctl(PR_SET_PDEATHSIG) unavailable: %s", e)


def node_for(node_plan: NodePlan) -> NodeBase:
    """The node of the role its stage plays: recorder, source (live or not) or worker."""
    sp = node_plan.graph.stages[node_plan.stage]
    if sp.kind == "recorder":
        return RecorderNode(node_plan)
    if sp.is_source():
        return LiveSourceNode(node_plan) if sp.params.get("kind") == "live" else SourceNode(node_plan)
    return WorkerNode(node_plan)


def run_node(plan_path: str, name: str) -> int:
    """Run the stage process of node plan ``plan_path`` (whose stage must be ``name``)."""
    keep_freed_memory()  # frame-sized buffers reused, not faulted in afresh every frame
    # Signals go to a thread of their own (pipeline/runtime/signals.py), never to a Python
    # handler that sets an Event: started before any other thread, so zenoh's inherit the mask.
    holder: list[NodeBase] = []

    def _on_signal(signum: int) -> None:
        if not holder:  # before the node exists there is nothing to stop cleanly
            exit_now()
        node = holder[0]
        if node.parent and os.getppid() != node.parent:
            node.orphaned.set()
        node.stop.set()

    StopSignals(_on_signal).start()
    die_with_parent()
    mark(f"node {name} imported")
    try:
        node_plan = read_node_plan(plan_path)
    except NodePlanError as e:
        print(f"gflow node: {e}", file=sys.stderr)
        return 2
    if node_plan.stage != name or name not in node_plan.graph.stages:
        print(f"gflow node: {plan_path} is the plan of stage {node_plan.stage!r}, not of {name!r}", file=sys.stderr)
        return 2
    node = node_for(node_plan)
    holder.append(node)
    if node.parent and os.getppid() != node.parent:  # the launcher died before we got here
        node.orphaned.set()
        node.stop.set()
    try:
        rc = node.run()
    finally:
        if node.orphaned.is_set():
            exit_now()  # the session was left open: zenoh's callback threads would hold the teardown
    return rc


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: python -m pipeline.runtime.node NODE_PLAN.json STAGE", file=sys.stderr)
        return 2
    logging.basicConfig(level=os.environ.get("GFLOW_LOG", "WARNING"), format="%(levelname)s %(message)s",
                        stream=sys.stderr)
    return run_node(argv[0], argv[1])


if __name__ == "__main__":
    sys.exit(main())
