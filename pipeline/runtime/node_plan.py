"""What the launcher hands each stage process: one typed plan, not environment variables.

The launcher writes a :class:`NodePlan` per stage process into the run's folder
(``RUN_DIR/nodes/NAME.json``, rewritten before a restart) and starts the process as
``python -m pipeline.runtime.node RUN_DIR/nodes/NAME.json NAME``, or forks it from the zygote
with the same arguments. The plan carries the validated graph, how to join zenoh, and the
run's state for this process: its restart count, the peers to wait for, where the recording
and the checkpoints are, the launcher to watch, and the run's time limits. A stage process
reads nothing else from its environment but the variables a user sets (``GFLOW_LOG``,
``GFLOW_STARTUP_TRACE``) and the thread counts of numerical libraries, which take effect
when those libraries load.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import msgspec

from pipeline.runtime.graph import Plan
from pipeline.runtime.transport import ZenohSettings

__all__ = ["NodePlan", "NodePlanError", "write_node_plan", "read_node_plan", "LATE_S", "DRAIN_S",
           "EXIT_BAD_SOURCE", "EXIT_DISK_FULL"]

#: seconds an input may be the next to step while the source is ahead before it is given up
LATE_S = 3.0
#: seconds a finished stage waits at most for what it sent to arrive (pipeline/runtime/drain.py)
DRAIN_S = 30.0
#: what a stage process tells its launcher by its exit status, besides 0 (done) and 1 (an exception):
#: a live source that cannot be opened, or an --init box outside its frames (not restarted)
EXIT_BAD_SOURCE = 2
#: the recorder's disk is full (ENOSPC): not worth a restart
EXIT_DISK_FULL = 28


class NodePlanError(ValueError):
    """A node plan that cannot be read; the message is one line naming the file."""


class NodePlan(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """One stage process's plan.

    graph : the validated graph.
    stage : the stage this process runs.
    zenoh : how the process joins zenoh (the launcher's endpoints, the run's security).
    launcher_pid : the launcher to watch: the process stops when it is gone (0: none).
    run_dir : the run's temporary folder (checkpoints under ``state/``), removed by an orphan.
    restarts : how many times the stage was restarted before this process (0: first start).
    peers : a restarted stage: the stages the launcher saw running, the only ones it waits for
        (None: every stage of the graph).
    finished : a restarted stage: the stages the launcher had heard finish (heartbeat state
        draining, done or stopped). They exited before this process could hear them, so it
        takes them as finished: it does not wait for them to drain what it sends.
    recording : the MCAP file: the recorder writes it (a restarted recorder, its next
        segment); a restarted stage catches up from it (None: no recording).
    late_s : seconds before an input that does not come is given up (while the source is ahead).
    drain_s : seconds a finished stage waits at most for what it sent to arrive.
    cv_threads : OpenCV threads of the process.
    """

    graph: Plan
    stage: str
    zenoh: ZenohSettings
    launcher_pid: int = 0
    run_dir: str = ""
    restarts: int = 0
    peers: tuple[str, ...] | None = None
    finished: tuple[str, ...] = ()
    recording: str | None = None
    late_s: float = LATE_S
    drain_s: float = DRAIN_S
    cv_threads: int = 1

    @property
    def state_dir(self) -> str:
        """Where the stage's checkpoint goes ('' without a run folder: no checkpoints)."""
        return os.path.join(self.run_dir, "state") if self.run_dir else ""


def write_node_plan(plan: NodePlan, run_dir: str) -> str:
    """Write ``plan`` to ``run_dir/nodes/STAGE.json`` (atomically: a process never reads half of
    one) and return the path."""
    folder = Path(run_dir, "nodes")
    folder.mkdir(exist_ok=True)
    path = folder / f"{plan.stage}.json"
    tmp = path.with_suffix(".tmp")
    # Python's JSON, which writes inf as Infinity: msgspec's writes null, and a tracker parameter of inf that means
    # something (G-flow's max_rotation_deg: no wall) failed every stage at start-up ("Expected `float`, got `null`")
    tmp.write_text(json.dumps(msgspec.to_builtins(plan), separators=(",", ":")))
    os.replace(tmp, path)
    return str(path)


def read_node_plan(path: str) -> NodePlan:
    """The plan in ``path``; :class:`NodePlanError` with one line when it cannot be read."""
    try:
        return msgspec.convert(json.loads(Path(path).read_text()), NodePlan)
    except OSError as e:
        raise NodePlanError(f"cannot read the node plan {path}: {e.strerror or e}") from None
    except (ValueError, msgspec.ValidationError) as e:  # json's JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise NodePlanError(f"{path} is not a node plan: {e}") from None
