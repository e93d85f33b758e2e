"""The live tools find a running pipeline by themselves: the launcher announces its endpoint in
the runtime folder; ``gflow ps / topics / echo / hz / pub`` use it without ``--connect``, and
say so (non-zero exit) when nothing runs. A real ``gflow run`` on loopback, real subprocesses;
every wait is for a condition."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import cli_fork
from pipeline.cli.live import rate_stats

ROOT = Path(__file__).resolve().parent.parent


def _env(rt: Path) -> dict:
    return dict(os.environ, GFLOW_RUNTIME_DIR=str(rt),
                PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _gflow(rt: Path, *args: str, timeout: float = 90) -> subprocess.CompletedProcess:
    """``gflow ARGS`` run to its end with runtime folder ``rt`` (forked from a process that has imported the
    command line: tests/cli_fork.py)."""
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args], env=_env(rt),
                                capture_output=True, text=True, timeout=timeout)


def _wait(cond, what: str, timeout: float = 60.0):
    end = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.1)


@pytest.fixture()
def pipeline(tmp_path: Path):
    """A demo pipeline playing in real time (long enough to outlast the test), stopped at the end."""
    rt = tmp_path / "runtime"
    rec = tmp_path / "run.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "run", "demo", "--set", "source.realtime=true",
                             "--set", "source.fps=20", "--set", "source.frames=3000", "--set", "filter.particles=100",
                             "--record", str(rec), "--listen", "tcp/127.0.0.1:0", "--stream", "demo"],
                            env=_env(rt), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        files = _wait(lambda: list(rt.glob("*.json")) if rt.is_dir() else [], "the launcher's announcement")
        info = json.loads(files[0].read_text())
        yield proc, rt, info, rec
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)


def test_tools_find_the_running_pipeline(pipeline) -> None:
    proc, rt, info, rec = pipeline
    assert info["stream"] == "demo" and info["pid"] == proc.pid
    assert "source" in info["stages"] and info["endpoints"][0].startswith("tcp/127.0.0.1:")

    # ps: every stage's state from its heartbeat, once the source plays
    def running() -> str | None:
        r = _gflow(rt, "ps")
        src = [ln for ln in r.stdout.splitlines() if ln.strip().startswith("source ")]
        return r.stdout if r.returncode == 0 and src and " running " in src[0] else None

    out = _wait(running, "gflow ps to show the source running")
    assert f"pid {proc.pid}" in out and "filter" in out and "recorder" in out
    # ps listens until every stage of the announcement has been heard, not for all of --listen-for
    t = time.monotonic()
    ps = json.loads(_gflow(rt, "ps", "--json", "--listen-for", "30").stdout)
    assert time.monotonic() - t < 20, "gflow ps listened for all of --listen-for though every stage beat"
    assert ps[0]["pid"] == proc.pid and ps[0]["states"]["filter"]["state"] in ("running", "ready")
    assert set(ps[0]["states"]) == set(info["stages"])

    # each tool listens as long as its assertion needs: topics from the first message, hz to its first report
    topics = _gflow(rt, "topics", "--duration", "1")
    assert topics.returncode == 0, topics.stderr
    assert "gflow/demo/estimate" in topics.stdout and "Estimate" in topics.stdout and "KiB/s" in topics.stdout
    tj = json.loads(_gflow(rt, "topics", "--duration", "1", "--json").stdout)
    assert tj["gflow/demo/frames"]["type"] == "Frame" and tj["gflow/demo/frames"]["bytes_per_s"] > 0

    echo = _gflow(rt, "echo", "gflow/demo/estimate", "-n", "2", "--timeout", "30")
    assert echo.returncode == 0, echo.stderr
    assert len([ln for ln in echo.stdout.splitlines() if ln.startswith("gflow/demo/estimate: Estimate seq=")]) == 2

    js = _gflow(rt, "echo", "demo/estimate", "-n", "1", "--json", "--timeout", "30")
    assert js.returncode == 0, js.stderr
    obj = json.loads(js.stdout.splitlines()[0])
    msg = obj["message"]
    assert obj["topic"] == "gflow/demo/estimate" and msg["type"] == "Estimate"
    assert len(msg["box"]) == 4 and msg["header"]["stream"] == "demo" and msg["n"] == 100

    hz = _gflow(rt, "hz", "gflow/demo/frames", "--duration", "1.5")
    assert hz.returncode == 0, hz.stderr
    lines = [ln for ln in hz.stdout.splitlines() if "average rate" in ln]
    assert lines, hz.stdout
    rate = float(lines[-1].split("average rate ")[1].split(" Hz")[0])
    assert 1 < rate < 60, lines[-1]  # 20 fps in real time: never above; loose below for a busy machine
    assert "std dev" in lines[-1] and "min" in lines[-1] and "max" in lines[-1]

    silent = _gflow(rt, "echo", "gflow/demo/no_such_topic", "--timeout", "1")
    assert silent.returncode == 1 and "no message on gflow/demo/no_such_topic" in silent.stderr

    # pub: the control topic; the launcher passes the stop on, the sources stop and the run ends by itself
    pub = _gflow(rt, "pub", "gflow/demo/_control", "Control", '{"command": "stop"}')
    assert pub.returncode == 0, pub.stderr
    proc.wait(60)
    assert not list(rt.glob("*.json")), "the announcement must be removed when the launcher exits"
    _, err = proc.communicate()
    assert "listening on tcp/127.0.0.1:" in err
    # the launcher passed the stop on to every stage (the tool may not have linked to them all yet)
    assert "stop received on the control topic" in err, err

    nothing = _gflow(rt, "topics", "--duration", "1")
    assert nothing.returncode == 2 and "no running gflow pipeline" in nothing.stderr
    assert _gflow(rt, "ps").returncode == 1


def test_a_stale_announcement_is_ignored(tmp_path: Path) -> None:
    rt = tmp_path / "rt"
    rt.mkdir()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (rt / "demo-1.json").write_text(json.dumps({"stream": "demo", "pid": int(dead.stdout), "endpoints": []}))
    r = _gflow(rt, "echo", "gflow/demo/estimate", "--timeout", "1")  # waited for, in vain: an answer, exit 1
    assert r.returncode == 1 and "no running gflow pipeline with stream 'demo'" in r.stderr
    assert not (rt / "demo-1.json").exists()


def test_rate_stats() -> None:
    st = rate_stats([0.0, 0.1, 0.2, 0.4])
    assert st is not None and st.window == 3
    assert st.rate_hz == pytest.approx(1 / (0.4 / 3)) and st.min_ms == pytest.approx(100) and st.max_ms == pytest.approx(200)
    last2 = rate_stats([0.0, 0.1, 0.2, 0.4], window=1)
    assert last2.rate_hz == pytest.approx(5.0) and last2.std_ms == pytest.approx(0.0)
    assert rate_stats([1.0]) is None


def test_a_replay_is_found_without_a_launcher(tmp_path: Path) -> None:
    rt = tmp_path / "rt"
    rec = tmp_path / "r.mcap"
    r = _gflow(rt, "run", "demo", "--inline", "--set", "source.frames=10", "--record", str(rec))
    assert r.returncode == 0, r.stderr
    rp = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "replay", str(rec), "--loop", "0", "--speed", "1"],
                          env=_env(rt), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        files = _wait(lambda: list(rt.glob("*.json")) if rt.is_dir() else [], "the replay's announcement")
        assert json.loads(files[0].read_text())["kind"] == "replay"
        echo = _gflow(rt, "echo", "gflow/demo/estimate", "-n", "1", "--timeout", "30")
        assert echo.returncode == 0 and "Estimate seq=" in echo.stdout, echo.stderr
    finally:
        rp.send_signal(signal.SIGINT)  # Ctrl-C: the replay stops and removes its announcement
        rp.wait(30)
    assert not list(rt.glob("*.json"))


def test_ps_says_a_no_record_run_is_not_recording(tmp_path: Path) -> None:
    """A --no-record run reads its results from a temporary file; gflow ps does not call it a recording."""
    rt = tmp_path / "runtime"
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "demo", "--no-record", "--frames", "3000",
                             "--particles", "50", "--listen", "tcp/127.0.0.1:0", "--stream", "norec"],
                            env=_env(rt), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True)
    try:
        files = _wait(lambda: list(rt.glob("*.json")) if rt.is_dir() else [], "the launcher's announcement")
        info = json.loads(files[0].read_text())
        assert info["pid"] == proc.pid and info["recording"] is None and info["no_record"] is True, info
        r = _gflow(rt, "ps", "--listen-for", "0.2")
        assert r.returncode == 0, r.stderr
        line = next(ln for ln in r.stdout.splitlines() if f"pid {proc.pid}" in ln)
        assert "not recording (--no-record)" in line and "gflow-norecord" not in r.stdout, r.stdout
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def test_lockstep_names_the_stages_it_heard_when_one_never_beats() -> None:
    """``gflow replay --lockstep nosuch`` waited its whole --ack-timeout, then said only that nosuch never beat;
    the stages it did hear are named beside it, so a mistyped name shows."""
    from pipeline.cli.live import _Acks

    acks = _Acks()
    acks.last.update({"filter": 4, "proposal": 4})
    with pytest.raises(TimeoutError, match=r"no heartbeat from nosuch .*heard from: filter, proposal\)"):
        acks.wait(("nosuch",), -1, 0.05)
    with pytest.raises(TimeoutError, match=r"acknowledgement of frame 9 from filter .*\?\)$"):
        _Acks().wait(("filter",), 9, 0.05)
