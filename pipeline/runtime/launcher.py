"""Start every stage of a graph as its own OS process, supervise them, show progress, and
shut everything down cleanly.

The launcher puts together the roles it plays, each in a module of its own:

* supervision (``pipeline/runtime/supervision.py``): the stage processes, each handed its
  node plan, in its own process group, restarted when the graph says ``restart: on-failure``;
* progress (``pipeline/runtime/progress.py``): the stages' heartbeats, errors and estimates,
  the progress line, and stall detection: a stage that makes no progress for
  ``stall_timeout`` seconds while the source is ahead of it is named, with what it waits
  for, and the run stops (not ok);
* shutdown (``pipeline/runtime/shutdown.py``): sources and stages first, the recorder last,
  so the MCAP file keeps everything (a Ctrl-C in the terminal reaches the launcher only).
  A ``stop`` published on the control topic by a user's tool (``gflow pub``) is passed on to
  every stage by the launcher, so the run ends normally even if the tool has not yet linked
  to every stage.

The launcher's zenoh session listens on one loopback endpoint; the stages connect to it and,
through gossip, to each other. The node plans, the checkpoints and nothing else live in one
temporary folder (``gflow-run-*``), removed at the end; if the launcher itself is killed, its
stages die with it (parent-death signal) and remove the folder.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, TextIO

from gflow_msgs.messages import Control, ErrorReport, StageStatus, decode

from pipeline.runtime.drain import FINISHED
from pipeline.runtime.graph import Plan
from pipeline.runtime.live_plan import live_source
from pipeline.runtime.multihost import HostWatch, host_gateway, node_listen, stream_in_use
from pipeline.runtime.node_plan import DRAIN_S, LATE_S, NodePlan
from pipeline.runtime.placement import describe_hosts, local_stages
from pipeline.runtime.progress import Console, ProgressMonitor, Stalled
from pipeline.runtime.security import Signer
from pipeline.runtime.shutdown import control, stop_recorder, stop_stages
from pipeline.runtime.signals import StopSignals
from pipeline.runtime.supervision import StageExit, StageLost, Supervisor
from pipeline.runtime.trace import mark
from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session
from pipeline.runtime.user_settings import seconds
from pipeline.runtime.zygote import lease, release, stage_environment

__all__ = ["Launcher", "LaunchResult", "StageExit", "run_dir_parent"]

#: seconds before a stage of a run placed on hosts gives up a late input (3 s on one host)
LATE_S_ACROSS_HOSTS = 10.0


@dataclass
class LaunchResult:
    ok: bool
    seconds: float
    recording: str | None
    status: dict[str, StageStatus]
    exits: dict[str, StageExit]
    errors: list[ErrorReport]
    pids: dict[str, list[int]] = field(default_factory=dict)
    interrupted: bool = False
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    stall: str = ""  # why the run was stopped as stalled ('' if it was not)
    estimates: dict[int, bytes] = field(default_factory=dict)  # every estimate payload heard, by frame


def run_dir_parent(min_free: int = 2 * 2**30) -> str | None:
    """Where the run's folder goes: /dev/shm (memory) when it is there with room to spare,
    else the default temporary folder. Every restartable stage rewrites its checkpoint
    there after every step (a frame, features: up to 660 KB a step on caviar1); measured
    on a shared disk, 410 us a write against 110 us in memory (GFLOW_RUN_PARENT overrides)."""
    explicit = os.environ.get("GFLOW_RUN_PARENT")
    if explicit:
        return explicit
    try:
        if os.access("/dev/shm", os.W_OK) and shutil.disk_usage("/dev/shm").free >= min_free:
            return "/dev/shm"
    except OSError:
        pass
    return None


class Launcher:
    """Run a plan as processes.

    Parameters
    ----------
    plan : validated graph.
    zenoh : how the launcher itself joins zenoh. The default listens on a free loopback port.
    recording : MCAP path (default: from the recorder's ``path`` pattern).
    out : where progress goes (default stderr); progress lines are rewritten in place on a tty.
    startup_timeout : seconds to wait for every stage's first heartbeat.
    threads_per_stage : compute threads (OpenCV, BLAS, OpenMP) each stage process may use.
    stall_timeout : seconds without progress before the run stops (default ``GFLOW_STALL_S``, 30).
    hosts : the host labels this launcher starts the stages of (placement; all stages without).
    say_recording : print "recording to PATH" (not for a temporary recording: ``--no-record``).
    """

    def __init__(self, plan: Plan, zenoh: ZenohSettings | None = None, recording: str | None = None,
                 out: TextIO | None = None, progress: bool = True, startup_timeout: float = 60.0,
                 total_frames: int | None = None, on_status: Callable[[dict[str, StageStatus]], None] | None = None,
                 threads_per_stage: int = 1, stall_timeout: float | None = None,
                 hosts: tuple[str, ...] = (), say_recording: bool = True) -> None:
        self.plan = plan
        self.say_recording = say_recording  # False: a temporary recording the user asked not to keep
        # placement: the stages this host starts (all of them without ``hosts``)
        self.local = local_stages(plan, hosts)
        self.hosts = tuple(hosts)
        if zenoh is None:
            zenoh = ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",))
        # the stages connect to the launcher's endpoints, so an ephemeral port must be made concrete
        listen = tuple(f"{e[:-2]}:{free_port()}" if e.startswith("tcp/127.0.0.1") and e.endswith(":0") else e
                       for e in zenoh.listen)
        self.zenoh = dataclasses.replace(zenoh, listen=listen)
        self.recording = recording or plan.recording_path()
        self.startup_timeout = startup_timeout
        self.on_status = on_status
        self.threads_per_stage = threads_per_stage
        # the user's settings, read once (pipeline/runtime/user_settings.py) and handed to the stages
        # in their plans; across hosts a link may stall for seconds (TCP retransmits after a cut)
        self.late_s = seconds("GFLOW_LATE_S", LATE_S_ACROSS_HOSTS if self.hosts else LATE_S)
        self.drain_s = seconds("GFLOW_DRAIN_S", DRAIN_S)
        self.console = Console(out or sys.stderr, progress)
        self.monitor = ProgressMonitor(plan, self.console, total_frames, live=live_source(plan) is not None,
                                       stall_timeout=(seconds("GFLOW_STALL_S", 30.0) if stall_timeout is None
                                                      else stall_timeout))
        self.supervisor = Supervisor(plan, self.console.say, on_spawn=self.monitor.forget,
                                     finished=lambda: {n for n, st in self.monitor.states().items() if st in FINISHED})
        self.run_dir: str = ""
        self._interrupt = threading.Event()
        self._stop_heard = threading.Event()  # a ``stop`` on the control topic, from a user's tool
        self._stop_relayed = False

    @property
    def status(self) -> dict[str, StageStatus]:
        """The last heartbeat of every stage heard so far (updated while the run goes on)."""
        return self.monitor.status

    @property
    def pids(self) -> dict[str, list[int]]:
        """Every process started for each stage, in order (restarts add theirs)."""
        return self.supervisor.pids

    @property
    def exits(self) -> dict[str, StageExit]:
        """The stages whose process has exited for good, with how."""
        return self.supervisor.exits

    def request_stop(self) -> None:
        """Ask the run to stop (what SIGINT / SIGTERM do)."""
        self._interrupt.set()

    def _node_zenoh(self, gateway: ZenohSettings | None) -> ZenohSettings:
        """How the stage processes join zenoh: through the launcher's endpoints. A client launcher
        listens nowhere: its stages go to the router only (not to whatever else may listen on the
        launcher's would-be port). A stage process's handshake waits for every peer's heartbeat,
        so opening its session need not wait for them too."""
        z = self.zenoh
        return ZenohSettings(mode=z.mode if z.mode != "router" else "peer",
                             listen=node_listen(z) if z.mode != "client" else (),
                             connect=tuple(e.replace("0.0.0.0", "127.0.0.1") for e in z.listen
                                           if not e.endswith(":0") and z.mode != "client")
                             + (tuple(z.connect) if gateway is None else ()),
                             multicast=z.multicast, shm_pool_mb=z.shm_pool_mb, security=z.security,
                             connect_scouted=False)

    def run(self) -> LaunchResult:
        plan, sup, monitor = self.plan, self.supervisor, self.monitor
        gateway = host_gateway(self.zenoh, bool(self.hosts))
        if gateway is not None:  # this host's stages reach the others through the launcher
            self.zenoh = gateway
        node_zenoh = self._node_zenoh(gateway)
        mark("launcher run")
        # SIGINT / SIGTERM / SIGHUP on a sigwait thread, never a Python handler setting the Event
        # (pipeline/runtime/signals.py); taken before the session opens, so zenoh's threads block them
        signals = (StopSignals(lambda _: self._interrupt.set()).start()
                   if threading.current_thread() is threading.main_thread() else None)
        try:
            session = open_session(self.zenoh)
            mark("launcher session")
            bus = Bus(session, signer=Signer.of(self.zenoh.security))
            if self.hosts or self.zenoh.connect:  # another run may hold this stream on the network
                busy = stream_in_use(session, plan.stream, self.local, external=bool(plan.external))
                if busy:
                    session.close()
                    raise RuntimeError(busy)
            watch = HostWatch(session, plan, self.local, self.console.say)
            monitor.subscribe(bus)
            bus.subscribe(plan.control_topic, self._on_control)
            self.run_dir = tempfile.mkdtemp(prefix="gflow-run-", dir=run_dir_parent())
            os.makedirs(os.path.join(self.run_dir, "state"))
        except BaseException:
            if signals is not None:
                signals.close()
            raise

        t0 = time.monotonic()
        recorder = [n for n, s in plan.stages.items() if s.kind == "recorder" and n in self.local]
        workers = [n for n in plan.stages if n not in recorder and n in self.local]
        node_plan = NodePlan(graph=plan, stage="", zenoh=node_zenoh, launcher_pid=os.getpid(), run_dir=self.run_dir,
                             recording=self.recording or None, late_s=self.late_s, drain_s=self.drain_s,
                             cv_threads=self.threads_per_stage)
        finished = interrupted = False
        zygote = None
        try:
            # the stage processes fork from this process's zygote, leased for the run (pipeline/runtime/zygote.py)
            if self.threads_per_stage == 1:
                zygote = lease(stage_environment(os.environ, 1), {plan.stages[n].kind for n in recorder + workers})
            sup.start(recorder + workers, node_plan, zygote)
            if recorder and self.recording and self.say_recording:
                self.console.say(f"recording to {self.recording}")
            self._await_heartbeats(watch, t0)
            mark("launcher heard all")
            control(bus, plan, "start")
            mark("launcher start sent")
            self._supervise(bus, watch, recorder, workers)
            finished = True
        except (KeyboardInterrupt, StageLost, Stalled) as e:
            interrupted = isinstance(e, KeyboardInterrupt)
            if interrupted:
                self.console.say("stopping: asking every stage to finish")
            if isinstance(e, Stalled):
                self.console.say(f"{e}; stopping the pipeline")
            stop_stages(sup, workers)
        except Exception:
            stop_stages(sup, workers, grace=5.0)
            raise
        finally:
            # the recorder goes last, so it keeps everything the stages sent
            if recorder:
                stop_recorder(sup, bus, plan, recorder)
            sup.record_exits()
            sup.reap_orphans(every=0.0)
            release(zygote, sup.zygote_broken)  # this process is no longer a subreaper
            # a stage's last heartbeat leaves just before its process exits: hear it before the
            # session closes (under load it can arrive after the exit is seen)
            monitor.await_final([n for n, e in sup.exits.items() if e.returncode == 0], 2.0)
            monitor.show_final()
            self.console.end()
            session.close()
            shutil.rmtree(self.run_dir, ignore_errors=True)
            if signals is not None:
                signals.close()
        exits = dict(sup.exits)
        ok = finished and all(e.returncode == 0 for e in exits.values()) and not watch.lost
        return LaunchResult(ok=ok, seconds=time.monotonic() - t0, recording=self.recording if recorder else None,
                            status=monitor.snapshot(), exits=exits, errors=list(monitor.errors),
                            pids=dict(sup.pids), interrupted=interrupted, peak_rss_mb=dict(monitor.peak_rss),
                            stall=monitor.stall, estimates=dict(monitor.estimates))

    def _await_heartbeats(self, watch: HostWatch, t0: float) -> None:
        """Wait for every stage's first heartbeat (from this host and the others)."""
        plan, sup = self.plan, self.supervisor
        while True:
            seen = set(self.monitor.snapshot())
            if seen >= set(plan.stages):
                return
            dead = sup.dead()
            if dead:
                for n in dead:
                    sup.record_exit(n)
                raise RuntimeError("stage(s) exited during start-up: " + "; ".join(
                    f"{n} (exit {sup.procs[n].popen.returncode}): {sup.procs[n].last_error() or 'no message'}"
                    for n in dead))
            self._check_interrupt()
            missing = [n for n in plan.stages if n not in seen]
            watch.waiting_for(missing, time.monotonic() - t0)
            if time.monotonic() - t0 > self.startup_timeout:
                raise RuntimeError(f"no heartbeat from {describe_hosts(plan, missing)} after "
                                   f"{self.startup_timeout:.0f} s")
            time.sleep(0.02)

    def _supervise(self, bus: Bus, watch: HostWatch, recorder: list[str], workers: list[str]) -> None:
        """Watch the running stages until every one of them has finished (returns), a stage or a
        host is lost (:class:`StageLost`), the run stalls (:class:`Stalled`) or is interrupted."""
        plan, sup, monitor = self.plan, self.supervisor, self.monitor
        # stages on other hosts: a local recorder keeps recording until they are all finished
        remote = [n for n in plan.stages if n not in self.local and plan.stages[n].kind != "recorder"]
        sources = [n for n in workers if plan.stages[n].is_source()]
        last_start = time.monotonic()
        monitor.begin(last_start)
        while True:
            self._check_interrupt()
            now = time.monotonic()
            states = monitor.states()
            if self._stop_heard.is_set() and not self._stop_relayed:
                self._relay_stop(bus)
            if now - last_start > 0.5 and any(states.get(n) == "ready" for n in sources):
                control(bus, plan, "start")  # a source missed the first start
                last_start = now
            running = sup.check(recorder, workers)
            monitor.check_stall(workers, sup.alive, now)
            states = monitor.states()
            if watch.check(states):  # a host of the graph is gone and the graph says stop
                raise StageLost(watch.lost_report)
            if recorder and watch.unfinished(remote, states):
                running = True  # the local recorder records until the other hosts have finished
            if recorder and not workers and not remote and not self._external_ended(recorder[0]):
                running = True  # a graph fed from outside only: record until each of its ends
            if self.on_status is not None:
                self.on_status(monitor.snapshot())
            monitor.show(now)
            if not running:
                return
            time.sleep(0.05)

    def _on_control(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        """On zenoh's thread: note a ``stop`` on the control topic (garbage is the stages' to count)."""
        try:
            msg = decode(payload)
        except ValueError:
            return
        if isinstance(msg, Control) and msg.command == "stop":
            self._stop_heard.set()

    def _relay_stop(self, bus: Bus) -> None:
        """Send a ``stop`` heard on the control topic on to every stage, once. A tool that
        publishes it (``gflow pub ... Control '{"command": "stop"}'``) reaches the launcher first,
        whose endpoint it connects to, but in peer mode only those stages it has already linked
        to; every stage is linked to the launcher, so the run stops as a whole, normally."""
        self._stop_relayed = True
        self.console.say("stop received on the control topic: every stage asked to finish")
        control(bus, self.plan, "stop")

    def _check_interrupt(self) -> None:
        if self._interrupt.is_set():
            raise KeyboardInterrupt

    def _external_ended(self, recorder: str) -> bool:
        """Whether the recorder has recorded the end of stream of every external topic it keeps."""
        from pipeline.runtime.drain import recorder_needs

        st = self.monitor.snapshot().get(recorder)
        _, need = recorder_needs(self.plan, self.plan.external)
        return st is not None and need <= set(st.ended)
