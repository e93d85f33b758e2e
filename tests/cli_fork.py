"""``gflow ARGS`` in a process of its own, forked from one that has already imported the command line.

A ``gflow`` command that only finds a mistake spends nearly all of its CPU (about 0.4 s on a 2-core test
machine) on starting Python and importing numpy and the command's module; the suite runs hundreds of them. Here
one *server* process per test process imports ``pipeline.cli.main``, numpy and every command's module once, and
forks a child for each command. The child is what ``python -m pipeline.cli.main ARGS`` would be after its imports:
it takes the request's working folder and environment, its stdin is /dev/null or the request's text, its stdout
and stderr are files,
it forks the stage zygote and binds an early UDP port as the command does at start-up, runs
:func:`pipeline.cli.main.main`, runs the exit handlers and exits with the command's status (an exception that
escapes ``main`` prints its traceback and exits 1, as the interpreter does).

The server also imports what a launching command's stage zygote imports (``pipeline.runtime.node``: zenoh, msgspec,
the runtime; pipeline/runtime/zygote.py), which starts no thread with BLAS held to one, so that zygote, forked from
the child, starts warm. What the server never imports (OpenCV starts a thread at import, and a process with threads
must not fork) the child imports as the command does. :func:`run` falls back to a new interpreter where the fork
server cannot stand in (not Linux, or ``GFLOW_TEST_FORK=0``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

SERVER = r"""
import json, os, sys, traceback
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # numpy's BLAS starts no thread here
    os.environ.setdefault(var, "1")
import pipeline.cli.main as cli_main
import numpy  # noqa: F401
from pipeline.cli.commands import command_modules
command_modules()  # every command's module (they import neither OpenCV nor zenoh at their top)
import pipeline.runtime.node  # noqa: F401  (what a command's stage zygote imports: zenoh, msgspec, the runtime)
assert len(os.listdir("/proc/self/task")) == 1, "the fork server has threads"
reply = os.fdopen(int(sys.argv[1]), "w", buffering=1)
for line in sys.stdin:
    req = json.loads(line)
    pid = os.fork()
    if pid == 0:
        rc = 1
        try:
            os.chdir(req["cwd"])
            os.environ.clear()
            os.environ.update(req["env"])
            import tempfile
            tempfile.tempdir = None  # found again from the request's TMPDIR
            cli_main.hold()
            os.dup2(os.open(req["in"] or os.devnull, os.O_RDONLY), 0)
            os.dup2(os.open(req["out"], os.O_WRONLY | os.O_TRUNC), 1)
            os.dup2(os.open(req["err"], os.O_WRONLY | os.O_TRUNC), 2)
            reply.close()
            sys.argv = [cli_main.__file__, *req["argv"]]
            cli_main.start_early(req["argv"])
            from pipeline.io.udp_relay import bind_early
            bind_early(req["argv"])
            try:
                code = cli_main.main(req["argv"])
            except SystemExit as e:
                code = e.code
            if code is None:
                rc = 0
            elif isinstance(code, int):
                rc = code
            else:
                print(code, file=sys.stderr)
                rc = 1
        except BaseException:
            traceback.print_exc()
            rc = 1
        try:
            import atexit
            atexit._run_exitfuncs()
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(rc & 0xFF)
    reply.write(json.dumps({"pid": pid}) + "\n")
    _, status = os.waitpid(pid, 0)
    reply.write(json.dumps({"rc": os.waitstatus_to_exitcode(status)}) + "\n")
