"""Stage processes forked from a warm process, so that a run pays for the interpreter and the shared
imports (numpy, msgspec, zenoh, the runtime: about 0.3 s of CPU) once, not once per stage.

The *zygote* imports what every stage process needs and then waits on a socket. The launcher asks
it for each stage (:meth:`Zygote.spawn`): the zygote forks, the fork forks the stage process and
exits, so the stage process is re-parented to the launcher's process (a child subreaper,
``PR_SET_CHILD_SUBREAPER``, while it runs): the launcher waits for it, signals its process group
and reads its stderr exactly as for a stage it started with ``python -m pipeline.runtime.node``.

Leases. A process holds at most one zygote. A run takes it with :func:`lease` and gives it back
with :func:`release` at its end, so one process runs many pipelines off one zygote (``gflow
benchmark``: every sequence, tracker and seed; the Python API: every run). A zygote that died or
failed a fork is given back *broken* and closed; the next lease starts a new one. While a lease
is held the process is a child subreaper, and the orphans of the run's stages are re-parented to
it and reaped (:func:`reap_orphans`); once it is given back they are not. One lease at a time:
a second run at the same time (another thread) starts its stages as new interpreters.

Where the zygote comes from:

* the ``gflow`` command forks it as its first act (:func:`start_early`, before its own imports),
  when its command will start stage processes (:data:`LAUNCHING`, not ``--inline``); it goes on
  with its own imports, parsing and checks meanwhile. This *early* zygote forks a stage only if
  the variables that matter at start-up (:data:`STARTUP_VARS`: ``GFLOW_*``, ``ZENOH*``,
  ``PYTHON*``, the BLAS / OpenMP thread counts...) of the environment given to the lease are
  those it was started with;
* any other process (the Python API, tests) starts one on its first lease as a new interpreter,
  ``python -m pipeline.runtime.zygote FD`` with the lease's environment, serving forks over the
  socket FD; it forks a stage only if the whole environment given to a lease equals that one.

A zygote that does not fit a lease's environment is closed and a new one started in its place.

Forking is safe here because the zygote has one thread when it forks: it forks before any zenoh
session exists in it, with BLAS limited to one thread (``OMP_NUM_THREADS`` etc., as the launcher
gives every stage), and without OpenCV (which starts a thread at import; measured: a fork of a
process that had run OpenCV and BLAS work hangs in ``cv2.setNumThreads``). Anything else -- no
zygote, a zygote that failed, a restart -- starts ``python -m pipeline.runtime.node`` as before.
``GFLOW_ZYGOTE=0`` turns it off.

A stop (SIGINT, SIGTERM, SIGHUP) may reach a stage process while it is still being born: the
launcher stops the run when the source cannot open its input, and signals each stage's process
group as soon as the group exists, which is the moment the stage calls ``setsid``. So the zygote
forks with the stop signals blocked, the stage process takes them only once its own handlers are
set, and a stage stopped before its node has started exits at once (code 130), quietly: a stop
asked for is not a fault, and the user sees the reason the run stopped, not a traceback.
"""

from __future__ import annotations

import atexit
import ctypes
import json
import os
import select
import signal
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Iterable, Mapping

__all__ = ["Zygote", "start_early", "lease", "release", "reap_orphans", "stage_environment", "ForkedStage"]

PR_SET_PDEATHSIG = 1
PR_SET_NAME = 15
PR_SET_CHILD_SUBREAPER = 36
PR_GET_CHILD_SUBREAPER = 37
#: the environment a stage process gets by default (the launcher's ``threads_per_stage`` = 1)
ONE_THREAD = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
#: the prefixes of the environment variables that the zygote's start-up (its imports) or a stage's
#: reads before its environment is set can depend on: an early zygote forks only for a lease whose
#: environment has the same ones. Not OpenCV's (the zygote never imports it) nor the loader's
#: (``LD_*``: read when a program starts, which a fork does not; importing cv2 sets LD_LIBRARY_PATH)
STARTUP_VARS = ("GFLOW_", "ZENOH", "RUST_", "PYTHON", "OMP_", "OPENBLAS_", "MKL_", "NPY_", "BLIS_",
                "VECLIB_", "NUMEXPR_", "MALLOC_")
#: the signals that stop a stage (pipeline.runtime.signals.STOP_SIGNALS, not imported here: the
#: zygote imports as little as it can before it forks)
_STOPS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: the exit code of a stage stopped before its node started (128 + SIGINT, as a shell reports it)
STOPPED_BEFORE_START = 130
#: commands of ``gflow`` that start stage processes
LAUNCHING = ("track", "run", "demo", "benchmark")

