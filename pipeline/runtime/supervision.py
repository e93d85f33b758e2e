"""Supervision: the stage processes of one launcher, started, watched and restarted.

* Each stage runs ``python -m pipeline.runtime.node NODE_PLAN NAME`` in its own process group
  (forked from the warm zygote the run leased, with the same command line, parent and process
  group: ``pipeline/runtime/zygote.py``), so a Ctrl-C in the terminal
  reaches the launcher only, which then stops the stages in order.
* Its node plan (:class:`pipeline.runtime.node_plan.NodePlan`) is written to the run's folder
  before it starts: the same plan for every stage but for the stage's name, its restart count,
  the peers a restarted stage can still hear from and a restarted recorder's segment file.
* A stage that exits non-zero is reported with its exit status and its last error line, and
  restarted when the graph says ``restart: on-failure`` (up to ``max_restarts``); a restarted
  recorder writes the rest of the run to a new segment file (``NAME.part1.mcap``...). A stage
  that is not restarted, or a recorder whose disk is full, stops the run
  (:class:`StageLost`).
"""

from __future__ import annotations

import collections
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Protocol

import msgspec

from pipeline.io.mcap_io import segment_path
from pipeline.runtime.graph import Plan
from pipeline.runtime.node_plan import EXIT_DISK_FULL, NodePlan, write_node_plan
from pipeline.runtime.trace import mark
from pipeline.runtime.zygote import ForkedStage, Zygote, reap_orphans, stage_environment

__all__ = ["Supervisor", "StageExit", "StageProcess", "StageLost"]


class StageLost(Exception):
    """A stage died and the graph does not restart it (or a host of the graph is lost)."""


@dataclass
class StageExit:
    name: str
    returncode: int
    last_error: str
    restarts: int


class Process(Protocol):
    """What the supervisor uses of a process: ``subprocess.Popen`` or a :class:`ForkedStage`."""

    @property
    def pid(self) -> int: ...

    @property
    def returncode(self) -> int | None: ...

    @property
    def stderr(self) -> Iterable[str] | None: ...

    def poll(self) -> int | None: ...

    def wait(self, timeout: float | None = None) -> int | None: ...


class StageProcess:
    """One stage process, with the last lines of its stderr."""

    def __init__(self, name: str, popen: Process, restarts: int = 0) -> None:
        self.name = name
        self.popen = popen
        self.tail: collections.deque[str] = collections.deque(maxlen=30)
        self.restarts = restarts
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.popen.stderr is not None
        for line in self.popen.stderr:
            line = line.rstrip()
            if line:
                self.tail.append(line)

    def alive(self) -> bool:
        return self.popen.poll() is None

    def last_error(self) -> str:
        for line in reversed(self.tail):
            if line.strip() and not line.startswith(("  ", "Traceback")):
                return line.strip()
        return ""


