"""A replay is a run of its own: it never feeds a running pipeline by accident. Two real zenoh
sessions on loopback: a live pipeline's stand-in (a stage's liveliness token on stream ``demo``
and a subscriber on ``gflow/demo/**``) and ``gflow replay`` of a recording of stream ``demo``."""

from __future__ import annotations

import queue
import subprocess
import time
from pathlib import Path

import pytest

from pipeline.io.mcap_io import iter_records
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.inline import run_inline
from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session
import cli_fork

FRAMES = 8


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """The demo graph's first frames, recorded inline: stream ``demo``."""
    rec = tmp_path_factory.mktemp("replay-stream") / "demo.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": FRAMES}, "filter": {"particles": 50}}))
    run_inline(plan, recording=str(rec))
    return rec


@pytest.fixture()
def live():
    """A live pipeline's stand-in on stream ``demo``: what it hears, by topic, and its endpoint."""
    port = free_port()
    s = open_session(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)))
    token = s.liveliness().declare_token("gflow/demo/_alive/preprocess")  # as a stage process holds one
    heard: queue.SimpleQueue = queue.SimpleQueue()
    bus = Bus(s)
    bus.subscribe("gflow/**", lambda k, p, ns, seq: heard.put((k, p)))
    yield f"tcp/127.0.0.1:{port}", heard
    token.undeclare()
    s.close()


def _drain(q: queue.SimpleQueue, n: int, timeout: float = 20.0) -> list[tuple[str, bytes]]:
    """The next ``n`` messages ``q`` gets (fewer if they do not come within ``timeout``)."""
    out, end = [], time.monotonic() + timeout
    while len(out) < n and time.monotonic() < end:
        try:
            out.append(q.get(timeout=0.05))
        except queue.Empty:
            pass
    return out


def test_a_replay_into_a_running_pipelines_stream_is_refused(recording: Path, live, gflow_cmd) -> None:
    endpoint, heard = live
    r = cli_fork.run_command([*gflow_cmd, "replay", str(recording), "--max", "--topics", "estimate", "--connect",
                              endpoint], capture_output=True, text=True, timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "stream 'demo' is in use" in lines[0] and "stage preprocess" in lines[0] and "--stream" in lines[0]
    # the refusal came before anything was sent: a marker sent now is the first thing the pipeline hears
    s = open_session(ZenohSettings(connect=(endpoint,)))
    try:
        Bus(s).publish("gflow/demo/marker", b"x", 0)
        first = _drain(heard, 1)
    finally:
        s.close()
    assert [k for k, _ in first] == ["gflow/demo/marker"]


def test_a_replay_beside_it_keeps_to_its_own_stream_and_into_it_on_purpose(recording: Path, live,
                                                                            gflow_cmd) -> None:
    endpoint, heard = live
    recorded = [r.data for r in iter_records(recording, topics=["gflow/demo/estimate"])]
    r = cli_fork.run_command([*gflow_cmd, "replay", str(recording), "--max", "--topics", "estimate", "--stream",
                              "again", "--connect", endpoint], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    got = _drain(heard, len(recorded))
    assert {k for k, _ in got} == {"gflow/again/estimate"}  # nothing on the live run's topics
    assert [p for _, p in got] == recorded  # byte for byte, under the new stream
    r = cli_fork.run_command([*gflow_cmd, "replay", str(recording), "--max", "--topics", "estimate", "--stream",
                              "demo", "--connect", endpoint], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    got = _drain(heard, len(recorded))
    assert [k for k, _ in got] == ["gflow/demo/estimate"] * len(recorded)


def test_a_pipeline_started_on_a_stream_a_replay_publishes_on_is_refused(recording: Path, gflow_cmd) -> None:
    """The other order: the replay first (looping, its own endpoint), then a run joining it on the
    same stream would take the replayed frames for its own. Refused in one line, before it starts."""
    port = free_port()
    replay = subprocess.Popen([*gflow_cmd, "replay", str(recording), "--loop", "0", "--speed", "1",
                               "--listen", f"tcp/127.0.0.1:{port}"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    try:
        assert replay.stderr is not None
        line = replay.stderr.readline()  # printed once the replay is announced and its token declared
        assert line.startswith("replaying"), line
        r = cli_fork.run_command([*gflow_cmd, "run", "demo", "--stream", "demo", "--connect", f"tcp/127.0.0.1:{port}",
                                  "--no-record"], capture_output=True, text=True, timeout=120)
        error = [ln for ln in r.stderr.splitlines() if "error" in ln]  # one line, no traceback
        assert r.returncode == 2 and len(error) == 1 and "Traceback" not in r.stderr, r.stderr
        assert "stream 'demo' is in use" in error[0] and f"gflow replay (pid {replay.pid})" in error[0], error[0]
        # another stream beside it is no clash
        ok = subprocess.run([*gflow_cmd, "run", "demo", "--stream", "beside", "--connect", f"tcp/127.0.0.1:{port}",
                             "--no-record"], capture_output=True, text=True, timeout=300)
        assert ok.returncode == 0, ok.stderr
    finally:
        replay.terminate()
        replay.communicate(timeout=30)