_HELD: "Zygote | None" = None  # the process's zygote while no run holds it
_LEASED = False  # whether a run holds it
_LOCK = threading.Lock()
_AT_EXIT = False


def _mark(label: str) -> None:
    """A start-up trace line (pipeline/runtime/trace.py: imports nothing but ``os`` and ``time``)."""
    from pipeline.runtime.trace import mark

    mark(label)


def _prctl(option: int, arg: int) -> bool:
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(option, arg, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def wants_stages(argv: list[str]) -> bool:
    """Whether ``gflow ARGV`` will start stage processes (a launching command, not --inline / --help)."""
    words = [a for a in argv if not a.startswith("-")]
    return (bool(words) and words[0] in LAUNCHING and not {"--inline", "-h", "--help", "--version"} & set(argv)
            and os.environ.get("GFLOW_ZYGOTE", "1") != "0")


def stage_environment(base: Mapping[str, str], threads: int) -> dict[str, str]:
    """The environment of a stage process: ``base`` (the launcher's), with ``threads`` compute
    threads per process unless it says otherwise, and this checkout first on ``PYTHONPATH``."""
    env = dict(base)
    for var in ONE_THREAD:
        env.setdefault(var, str(threads))
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _startup_part(env: Mapping[str, str]) -> dict[str, str]:
    """The variables of ``env`` that matter at start-up (:data:`STARTUP_VARS`)."""
    return {k: v for k, v in env.items() if k.startswith(STARTUP_VARS)}


def start_early(argv: list[str]) -> None:
    """Fork the zygote now if ``gflow ARGV`` will start stage processes (see the module doc)."""
    global _HELD
    if _HELD is None and not _LEASED and sys.platform.startswith("linux") and wants_stages(argv):
        _hold(Zygote.fork())


def _hold(z: "Zygote | None") -> None:
    """Keep ``z`` as the process's zygote (closed, and so waited for, when the process exits)."""
    global _HELD, _AT_EXIT
    _HELD = z
    if z is not None and not _AT_EXIT:
        atexit.register(_close_held)
        _AT_EXIT = True


def _close_held() -> None:
    global _HELD
    z, _HELD = _HELD, None
    if z is not None:
        z.close()


def held_pid() -> int | None:
    """The pid of the zygote this process holds between runs (None: none)."""
    z = _HELD
    return z.pid if z is not None else None


def preload(kinds: Iterable[str]) -> None:
    """Have the zygote held between runs import the modules of these stage kinds (while this
    process goes on), so that each stage process forks with its own stage's imports done too. A
    no-op without one (:func:`lease` preloads what it is given)."""
    z = _HELD
    if z is not None and not _LEASED:
        z.preload(kinds)


def lease(env: Mapping[str, str], kinds: Iterable[str] = ()) -> "Zygote | None":
    """The process's zygote for one run whose stage processes get ``env`` (see the module doc):
    the one held if it is alive and fits ``env``, else a new interpreter started with ``env``;
    with the modules of ``kinds`` preloaded. None: no zygote (not Linux, ``GFLOW_ZYGOTE=0``, a
    lease already held, no subreaper). Give it back with :func:`release` at the run's end."""
    global _HELD, _LEASED
    if not sys.platform.startswith("linux") or env.get("GFLOW_ZYGOTE", "1") == "0":
        return None
    with _LOCK:
        if _LEASED:
            return None
        z, _HELD = _HELD, None
        if z is not None and not (z.alive() and z.fits(env)):
            z.close()
            z = None
        if z is None:
            z = Zygote.start(env)
        if z is None:
            return None
        if not _prctl(PR_SET_CHILD_SUBREAPER, 1):  # the stage processes must come back to us
            _hold(z)
            return None
        _LEASED = True
    z.preload(kinds)
    return z


def release(z: "Zygote | None", broken: bool) -> None:
    """Give back the zygote of :func:`lease` at the end of its run; a ``broken`` one (it failed a
    fork) or a dead one is closed, and the next lease starts a new one. The process stops being a
    child subreaper."""
    global _LEASED
    if z is None:
        return
    _prctl(PR_SET_CHILD_SUBREAPER, 0)
    with _LOCK:
        _LEASED = False
        if broken or _HELD is not None or not z.alive():
            z.close()
        else:
            _hold(z)


def _children() -> list[int]:
    """The pids of this process's children (every thread's)."""
    pids: list[int] = []
    try:
        for tid in os.listdir("/proc/self/task"):
            try:
                pids += [int(p) for p in Path(f"/proc/self/task/{tid}/children").read_text().split()]
            except OSError:
                pass
    except OSError:
        pass
    return pids


def reap_orphans(sessions: Iterable[int], known: Iterable[int] = ()) -> list[int]:
    """Reap the children of this process that have exited, are none of ``known`` and belong to one
    of ``sessions`` (a run's stage processes: each is a session of its own, which its children
    keep): orphans of the run's stages, re-parented to this subreaper. Returns their pids."""
    sessions, known = set(sessions), set(known)
    reaped = []
    for pid in _children():
        if pid in known:
            continue
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z" or int(fields[3]) not in sessions:  # state, session (fields 3 and 6 of proc(5))
            continue
        try:
            if os.waitpid(pid, os.WNOHANG)[0] == pid:
                reaped.append(pid)
        except ChildProcessError:
            pass
    return reaped


class ForkedStage:
    """What the launcher holds of a stage process it did not start itself (the ``subprocess.Popen``
    calls it uses): ``pid``, ``stderr``, ``returncode``, ``poll()``, ``wait(timeout)``."""

    def __init__(self, pid: int, stderr) -> None:
        self.pid = pid
        self.stderr = stderr
        self.returncode: int | None = None
        try:
            self._pidfd = os.pidfd_open(pid)
        except (AttributeError, OSError):
            self._pidfd = -1

    def _reap(self, flags: int) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, flags)
            except ChildProcessError:
                return self.returncode
            if pid == self.pid:
                self.returncode = os.waitstatus_to_exitcode(status)
                if self._pidfd >= 0:
                    os.close(self._pidfd)
                    self._pidfd = -1
        return self.returncode

    def poll(self) -> int | None:
        return self._reap(os.WNOHANG)

    def wait(self, timeout: float | None = None) -> int | None:
        """The exit code; None when the process was reaped elsewhere before its code was read."""
        import subprocess

        if timeout is None:
            return self._reap(0)
        end = time.monotonic() + timeout
        while self.poll() is None:
            left = end - time.monotonic()
            if left <= 0:
                raise subprocess.TimeoutExpired(str(self.pid), timeout)
            if self._pidfd >= 0:
                select.select([self._pidfd], [], [], left)  # readable when the process has exited
            else:
                time.sleep(min(left, 0.01))
        return self.returncode


