"""Nothing outlives its launcher: SIGKILL or SIGHUP the `gflow` process mid-run; within 2 s no
process of the run is alive, the recording is readable and the run's temporary folder is gone."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from pipeline.recording.results import estimates


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


def _running(p: psutil.Process) -> bool:
    try:
        return p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGHUP])
def test_stages_die_with_the_launcher(tmp_path, sig):
    rec = tmp_path / "run.mcap"
    stream = f"faults-{os.getpid()}-{time.monotonic_ns()}"
    p = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "run", "demo", "--set", "source.realtime=true",
                          "--set", "source.frames=600", "--set", "filter.particles=100", "--record", str(rec),
                          "--listen", "tcp/127.0.0.1:0", "--stream", stream],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 90
    while not (rec.exists() and rec.stat().st_size > 64 and len(estimates(rec)) >= 10):
        assert time.monotonic() < deadline and p.poll() is None, "the pipeline did not get going"
        time.sleep(0.1)
    # the stage processes and the zygote the run leased (pipeline/runtime/zygote.py): all must go
    children = psutil.Process(p.pid).children()
    stages = [c for c in children if "pipeline.runtime.node" in " ".join(c.cmdline())]
    assert len(stages) == 6 and len(children) <= 7, [c.cmdline() for c in children]
    # every stage process is started with its node plan, RUN_DIR/nodes/NAME.json
    run_dirs = {Path(c.cmdline()[-2]).parents[1] for c in stages}
    assert len(run_dirs) == 1, run_dirs
    run_dir = str(run_dirs.pop())
    assert Path(run_dir).name.startswith("gflow-run-") and f'"stream":"{stream}"' in _read(Path(run_dir, "nodes", "filter.json"))
    assert os.path.isdir(run_dir)
    p.send_signal(sig)
    t0 = time.monotonic()
    alive = children
    while alive and time.monotonic() - t0 < 2.0:  # poll: exited, or a zombie its new parent has yet to reap
        alive = [c for c in children if _running(c)]
        time.sleep(0.02)
    assert not alive, f"still running {time.monotonic() - t0:.1f} s after the launcher's {sig.name}: {alive}"
    p.wait(timeout=30)
    # the recorder closed its file before it went: readable to the end, with its summary
    from mcap.reader import make_reader

    with open(rec, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    assert len(estimates(rec)) >= 10
    deadline = time.monotonic() + 5
    while os.path.exists(run_dir):  # removed by the last stage to go (or by the launcher on SIGHUP)
        assert time.monotonic() < deadline, f"{run_dir} was left behind"
        time.sleep(0.05)


def test_a_stalled_stage_is_named_and_the_run_stops(tmp_path):
    from pipeline.runtime.build import apply_defaults
    from pipeline.runtime.graph import load_graph
    from pipeline.runtime.launcher import Launcher
    from pipeline.runtime.transport import ZenohSettings, free_port

    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 400}, "filter": {"particles": 100}}))
    rec = tmp_path / "run.mcap"
    launcher = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=str(rec),
                        progress=False, stall_timeout=3.0)
    import threading

    result: dict = {}
    th = threading.Thread(target=lambda: result.setdefault("r", launcher.run()), daemon=True)
    th.start()
    deadline = time.monotonic() + 60
    while not (launcher.status.get("filter") and launcher.status["filter"].steps >= 10):
        assert time.monotonic() < deadline and th.is_alive(), "pipeline did not start"
        time.sleep(0.02)
    os.kill(launcher.pids["filter"][0], signal.SIGSTOP)  # alive, but makes no progress
    th.join(90)
    assert not th.is_alive(), "the launcher did not notice the stall"
    r = result["r"]
    assert not r.ok and "filter after frame" in r.stall and "no progress for 3 s" in r.stall, r.stall
    assert all(e.returncode == 0 for e in r.exits.values()), r.exits  # stopped cleanly, the filter too
    from mcap.reader import make_reader

    with open(rec, "rb") as f:
        assert make_reader(f).get_summary() is not None
