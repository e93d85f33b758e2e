"""SIGINT / SIGTERM / SIGHUP are taken on a thread of their own (pipeline/runtime/signals.py), never by a
Python handler that sets an Event: such a handler runs on the main thread, and deadlocks when the
signal lands while the main thread holds that Event's lock. Each test makes exactly that happen:
the Event of the launcher, of ``gflow router`` or of the helper itself sends the signal to its own
process while its lock is held; the process must still stop cleanly, where a handler hangs for good."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import psutil
import pytest

from pipeline.runtime.transport import free_port

ROOT = Path(__file__).resolve().parent.parent

#: ``threading.Event`` replaced, in the process under test, by one that (created in MODULES, the
#: first time the main thread looks at it) sends SIG to its own process while holding its lock
HOLDING_EVENT = textwrap.dedent("""
    import os, signal, sys, threading

    class HoldingEvent(threading.Event):
        armed = True

        def __init__(self):
            super().__init__()
            self.watched = sys._getframe(1).f_globals.get("__name__") in MODULES

        def _hold(self):
            if self.watched and HoldingEvent.armed and threading.current_thread() is threading.main_thread():
                HoldingEvent.armed = False
                with self._cond:
                    os.kill(os.getpid(), SIG)
                    sum(range(100000))  # bytecodes: a Python signal handler would run here, lock held

        def is_set(self):
            self._hold()
            return super().is_set()

        def wait(self, timeout=None):
            self._hold()
            return super().wait(timeout)

    threading.Event = HoldingEvent
""")


def _run(code: str, modules: tuple[str, ...], sig: int, timeout: float = 60) -> subprocess.CompletedProcess:
    prelude = f"MODULES = {modules!r}\nSIG = {int(sig)}\n" + HOLDING_EVENT
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.Popen([sys.executable, "-c", prelude + textwrap.dedent(code)], cwd=ROOT, env=env, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        kids = psutil.Process(p.pid).children(recursive=True)
        p.kill()
        for k in kids:
            k.kill()
        out, err = p.communicate()
        pytest.fail(f"hung with the signal taken while the Event's lock was held (deadlock); stderr: {err[-800:]}")
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def test_the_helper_takes_a_signal_while_the_event_lock_is_held():
    r = _run("""
        from pipeline.runtime.signals import StopSignals
        stop = threading.Event()
        signals = StopSignals(lambda s: stop.set()).start()
        assert stop.wait(30), "the signal never reached the callback"
        signals.close()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers restored
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
        assert signal.set_wakeup_fd(-1) == -1  # and the wakeup fd
        print("ok")
    """, ("__main__",), signal.SIGINT, timeout=30)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_gflow_router_stops_on_sigterm_while_waiting():
    """The main thread waits on the stop Event without a timeout; the signal lands on whichever
    thread the kernel picks (numpy's and OpenCV's threads take signals too)."""
    p = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "router", "--listen", f"tcp/127.0.0.1:{free_port()}"],
                         cwd=ROOT, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")))
    try:
        assert "listening on" in p.stderr.readline()
        p.send_signal(signal.SIGTERM)
        assert p.wait(30) == 0
        assert p.stderr.read().strip().splitlines()[-1] == "gflow router: stopped"
    finally:
        if p.poll() is None:
            p.kill()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_gflow_router_stops_on_a_signal_that_lands_on_the_held_lock(sig):
    r = _run(f"""
        from pipeline.cli.main import main
        sys.exit(main(["router", "--listen", "tcp/127.0.0.1:{free_port()}"]))
    """, ("pipeline.cli.commands.router",), sig)
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip().splitlines()[-1] == "gflow router: stopped", r.stderr


def test_the_launcher_stops_on_a_signal_that_lands_on_the_held_lock(tmp_path):
    rec = tmp_path / "run.mcap"
    r = _run(f"""
        from pipeline.cli.main import main
        sys.exit(main(["run", "demo", "--set", "source.frames=200", "--set", "filter.particles=50",
                       "--record", {str(rec)!r}, "--listen", "tcp/127.0.0.1:0"]))
    """, ("pipeline.runtime.launcher",), signal.SIGINT, timeout=90)
    assert r.returncode == 130, r.stderr
    assert "interrupted" in r.stderr and "Traceback" not in r.stderr, r.stderr