class Zygote:
    """A process that forks stage processes on request (see the module doc).

    env : the stage environment it was started for; whole : whether a lease must give exactly
    that environment (a new interpreter), else the variables of :data:`STARTUP_VARS` only (forked
    early, from a process whose environment may change afterwards without touching it)."""

    def __init__(self, pid: int, sock: socket.socket, env: Mapping[str, str], whole: bool, popen=None) -> None:
        self.pid = pid
        self.sock = sock
        self.env = dict(env)
        self.whole = whole
        self._popen = popen
        self._exited = False

    @classmethod
    def fork(cls) -> "Zygote | None":
        """The early zygote: a fork of this process (which must have one thread)."""
        if len(os.listdir("/proc/self/task")) != 1:  # a thread could hold a lock the fork would keep
            return None
        env = stage_environment(os.environ, 1)  # what a stage of a run of this command gets, by default
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        parent = os.getpid()
        # a Ctrl-C to the terminal's process group while the fork is made is the command's alone: held until the
        # child has left the group (in the child, a KeyboardInterrupt inside the fork's own hooks was a traceback)
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        pid = os.fork()
        if pid == 0:
            ours.close()
            code = 0
            try:
                _serve(theirs, parent, sigint_mask=mask)
            except BaseException:  # noqa: BLE001  (never back into the caller's code)
                code = 1
            os._exit(code)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # one sent meanwhile lands here, in the command's handler
        theirs.close()
        _mark(f"zygote forked {pid}")
        return cls(pid, ours, env, whole=False)

    @classmethod
    def start(cls, env: Mapping[str, str]) -> "Zygote | None":
        """A zygote in a new interpreter with environment ``env``: ``python -m pipeline.runtime.zygote FD``."""
        import subprocess

        try:
            ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        except OSError:
            return None
        try:
            popen = subprocess.Popen([sys.executable, "-m", "pipeline.runtime.zygote", str(theirs.fileno()),
                                      str(os.getpid())], env=dict(env), pass_fds=[theirs.fileno()],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        except OSError:
            ours.close()
            return None
        finally:
            theirs.close()
        _mark(f"zygote started {popen.pid}")
        return cls(popen.pid, ours, env, whole=True, popen=popen)

    def fits(self, env: Mapping[str, str]) -> bool:
        """Whether it may fork the stages of a run whose stage processes get ``env``."""
        return dict(env) == self.env if self.whole else _startup_part(env) == _startup_part(self.env)

    def alive(self) -> bool:
        """Whether the zygote process still runs (one that exited is reaped here)."""
        if self._exited:
            return False
        if self._popen is not None:
            self._exited = self._popen.poll() is not None
        else:
            try:
                self._exited = os.waitpid(self.pid, os.WNOHANG)[0] == self.pid
            except ChildProcessError:
                self._exited = True
        return not self._exited

    def preload(self, kinds) -> None:
        """Ask for the modules of these stage kinds to be imported now (no answer is waited for)."""
        req = json.dumps({"preload": sorted(set(kinds))}).encode()
        try:
            self.sock.sendall(len(req).to_bytes(4, "big") + req)
        except OSError:
            pass

    def spawn(self, plan_file: str, name: str, env: dict[str, str], stderr_fd: int, timeout: float = 30.0) -> int:
        """Start stage ``name``; its stderr goes to ``stderr_fd``. Returns its pid, once it is our child."""
        req = json.dumps({"plan": plan_file, "name": name, "env": env}).encode()
        self.sock.settimeout(timeout)
        socket.send_fds(self.sock, [len(req).to_bytes(4, "big") + req], [stderr_fd])
        line = b""
        while not line.endswith(b"\n"):
            chunk = self.sock.recv(64)
            if not chunk:
                raise OSError("the zygote is gone")
            line += chunk
        pid = int(line)
        if pid <= 0:
            raise OSError("the zygote has threads now: it does not fork")
        return pid

    def close(self) -> None:
        """End it: the zygote sees the end of its socket and exits; wait for it."""
        try:
            self.sock.close()
        finally:
            if self._popen is not None:
                self._popen.wait()
            elif not self._exited:
                try:
                    os.waitpid(self.pid, 0)
                except ChildProcessError:
                    pass
            self._exited = True


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise EOFError
        data += chunk
    return data


def _serve(sock: socket.socket, parent: int, die_with_thread: bool = True,
           sigint_mask: set[int | signal.Signals] | None = None) -> None:
    """The zygote: import what every stage needs, then fork one stage per request until the socket
    ends (when ``parent`` closes it or exits). ``die_with_thread``: killed too when the thread that
    forked it ends (``PR_SET_PDEATHSIG`` is a thread's): the early zygote's, forked by the main
    thread; not a new interpreter's, which a run's thread may start and outlive. ``sigint_mask``: the
    early zygote's, forked with SIGINT blocked, the mask to go back to once it has left the terminal's
    process group (a SIGINT sent to the group before is dropped, and Python's handler is taken back
    from the command's start-up one)."""
    try:
        os.setsid()  # out of the terminal's process group: Ctrl-C goes to the launcher, which stops the run
    except OSError:  # already a session's leader
        pass
    if sigint_mask is not None:
        ignored = signal.getsignal(signal.SIGINT) == signal.SIG_IGN  # (nohup ... &): left ignored
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a pending SIGINT, the command's, is discarded
        signal.pthread_sigmask(signal.SIG_SETMASK, sigint_mask)
        signal.signal(signal.SIGINT, signal.SIG_IGN if ignored else signal.default_int_handler)
    if die_with_thread:
        _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:
        return
    for var in ONE_THREAD:  # before numpy: BLAS starts no thread, as in every stage process
        os.environ.setdefault(var, "1")
    import pipeline.runtime.node  # noqa: F401  (numpy, msgspec, zenoh, the runtime: paid once, here)

    while True:
        try:
            msg, fds, _, _ = socket.recv_fds(sock, 4, 1)
            if not msg:
                return
            if len(msg) < 4:
                msg += _recv_exact(sock, 4 - len(msg))
            req = json.loads(_recv_exact(sock, int.from_bytes(msg, "big")))
        except (EOFError, OSError, ValueError):
            return
        if "preload" in req:
            _preload(req["preload"])
            continue
        if not fds:
            return
        if len(os.listdir("/proc/self/task")) != 1:  # a preloaded module started a thread: not safe to fork
            os.close(fds[0])
            sock.sendall(b"-1\n")
            continue
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STOPS)  # the stage takes them once it can
        pid = os.fork()
        if pid == 0:
            req["zygote"] = os.getppid()
            grandchild = os.fork()
            if grandchild == 0:
                _stage(req, fds[0], parent, sock, mask)
            sock.sendall(f"{grandchild}\n".encode())
            os._exit(0)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        os.close(fds[0])
        os.waitpid(pid, 0)  # once it has exited, its child is the launcher's