class Supervisor:
    """The stage processes this launcher starts.

    Parameters
    ----------
    plan : the graph.
    say : where the supervisor's one-line reports go (a stage died, is restarted...).
    on_spawn : called with a stage's name whenever a process of it is started.
    finished : the stages heard to have finished so far (handed to a restarted stage).
    """

    def __init__(self, plan: Plan, say: Callable[[str], None], on_spawn: Callable[[str], None] | None = None,
                 finished: Callable[[], set[str]] | None = None) -> None:
        self.plan = plan
        self.finished = finished
        self.node_plan: NodePlan | None = None
        self.say = say
        self.on_spawn = on_spawn
        self.procs: dict[str, StageProcess] = {}
        self.pids: dict[str, list[int]] = {}
        self.exits: dict[str, StageExit] = {}
        self._zygote: Zygote | None = None
        self.zygote_broken = False  # the zygote failed a fork: the run gives it back broken
        self._reaped_at = 0.0

    # -- starting ----------------------------------------------------------------------------
    def start(self, names: list[str], node_plan: NodePlan, zygote: Zygote | None) -> None:
        """Start a process for each of ``names``, forked from ``zygote`` when there is one (the
        run's lease: the launcher gives it back; restarts start ``python -m pipeline.runtime.node``).
        ``node_plan`` is what every stage process is handed, but for ``stage``, ``restarts``,
        ``peers`` and a restarted recorder's ``recording``, which :meth:`spawn` fills in."""
        self.node_plan = node_plan
        self._zygote = zygote
        try:
            for n in names:
                self.procs[n] = self.spawn(n)
                mark(f"launcher spawned {n} {self.procs[n].popen.pid}")
        finally:
            self._zygote = None

    def _plan_of(self, name: str, restarts: int) -> NodePlan:
        """What stage ``name`` is handed (its ``restarts``-th restart; 0: its first start)."""
        base = self.node_plan
        assert base is not None, "start() first"
        recording = base.recording
        if recording and restarts and self.plan.stages[name].kind == "recorder":
            # a restarted recorder starts a new segment: the first file stays as it was closed or torn
            recording = str(segment_path(recording, restarts))
        # the peers a restarted stage can still hear from
        peers = tuple(n for n, p in self.procs.items() if n != name and p.alive()) if restarts else None
        # and those that finished meanwhile: it would never hear them say so
        done = tuple(sorted(n for n in self.finished() if n != name)) if restarts and self.finished else ()
        return msgspec.structs.replace(base, stage=name, restarts=restarts, peers=peers, finished=done,
                                       recording=recording)

    def spawn(self, name: str, restarts: int = 0) -> StageProcess:
        """Start a process of stage ``name``."""
        node_plan = self._plan_of(name, restarts)
        plan_file = write_node_plan(node_plan, node_plan.run_dir)
        env = self._environment(node_plan.cv_threads)
        if self.on_spawn is not None:
            self.on_spawn(name)
        if self._zygote is not None and not restarts:
            # forked from the warm zygote (pipeline/runtime/zygote.py): no interpreter start, shared imports paid once
            r, w = os.pipe()
            try:
                pid = self._zygote.spawn(plan_file, name, env, w)
            except OSError as e:
                self._zygote, self.zygote_broken = None, True
                os.close(r)
                mark(f"launcher zygote failed: {e}")
            else:
                self.pids.setdefault(name, []).append(pid)
                return StageProcess(name, ForkedStage(pid, os.fdopen(r, "r", errors="replace")), restarts)
            finally:
                os.close(w)
        popen = subprocess.Popen([sys.executable, "-m", "pipeline.runtime.node", plan_file, name], env=env,
                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                 text=True, start_new_session=True)
        self.pids.setdefault(name, []).append(popen.pid)
        return StageProcess(name, popen, restarts)

    @staticmethod
    def _environment(threads: int) -> dict[str, str]:
        """The environment of a stage process: the launcher's, with one compute thread per
        process unless the user says otherwise. Parallelism comes from the stage processes:
        several processes each running a thread per core for BLAS / OpenMP oversubscribe the
        cores (measured: every stage 2-3x slower than inline on 2 cores). The run's own state
        goes in the node plan, never here (:func:`pipeline.runtime.zygote.stage_environment`)."""
        return stage_environment(os.environ, threads)

    def reap_orphans(self, every: float = 0.5) -> None:
        """Reap the exited orphans of the stage processes (re-parented to this process while it
        holds a zygote's lease), at most once every ``every`` s."""
        now = time.monotonic()
        if now - self._reaped_at < every:
            return
        self._reaped_at = now
        pids = [p for ps in self.pids.values() for p in ps]
        reap_orphans(pids, pids)

    # -- watching ----------------------------------------------------------------------------
    def alive(self, name: str) -> bool:
        p = self.procs.get(name)
        return p is not None and p.alive()

    def dead(self) -> list[str]:
        """The stages whose process has exited."""
        return [n for n, p in self.procs.items() if not p.alive()]

    def check(self, recorder: list[str], workers: list[str]) -> bool:
        """Take note of the processes that exited since the last call, restart those the graph
        restarts, and return whether a worker (a stage that is not the recorder) still runs.
        Raises :class:`StageLost` when a stage is gone for good (a recorder that stopped at all
        is restarted or lost: it stops only when told to)."""
        running = False
        self.reap_orphans()
        for n in recorder + workers:
            p = self.procs[n]
            rc = p.popen.poll()
            if rc is None:
                running = running or n in workers
                continue
            if n in self.exits:
                continue
            if rc != 0 or n in recorder:
                sp = self.plan.stages[n]
                self.say(f"stage {n} died with exit status {rc}: {p.last_error() or 'no message'}")
                if n in recorder and rc == EXIT_DISK_FULL:
                    self.record_exit(n)
                    self.say(f"stopping the pipeline: the recording's disk is full ({p.last_error()})")
                    raise StageLost(n)
                if sp.restart == "on-failure" and p.restarts < sp.max_restarts:
                    recording = self.node_plan.recording if self.node_plan is not None else None
                    self.say(f"restarting {n} ({p.restarts + 1}/{sp.max_restarts})"
                             + (f": recording the rest to {segment_path(recording, p.restarts + 1)}"
                                if n in recorder and recording else ""))
                    self.procs[n] = self.spawn(n, p.restarts + 1)
                    running = True
                    continue
                self.record_exit(n)
                # the graph cannot go on without it: stop the others cleanly
                self.say(f"stopping the pipeline: {n} is not restarted (restart: {sp.restart})")
                raise StageLost(n)
            self.record_exit(n)
        return running

    def record_exit(self, n: str) -> None:
        p = self.procs[n]
        p.reader.join(timeout=1.0)
        self.exits[n] = StageExit(n, p.popen.returncode if p.popen.returncode is not None else -1,
                                  p.last_error(), p.restarts)

    def record_exits(self) -> None:
        """Take note of every process that has exited and was not yet noted."""
        for n in self.procs:
            if n not in self.exits and not self.procs[n].alive():
                self.record_exit(n)

    # -- stopping ----------------------------------------------------------------------------
    def signal(self, names: Iterable[str], sig: int) -> None:
        """Send ``sig`` to the process group of each running stage of ``names``."""
        for n in names:
            p = self.procs.get(n)
            if p is not None and p.alive():
                try:
                    os.killpg(p.popen.pid, sig)
                    if sig in (signal.SIGINT, signal.SIGTERM):
                        os.killpg(p.popen.pid, signal.SIGCONT)  # a stopped (SIGSTOP) stage must see it too
                except ProcessLookupError:  # no group yet: a stage forked by the zygote, before its setsid
                    try:
                        os.kill(p.popen.pid, sig)
                    except ProcessLookupError:
                        pass

    def wait(self, names: Iterable[str], timeout: float) -> bool:
        """Wait up to ``timeout`` s in all for the processes of ``names`` to exit; whether they did."""
        end = time.monotonic() + timeout
        for n in names:
            p = self.procs.get(n)
            if p is None:
                continue
            try:
                p.popen.wait(max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                return False
        return True
