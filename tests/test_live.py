"""Supervision (a stage killed mid-run), live inspection (topics / echo / hz) and replay,
against a real multi-process pipeline on loopback."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

import cli_fork

from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import parse_graph
from pipeline.runtime.launcher import Launcher
from pipeline.io.mcap_io import iter_records
from pipeline.recording.results import estimates
from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session

DEMO = (Path(__file__).resolve().parent.parent / "pipeline" / "graphs" / "demo.yaml").read_text()


def _start(tmp_path, frames=60, fps=30, graph=DEMO):
    plan = apply_defaults(parse_graph(graph, "demo.yaml", overrides={
        "source": {"frames": frames, "realtime": True, "fps": fps}, "filter": {"particles": 200}}))
    port = free_port()
    rec = tmp_path / "run.mcap"
    launcher = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)), recording=str(rec),
                        progress=False)
    result: dict = {}
    th = threading.Thread(target=lambda: result.setdefault("r", launcher.run()), daemon=True)
    th.start()
    deadline = time.monotonic() + 60
    while not (launcher.status.get("source") and launcher.status["source"].state == "running"):
        assert time.monotonic() < deadline, "pipeline did not start"
        time.sleep(0.02)
    return launcher, th, result, port, rec


def _wait_steps(launcher, stage, n, timeout=30):
    deadline = time.monotonic() + timeout
    while not (launcher.status.get(stage) and launcher.status[stage].steps >= n):
        assert time.monotonic() < deadline, f"{stage} did not reach {n} steps"
        time.sleep(0.02)


def test_a_killed_stage_is_reported_and_restarted(tmp_path):
    assert "restart: on-failure" in DEMO.split("preprocess:")[1].split("proposal:")[0]  # the shipped graph restarts it
    launcher, th, result, _, rec = _start(tmp_path, frames=90)
    _wait_steps(launcher, "preprocess", 20)
    os.kill(launcher.pids["preprocess"][0], signal.SIGKILL)
    th.join(120)
    r = result["r"]
    assert r.ok, r.exits
    assert len(r.pids["preprocess"]) == 2 and r.exits["preprocess"].restarts == 1
    est = estimates(rec)
    # the restarted stage took the frames it missed from the recording: every frame was tracked
    assert sorted(est) == list(range(90)) and est[89].state == "track"


def test_a_stage_that_dies_for_good_stops_the_run_and_the_recording_closes(tmp_path, capsys):
    graph = DEMO.replace("kind: particle.proposal\n    restart: on-failure", "kind: particle.proposal\n    restart: never")
    assert graph != DEMO
    launcher, th, result, _, rec = _start(tmp_path, frames=300, graph=graph)
    _wait_steps(launcher, "proposal", 10)
    os.kill(launcher.pids["proposal"][0], signal.SIGKILL)
    th.join(120)
    assert not th.is_alive(), "the launcher hung after a stage died"
    r = result["r"]
    assert not r.ok and r.exits["proposal"].returncode == -signal.SIGKILL
    with open(rec, "rb") as f:  # closed properly: the summary is there
        assert make_reader(f).get_summary() is not None


def test_topics_echo_hz_and_replay(tmp_path, gflow_cmd):
    # long enough to outlast the tools on a busy machine; stopped when they are done
    launcher, th, result, port, rec = _start(tmp_path, frames=3000)
    conn = ["--connect", f"tcp/127.0.0.1:{port}"]
    # each tool listens as long as its assertion needs: topics from the first message, hz to its first report
    topics = cli_fork.run_command([*gflow_cmd, "topics", "--duration", "1", *conn], capture_output=True, text=True,
                                  timeout=60)
    assert "gflow/demo/features" in topics.stdout and "Features" in topics.stdout, topics.stdout
    echo = cli_fork.run_command([*gflow_cmd, "echo", "gflow/demo/estimate", "-n", "3", "--timeout", "20", *conn],
                                capture_output=True, text=True, timeout=60)
    assert echo.returncode == 0, echo.stderr
    lines = [ln for ln in echo.stdout.splitlines() if ln.startswith("gflow/demo/estimate: Estimate seq=")]
    assert len(lines) == 3, echo.stdout
    hz = cli_fork.run_command([*gflow_cmd, "hz", "gflow/demo/frames", "--duration", "1.5", *conn],
                              capture_output=True, text=True, timeout=60)
    assert hz.returncode == 0 and "average rate" in hz.stdout, hz.stdout + hz.stderr
    rate = float(hz.stdout.splitlines()[-1].split("average rate ")[1].split(" Hz")[0])
    assert 2 < rate < 60  # the source plays at 30 fps in real time: never above; loose below for a busy machine
    launcher.request_stop()
    th.join(120)
    r = result["r"]
    assert r.interrupted and all(e.returncode == 0 for e in r.exits.values()), r.exits
    with open(rec, "rb") as f:  # stopped cleanly: the recording is closed
        assert make_reader(f).get_summary() is not None

    # replay the recording on a fresh network; a subscriber gets every payload byte for byte
    port2 = free_port()
    s = open_session(ZenohSettings(listen=(f"tcp/127.0.0.1:{port2}",)))
    q: queue.SimpleQueue = queue.SimpleQueue()
    Bus(s).subscribe("gflow/demo/estimate", lambda k, p, ns, seq: q.put(p))
    rp = cli_fork.run_command([*gflow_cmd, "replay", str(rec), "--max", "--topics", "gflow/demo/estimate",
                               "--connect", f"tcp/127.0.0.1:{port2}"], capture_output=True, text=True, timeout=120)
    assert rp.returncode == 0, rp.stderr
    want = [r.data for r in iter_records(rec, topics=["gflow/demo/estimate"])]
    got = []
    deadline = time.monotonic() + 30
    while len(got) < len(want) and time.monotonic() < deadline:
        try:
            got.append(q.get(timeout=0.1))
        except queue.Empty:
            pass
    s.close()
    assert want and got == want


def test_topics_waits_for_a_pipeline_that_is_slow_to_come_up(gflow_cmd):
    """`gflow topics` started before anything publishes: its --duration counts from the first message."""
    port = free_port()
    s = open_session(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)))
    try:
        tool = subprocess.Popen([*gflow_cmd, "topics", "--connect", f"tcp/127.0.0.1:{port}", "--duration", "1",
                                 "--wait", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        bus = Bus(s)
        pub = bus.publisher("gflow/slow/_status/source")
        deadline = time.monotonic() + 60
        while not pub.matching_status.matching:  # the tool has subscribed
            assert time.monotonic() < deadline and tool.poll() is None, "the tool never subscribed"
            time.sleep(0.02)
        quiet_until = time.monotonic() + 2.0  # longer than --duration: nothing yet
        while time.monotonic() < quiet_until:
            assert tool.poll() is None, "topics gave up before its --wait"
            time.sleep(0.05)
        while tool.poll() is None:  # beats until the tool has listened its second
            bus.publish("gflow/slow/_status/source", b"x", 0)
            time.sleep(0.05)
        out, err = tool.communicate(timeout=30)
    finally:
        s.close()
    assert tool.returncode == 0, err
    assert "gflow/slow/_status/source" in out, out


@pytest.mark.parametrize("loops", ["0", "1"])
def test_replay_stopped_by_ctrl_c_after_its_ready_line_exits_cleanly(demo8, gflow_cmd, loops):
    """The ready line is printed once the session is open: a Ctrl-C any time after it ends the replay with the count
    sent, never a traceback. With ``--loop 0`` that is how a replay ends: exit 0. One asked to play the file once
    (slowed so that it is still playing) said "replayed N messages" and exited 0 too, taken for the whole file: it
    now says it was interrupted after N of the messages it had to send, and exits 130. (The recording: conftest's
    ``demo8``, a small demo recording made once for the test run.)"""
    rec = demo8
    pace = ["--max"] if loops == "0" else ["--speed", "0.01"]
    p = subprocess.Popen([*gflow_cmd, "replay", str(rec), "--loop", loops, *pace,
                          "--listen", f"tcp/127.0.0.1:{free_port()}"], stderr=subprocess.PIPE, text=True)
    try:
        line = p.stderr.readline()
        assert line.startswith("replaying "), line
        p.send_signal(signal.SIGINT)
        rc = p.wait(60)
        err = p.stderr.read()
        last = err.strip().splitlines()[-1]
        assert "Traceback" not in err, err
        if loops == "0":
            assert rc == 0 and last.startswith("replayed ") and last.endswith(" (until interrupted)"), err
        else:
            assert rc == 130 and last.startswith("gflow replay: interrupted after ") and " of the " in last, err
    finally:
        if p.poll() is None:
            p.kill()