def _preload(kinds: list[str]) -> None:
    from stages.registry import get_stage_class

    for kind in kinds:
        try:
            if kind == "recorder":
                import pipeline.io.recorder  # noqa: F401  (mcap: what the recorder imports when it starts)
            else:
                get_stage_class(kind)
            if kind == "source":
                import pipeline.io.frame_readers  # noqa: F401  (the readers: what the source imports when it starts)
        except Exception:  # noqa: BLE001  (the stage process reports it, as without a zygote)
            pass


def _set_title(plan: str, name: str) -> None:
    """Show the stage process as ``python -m pipeline.runtime.node PLAN NAME`` (ps, psutil, py-spy),
    as when it is started that way: a fork would show the gflow command's line."""
    try:
        import setproctitle

        setproctitle.setproctitle(f"{sys.executable} -m pipeline.runtime.node {plan} {name}")
        # it pads the rest of the argument area with NULs, which /proc/PID/cmdline then shows as
        # empty arguments; a non-NUL last byte makes Linux show the title up to its NUL only
        stat = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        arg_end = int(stat[49 - 3])  # field 49 of proc(5); the first after the ')' is field 3
        last = ctypes.c_char.from_address(arg_end - 1)
        if last.value == b"\x00":
            last.value = b" "
    except ImportError:  # at least the short name (ps -o comm, top)
        try:
            ctypes.CDLL(None).prctl(PR_SET_NAME, f"gflow-{name}"[:15].encode(), 0, 0, 0)
        except (OSError, AttributeError):
            pass


