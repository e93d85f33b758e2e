"""Start every stage of a graph as its own OS process, supervise them, show progress, and
shut everything down cleanly.

* Each stage runs ``python -m pipeline.runtime.node PLAN.json NAME`` in its own process group
  (started from the ``gflow`` command, it is forked from a warm zygote instead, with the same
  command line, parent and process group: ``pipeline/runtime/zygote.py``)
  (so a Ctrl-C in the terminal reaches the launcher only, which then stops the stages in
  order: sources and stages first, the recorder last, so the MCAP file keeps everything).
* The launcher's zenoh session listens on one loopback endpoint; the stages connect to
  it and, through gossip, to each other.
* A stage that exits non-zero is reported with its exit status and its last error line,
  and restarted when the graph says ``restart: on-failure`` (up to ``max_restarts``). The
  restarted stage resumes from its checkpoint (see ``pipeline/runtime/node.py``); a restarted
  recorder writes the rest of the run to a new segment file (``NAME.part1.mcap``...).
* Stall detection: a stage that makes no progress for ``stall_timeout`` seconds while the
  source is ahead of it is named, with what it waits for, and the run stops (not ok).
* The plan, the checkpoints and nothing else live in one temporary folder
  (``gflow-run-*``), removed at the end; if the launcher itself is killed, its stages die
  with it (parent-death signal) and remove the folder.
"""

from __future__ import annotations

import collections
import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TextIO

from stages.messages import Control, ErrorReport, Header, StageStatus, decode, encode

from pipeline.runtime.graph import Plan
from pipeline.runtime.live_plan import live_source
from pipeline.runtime.placement import describe_hosts, local_stages
from pipeline.runtime.multihost import HostWatch, host_gateway, node_listen, stream_in_use
from pipeline.io.mcap_io import segment_path

EXIT_DISK_FULL = 28  # pipeline.runtime.node's recorder exit status on a full disk
#: estimates whose capture-to-estimate latency the progress line summarises (a live source)
LATENCY_WINDOW = 250
#: seconds before a stage of a run placed on hosts gives up a late input (3 s on one host)
LATE_S_ACROSS_HOSTS = 10.0
from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session
from pipeline.runtime.security import Signer
from pipeline.runtime.signals import StopSignals
from pipeline.runtime.trace import mark
from pipeline.runtime.zygote import ForkedStage, Zygote, take

__all__ = ["Launcher", "LaunchResult", "StageExit"]


@dataclass
class StageExit:
    name: str
    returncode: int
    last_error: str
    restarts: int


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


class _StageLost(Exception):
    """A stage died and the graph does not restart it."""


class _Stalled(Exception):
    """No stage made progress for ``stall_timeout`` seconds while the source was ahead."""