"""


class _Server:
    def __init__(self) -> None:
        r, w = os.pipe()
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen([sys.executable, "-c", SERVER, str(w)], stdin=subprocess.PIPE, text=True,
                                     env=env, pass_fds=(w,), stdout=subprocess.DEVNULL, cwd=ROOT)
        os.close(w)
        self.replies = r
        self.pending = b""
        self.lock = threading.Lock()

    def run(self, argv: list[str], cwd: Path, env: dict[str, str], timeout: float,
            input: str | None) -> subprocess.CompletedProcess:
        with tempfile.TemporaryDirectory(prefix="gflow-fork-") as d, self.lock:
            out, err, inp = Path(d) / "out", Path(d) / "err", Path(d) / "in"
            out.touch()
            err.touch()
            if input is not None:
                inp.write_text(input)
            req = {"argv": argv, "cwd": str(cwd), "env": env, "out": str(out), "err": str(err),
                   "in": str(inp) if input is not None else None}
            assert self.proc.stdin is not None
            self.proc.stdin.write(json.dumps(req) + "\n")
            self.proc.stdin.flush()
            pid = json.loads(self._reply(30.0))["pid"]
            try:
                rc = json.loads(self._reply(timeout))["rc"]
            except subprocess.TimeoutExpired:
                os.kill(pid, signal.SIGKILL)
                self._reply(30.0)
                raise subprocess.TimeoutExpired(["gflow", *argv], timeout, out.read_text(), err.read_text())
            return subprocess.CompletedProcess(["gflow", *argv], rc, out.read_text(errors="replace"),
                                               err.read_text(errors="replace"))

    def _reply(self, timeout: float) -> str:
        """The server's next line, waited for up to ``timeout`` s."""
        import select
        import time

        end = time.monotonic() + timeout
        while b"\n" not in self.pending:
            ready, _, _ = select.select([self.replies], [], [], max(0.0, end - time.monotonic()))
            if not ready:
                raise subprocess.TimeoutExpired("gflow fork server", timeout)
            chunk = os.read(self.replies, 4096)
            if not chunk:
                raise RuntimeError(f"the gflow fork server exited ({self.proc.poll()})")
            self.pending += chunk
        line, self.pending = self.pending.split(b"\n", 1)
        return line.decode()

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            self.proc.wait(30)
        os.close(self.replies)


_SERVER: _Server | None = None


def usable() -> bool:
    """Whether commands fork from the server here (Linux, and not turned off with ``GFLOW_TEST_FORK=0``)."""
    return sys.platform.startswith("linux") and os.environ.get("GFLOW_TEST_FORK", "1") != "0"


def _same_path(env: dict[str, str]) -> bool:
    """Whether ``env``'s PYTHONPATH names only what the server's does (this checkout, this process's PYTHONPATH): a
    command given a folder of its own to import from (a tracker of the user's) needs a new interpreter."""
    have = {str(ROOT), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))}
    return {str(Path(p).resolve()) if p else "" for p in env.get("PYTHONPATH", "").split(os.pathsep)} - {""} <= {
        str(Path(p).resolve()) for p in have}


def run(argv: list[str], cwd: Path, env: dict[str, str] | None = None, timeout: float = 60.0,
        input: str | None = None) -> subprocess.CompletedProcess:
    """``gflow ARGV`` in ``cwd`` with environment ``env`` (default: this process's) and ``input`` on its stdin
    (None: /dev/null): its exit status, stdout and stderr as text (``subprocess.run(..., capture_output=True,
    text=True)``'s result)."""
    global _SERVER
    env = dict(os.environ if env is None else env)
    if not usable() or not _same_path(env):
        env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
        return subprocess.run([sys.executable, "-m", "pipeline.cli.main", *argv], cwd=cwd, env=env, input=input,
                              capture_output=True, text=True, timeout=timeout,
                              stdin=subprocess.DEVNULL if input is None else None)
    if _SERVER is None or _SERVER.proc.poll() is not None:
        _SERVER = _Server()
    return _SERVER.run(list(argv), Path(cwd), env, timeout, input)


def close() -> None:
    """Stop the server (the test session's end)."""
    global _SERVER
    if _SERVER is not None:
        _SERVER.close()
        _SERVER = None


def run_command(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, capture_output=True, text=True, ...)`` for ``cmd`` = ``[python, -m, pipeline.cli.main,
    ARGS...]`` (or ``pipeline.cli``), forked as :func:`run` does; any other command, or options :func:`run` does
    not stand in for, go to ``subprocess.run`` unchanged."""
    cli = len(cmd) >= 3 and cmd[0] == sys.executable and cmd[1] == "-m" and cmd[2] in ("pipeline.cli.main",
                                                                                        "pipeline.cli")
    plain = kw.get("capture_output") is True and kw.get("text") is True and kw.get("stdin", subprocess.DEVNULL) in (
        subprocess.DEVNULL, None) and set(kw) <= {"capture_output", "text", "timeout", "env", "cwd", "input", "stdin"}
    if not (cli and plain) or (kw.get("stdin") is None and "stdin" in kw and kw.get("input") is None):
        return subprocess.run(cmd, **kw)
    return run(cmd[3:], cwd=Path(kw.get("cwd") or os.getcwd()), env=kw.get("env"), timeout=kw.get("timeout") or 600.0,
               input=kw.get("input"))