def _stage(req: dict, stderr_fd: int, launcher: int, sock: socket.socket, mask: set | None = None) -> None:
    """The stage process: what ``python -m pipeline.runtime.node PLAN NAME`` does, in a fork.

    It starts with the stop signals blocked (:func:`_serve`) and takes them back (``mask``, the
    zygote's own signal mask) once its handlers are set; a stop that lands before its node has
    started (a ``KeyboardInterrupt`` from SIGINT) ends it with :data:`STOPPED_BEFORE_START`."""
    code = 1
    try:
        from pipeline.runtime.trace import mark

        mark("node begin")
        mark("node forked")
        mark(f"node zygote {req.get('zygote', 0)}")
        sock.close()
        os.setsid()  # its own process group, as the launcher's start_new_session
        null = os.open(os.devnull, os.O_RDWR)
        os.dup2(null, 0)
        os.dup2(null, 1)
        os.dup2(stderr_fd, 2)
        os.close(null)
        os.close(stderr_fd)
        for s in _STOPS:
            signal.signal(s, signal.SIG_DFL if s != signal.SIGINT else signal.default_int_handler)
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a stop sent meanwhile lands here
        _set_title(req["plan"], req["name"])
        os.environ.clear()
        os.environ.update(req["env"])
        deadline = time.monotonic() + 5.0
        while os.getppid() != launcher and time.monotonic() < deadline:  # re-parented when the middle fork exits
            time.sleep(0.0005)
        sys.argv = ["pipeline.runtime.node", req["plan"], req["name"]]
        from pipeline.runtime.node import main

        code = main([req["plan"], req["name"]])
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    except KeyboardInterrupt:  # stopped before the node took its signals: asked for, not a fault
        code = STOPPED_BEFORE_START
    except BaseException:  # noqa: BLE001  (as the interpreter would: the traceback on stderr, exit 1)
        import traceback

        traceback.print_exc()
        code = 1
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def main(argv: list[str]) -> int:
    """``python -m pipeline.runtime.zygote FD [PARENT]``: serve forks over the socket FD (for the
    process PARENT, by default the one that started it) until the socket ends."""
    try:
        sock = socket.socket(fileno=int(argv[0]))
        parent = int(argv[1]) if len(argv) > 1 else os.getppid()
    except (IndexError, ValueError, OSError):
        print("usage: python -m pipeline.runtime.zygote FD [PARENT]", file=sys.stderr)
        return 2
    try:
        _serve(sock, parent, die_with_thread=False)
    except Exception:  # noqa: BLE001  (the launcher sees the socket end and starts stages itself)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