class _Proc:
    def __init__(self, name: str, popen: subprocess.Popen) -> None:
        self.name = name
        self.popen = popen
        self.tail: collections.deque[str] = collections.deque(maxlen=30)
        self.restarts = 0
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.popen.stderr is not None
        for line in self.popen.stderr:
            line = line.rstrip()
            if line:
                self.tail.append(line)

    def last_error(self) -> str:
        for line in reversed(self.tail):
            if line.strip() and not line.startswith(("  ", "Traceback")):
                return line.strip()
        return ""


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
    """

    def __init__(self, plan: Plan, zenoh: ZenohSettings | None = None, recording: str | None = None,
                 out: TextIO | None = None, progress: bool = True, startup_timeout: float = 60.0,
                 total_frames: int | None = None, on_status: Callable[[dict[str, StageStatus]], None] | None = None,
                 threads_per_stage: int = 1, stall_timeout: float | None = None,
                 hosts: tuple[str, ...] = ()) -> None:
        self.plan = plan
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
        self.out = out or sys.stderr
        self.progress = progress
        self.startup_timeout = startup_timeout
        self.total_frames = total_frames
        self.on_status = on_status
        self.threads_per_stage = threads_per_stage
        self.stall_timeout = (float(os.environ.get("GFLOW_STALL_S", "30")) if stall_timeout is None
                              else stall_timeout)
        self.stall: str = ""  # the stall report, when the run stopped for one
        self.run_dir: str = ""
        self._progress_at: dict[str, tuple[tuple, float]] = {}
        self.estimates: dict[int, bytes] = {}
        # a live source: capture-to-estimate latency (ms) of the last estimates heard, for the progress line
        self.live = live_source(plan) is not None
        self.latency_ms: collections.deque[float] = collections.deque(maxlen=LATENCY_WINDOW)
        self.status: dict[str, StageStatus] = {}
        self.errors: list[ErrorReport] = []
        self.procs: dict[str, _Proc] = {}
        self.pids: dict[str, list[int]] = {}
        self.exits: dict[str, StageExit] = {}
        self.peak_rss: dict[str, float] = {}
        self._interrupt = threading.Event()
        self._lock = threading.Lock()
        self._zygote: Zygote | None = None

    # -- zenoh callbacks (zenoh threads: hand over, never block) -----------------------------
    def _on_status(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        try:
            msg = decode(payload)
        except ValueError:
            return
        if isinstance(msg, StageStatus):
            with self._lock:
                self.status[msg.stage] = msg
                self.peak_rss[msg.stage] = max(self.peak_rss.get(msg.stage, 0.0), msg.rss_mb)

    def _on_error(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        try:
            msg = decode(payload)
        except ValueError:
            return
        if isinstance(msg, ErrorReport):
            with self._lock:
                self.errors.append(msg)
                n = len(self.errors)
            if n <= 20:
                self._print(f"error from {msg.stage} [{msg.kind}] {msg.message}")
            elif n == 21:
                self._print("more errors: counting them without printing (see the recording's errors topic)")

    def _on_estimate(self, key: str, payload: bytes, pub_ns: int, seq: int, type_name: str) -> None:
        # a copy of every estimate: what the recording lost (a recorder restart) is still known
        if seq >= 0 and type_name in ("Estimate", "PoseEstimate"):
            self.estimates[seq] = payload
            if self.live:
                now = time.time_ns()
                try:
                    self.latency_ms.append((now - decode(payload).header.stamp_ns) / 1e6)
                except (ValueError, AttributeError):
                    pass

    # -- output ----------------------------------------------------------------------------
    def _print(self, text: str) -> None:
        if self.progress:
            if self.out.isatty():
                self.out.write("\r\033[K")
            self.out.write(text + "\n")
            self.out.flush()

    def _progress_line(self) -> str:
        parts = []
        with self._lock:
            # heartbeats arrive at different times: the source has sent at least what any stage did
            done = max((st.steps for n, st in self.status.items() if n in self.plan.stages
                        and self.plan.stages[n].kind != "recorder"), default=0)
            for name in self.plan.stages:
                st = self.status.get(name)
                if st is None:
                    parts.append(f"{name}: -")
                elif self.plan.stages[name].kind == "recorder":
                    parts.append(f"{name}: {st.steps} msgs")
                else:
                    drop = sum(st.dropped.values())
                    steps = max(st.steps, done) if self.plan.stages[name].is_source() else st.steps
                    parts.append(f"{name}: {steps}" + (f"/{self.total_frames}" if self.total_frames and
                                 self.plan.stages[name].is_source() else "") + f" @{st.fps:.1f}fps"
                                 + (f" drop={drop}" if drop else "")
                                 + (f" skipped={st.skipped}" if st.captured else ""))
            lat = sorted(self.latency_ms)
        if lat:  # capture to estimate, over the last LATENCY_WINDOW estimates
            parts.append(f"latency p50 {lat[len(lat) // 2]:.0f} ms p99 {lat[min(len(lat) - 1, int(0.99 * len(lat)))]:.0f} ms")
        return " | ".join(parts)

    # -- processes -------------------------------------------------------------------------
    def _spawn(self, name: str, plan_file: str, restarts: int = 0) -> _Proc:
        env = dict(os.environ)
        # Parallelism comes from the stage processes: one compute thread each. Several processes
        # each running a thread per core for BLAS / OpenMP oversubscribe the cores (measured:
        # every stage 2-3x slower than inline on 2 cores). A user's explicit setting wins.
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(var, str(self.threads_per_stage))
        env.setdefault("GFLOW_CV_THREADS", str(self.threads_per_stage))
        if self.hosts:  # across hosts a link may stall for seconds (TCP retransmits after a cut)
            env.setdefault("GFLOW_LATE_S", str(LATE_S_ACROSS_HOSTS))
        if self.recording:
            # a restarted recorder starts a new segment: the first file stays as it was closed or torn
            recorder = self.plan.stages[name].kind == "recorder"
            env["GFLOW_RECORDING"] = str(segment_path(self.recording, restarts)) if restarts and recorder else self.recording
        env["GFLOW_RUN_DIR"] = self.run_dir
        env["GFLOW_STATE_DIR"] = os.path.join(self.run_dir, "state")
        env["GFLOW_LAUNCHER_PID"] = str(os.getpid())
        env["GFLOW_RESTARTS"] = str(restarts)
        if restarts:  # the peers a restarted stage can still hear from
            env["GFLOW_PEERS"] = ",".join(n for n, p in self.procs.items() if n != name and p.popen.poll() is None)
        self._progress_at.pop(name, None)
        root = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        if self._zygote is not None and not restarts:
            # forked from the warm zygote (pipeline/runtime/zygote.py): no interpreter start, shared imports paid once
            r, w = os.pipe()
            try:
                pid = self._zygote.spawn(plan_file, name, env, w)
            except OSError as e:
                self._close_zygote()
                os.close(r)
                mark(f"launcher zygote failed: {e}")
            else:
                self.pids.setdefault(name, []).append(pid)
                return _Proc(name, ForkedStage(pid, os.fdopen(r, "r", errors="replace")))  # type: ignore[arg-type]
            finally:
                os.close(w)
        popen = subprocess.Popen([sys.executable, "-m", "pipeline.runtime.node", plan_file, name], env=env,
                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                 text=True, start_new_session=True)
        self.pids.setdefault(name, []).append(popen.pid)
        return _Proc(name, popen)

    def _close_zygote(self) -> None:
        if self._zygote is not None:
            z, self._zygote = self._zygote, None
            z.close()

    def _signal_all(self, names, sig: int) -> None:
        for n in names:
            p = self.procs.get(n)
            if p is not None and p.popen.poll() is None:
                try:
                    os.killpg(p.popen.pid, sig)
                    if sig in (signal.SIGINT, signal.SIGTERM):
                        os.killpg(p.popen.pid, signal.SIGCONT)  # a stopped (SIGSTOP) stage must see it too
                except ProcessLookupError:
                    pass

    def _wait(self, names, timeout: float) -> bool:
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

    def _check_stall(self, workers: list[str], now: float) -> None:
        """Raise :class:`_Stalled` when a live stage has not moved for ``stall_timeout`` s
        while the source is ahead of it, it waits for an input, or the sources have finished."""
        if self.stall_timeout <= 0:
            return
        with self._lock:
            status = dict(self.status)
        sources = [n for n in workers if self.plan.stages[n].is_source()]
        src = max((status[n].last_seq for n in sources if n in status), default=-1)
        sources_done = bool(sources) and all(n in status and status[n].state == "done" for n in sources)
        stuck = []
        for n in workers:
            st = status.get(n)
            if (st is None or n in sources or st.state in ("done", "stopped", "draining")
                    or self.procs[n].popen.poll() is not None):
                continue
            key = (st.pid, st.steps, st.last_seq)
            prev = self._progress_at.get(n)
            if prev is None or prev[0] != key:
                self._progress_at[n] = (key, now)
                continue
            if now - prev[1] >= self.stall_timeout and (src > st.last_seq or st.waiting or sources_done):
                stuck.append(f"{n} after frame {st.last_seq}" + (f" ({st.waiting})" if st.waiting else ""))
        if stuck:
            self.stall = (f"stalled: no progress for {self.stall_timeout:.0f} s while the source is at frame {src}: "
                          + "; ".join(stuck))
            raise _Stalled(self.stall)

    def request_stop(self) -> None:
        """Ask the run to stop (what SIGINT / SIGTERM do)."""
        self._interrupt.set()

    def run(self) -> LaunchResult:
        plan = self.plan
        gateway = host_gateway(self.zenoh, bool(self.hosts))
        if gateway is not None:  # this host's stages reach the others through the launcher
            self.zenoh = gateway
        node_settings = ZenohSettings(mode=self.zenoh.mode if self.zenoh.mode != "router" else "peer",
                                      listen=node_listen(self.zenoh) if self.zenoh.mode != "client" else (),
                                      # a client launcher listens nowhere: its stages go to the router only
                                      # (not to whatever else may listen on the launcher's would-be port)
                                      connect=tuple(e.replace("0.0.0.0", "127.0.0.1") for e in self.zenoh.listen
                                                    if not e.endswith(":0") and self.zenoh.mode != "client")
                                      + (tuple(self.zenoh.connect) if gateway is None else ()),
                                      multicast=self.zenoh.multicast, shm_pool_mb=self.zenoh.shm_pool_mb,
                                      security=self.zenoh.security)
        plan.zenoh = node_settings.to_json()
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
                busy = stream_in_use(session, plan.stream, self.local)
                if busy:
                    session.close()
                    raise RuntimeError(busy)
            watch = HostWatch(session, plan, self.local, self._print)
            bus.subscribe(f"gflow/{plan.stream}/_status/*", self._on_status)
            bus.subscribe(plan.error_topic, self._on_error)
            for sp in plan.stages.values():
                if "estimate" in sp.outputs and sp.kind != "recorder":
                    bus.subscribe(sp.outputs["estimate"], self._on_estimate, with_type=True)
            self.run_dir = tempfile.mkdtemp(prefix="gflow-run-", dir=run_dir_parent())
            os.makedirs(os.path.join(self.run_dir, "state"))
            plan_file = os.path.join(self.run_dir, "plan.json")
            Path(plan_file).write_text(plan.to_json())
        except BaseException:
            if signals is not None:
                signals.close()
            raise

        t0 = time.monotonic()
        recorder = [n for n, s in plan.stages.items() if s.kind == "recorder" and n in self.local]
        workers = [n for n in plan.stages if n not in recorder and n in self.local]
        # stages on other hosts: a local recorder keeps recording until they are all finished
        remote = [n for n in plan.stages if n not in self.local and plan.stages[n].kind != "recorder"]
        ok = True
        try:
            # the stage processes fork from the zygote the gflow command started first, when there is one
            self._zygote = take() if self.threads_per_stage == 1 else None
            try:
                for n in recorder + workers:
                    self.procs[n] = self._spawn(n, plan_file)
                    mark(f"launcher spawned {n} {self.procs[n].popen.pid}")
            finally:
                self._close_zygote()  # restarts start `python -m pipeline.runtime.node`
            if recorder and self.recording:
                self._print(f"recording to {self.recording}")
            # wait for every heartbeat, then tell the sources to start
            while True:
                with self._lock:
                    seen = set(self.status)
                if seen >= set(plan.stages):
                    break
                dead = [n for n, p in self.procs.items() if p.popen.poll() is not None]
                if dead:
                    for n in dead:
                        self._record_exit(n)
                    raise RuntimeError("stage(s) exited during start-up: " + "; ".join(
                        f"{n} (exit {self.procs[n].popen.returncode}): {self.procs[n].last_error() or 'no message'}"
                        for n in dead))
                if self._interrupt.is_set():
                    raise KeyboardInterrupt
                missing = [n for n in plan.stages if n not in seen]
                watch.waiting_for(missing, time.monotonic() - t0)
                if time.monotonic() - t0 > self.startup_timeout:
                    raise RuntimeError(f"no heartbeat from {describe_hosts(plan, missing)} after "
                                       f"{self.startup_timeout:.0f} s")
                time.sleep(0.02)
            mark("launcher heard all")
            start = encode(Control(header=Header(plan.stream, 0, time.time_ns()), command="start"))
            bus.publish(plan.control_topic, start, 0)
            mark("launcher start sent")
            last_print = last_start = time.monotonic()
            while True:
                if self._interrupt.is_set():
                    raise KeyboardInterrupt
                now = time.monotonic()
                if now - last_start > 0.5 and any(self.status.get(n) and self.status[n].state == "ready"
                                                   for n in workers if plan.stages[n].is_source()):
                    bus.publish(plan.control_topic, start, 0)  # a source missed the first start
                    last_start = now
                running = False
                for n in recorder + workers:
                    p = self.procs[n]
                    rc = p.popen.poll()
                    if rc is None:
                        running = running or n in workers
                        continue
                    if n in self.exits:
                        continue
                    if rc != 0 or n in recorder:
                        sp = plan.stages[n]
                        self._print(f"stage {n} died with exit status {rc}: {p.last_error() or 'no message'}")
                        if n in recorder and rc == EXIT_DISK_FULL:
                            ok = False
                            self._record_exit(n)
                            self._print(f"stopping the pipeline: the recording's disk is full ({p.last_error()})")
                            raise _StageLost(n)
                        if sp.restart == "on-failure" and p.restarts < sp.max_restarts:
                            self._print(f"restarting {n} ({p.restarts + 1}/{sp.max_restarts})"
                                        + (f": recording the rest to {segment_path(self.recording, p.restarts + 1)}"
                                           if n in recorder and self.recording else ""))
                            new = self._spawn(n, plan_file, p.restarts + 1)
                            new.restarts = p.restarts + 1
                            self.procs[n] = new
                            running = True
                            continue
                        ok = False
                        self._record_exit(n)
                        # the graph cannot go on without it: stop the others cleanly
                        self._print(f"stopping the pipeline: {n} is not restarted (restart: {sp.restart})")
                        raise _StageLost(n)
                    self._record_exit(n)
                self._check_stall(workers, now)
                with self._lock:
                    states = {n: st.state for n, st in self.status.items()}
                if watch.check(states):  # a host of the graph is gone and the graph says stop
                    ok = False
                    raise _StageLost(watch.lost_report)
                if recorder and any(states.get(n) not in ("done", "stopped") for n in remote):
                    running = True  # the local recorder records until the other hosts have finished
                if recorder and not workers and not remote and not self._external_ended(recorder[0]):
                    running = True  # a graph fed from outside only: record until each of its ends
                if self.on_status is not None:
                    with self._lock:
                        self.on_status(dict(self.status))
                if self.progress and now - last_print >= 1.0:
                    line = self._progress_line()
                    if self.out.isatty():
                        self.out.write("\r\033[K" + line[: os.get_terminal_size(self.out.fileno()).columns - 1])
                    else:
                        self.out.write(line + "\n")
                    self.out.flush()
                    last_print = now
                if not running:
                    break
                time.sleep(0.05)
            interrupted = False
        except (KeyboardInterrupt, _StageLost, _Stalled) as e:
            interrupted = isinstance(e, KeyboardInterrupt)
            ok = ok and interrupted
            if interrupted:
                self._print("stopping: asking every stage to finish")
            if isinstance(e, _Stalled):
                ok = False
                self._print(f"{e}; stopping the pipeline")
            self._signal_all(workers, signal.SIGINT)
            if not self._wait(workers, 10.0):
                self._signal_all(workers, signal.SIGKILL)
        except Exception:
            interrupted = True
            self._signal_all(workers, signal.SIGINT)
            self._wait(workers, 5.0)
            self._signal_all(workers, signal.SIGKILL)
            raise
        finally:
            # the recorder goes last, so it keeps everything the stages sent
            if recorder:
                bus.publish(plan.control_topic, encode(Control(header=Header(plan.stream, 0, time.time_ns()),
                                                               command="stop")), 0)
                if not self._wait(recorder, 10.0):
                    self._signal_all(recorder, signal.SIGINT)
                    if not self._wait(recorder, 10.0):
                        self._signal_all(recorder, signal.SIGKILL)
            for n in self.procs:
                if n not in self.exits and self.procs[n].popen.poll() is not None:
                    self._record_exit(n)
            if self.progress and self.out.isatty():
                self.out.write("\n")
            session.close()
            shutil.rmtree(self.run_dir, ignore_errors=True)
            if signals is not None:
                signals.close()
        ok = ok and all(e.returncode == 0 for e in self.exits.values()) and not watch.lost
        return LaunchResult(ok=ok and not interrupted, seconds=time.monotonic() - t0, recording=self.recording if recorder else None,
                            status=dict(self.status), exits=dict(self.exits), errors=list(self.errors),
                            pids=dict(self.pids), interrupted=interrupted, peak_rss_mb=dict(self.peak_rss),
                            stall=self.stall, estimates=dict(self.estimates))

    def _external_ended(self, recorder: str) -> bool:
        """Whether the recorder has recorded the end of stream of every external topic it keeps."""
        from pipeline.runtime.drain import recorder_needs

        with self._lock:
            st = self.status.get(recorder)
        _, need = recorder_needs(self.plan, self.plan.external)
        return st is not None and need <= set(st.ended)

    def _record_exit(self, n: str) -> None:
        p = self.procs[n]
        p.reader.join(timeout=1.0)
        self.exits[n] = StageExit(n, p.popen.returncode if p.popen.returncode is not None else -1,
                                  p.last_error(), p.restarts)
