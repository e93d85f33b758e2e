"""Resume, not restart: SIGKILL one stage of the shipped chamfer graph mid-run on caviar1
(`gflow track`, processes). The run completes, the CSV has one row per frame, and at most
the frames in flight at the kill differ from an undisturbed run, named in the report."""

from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

import cli_fork
from pipeline.io.mcap_io import segments
from pipeline.recording.results import estimates

STOP = 60  # frames: enough to kill mid-run, few enough to keep the test fast
KILL_AT = 20  # estimates in the recording when the stage is killed
WINDOW = 8  # the source's flow-control window: at most this many frames are in flight
# the G-flow runs (a tracker several times slower than chamfer): the kill comes once frame GFLOW_KILL_AT is
# recorded, and 30 frames follow it: more than the recording's 0.5 s lag and the window in flight at G-flow's
# 25 frames/s, so the resumed filter/proposal track frames of their own even on a fast machine
GFLOW_STOP = 40
GFLOW_KILL_AT = 10
# what is under test is the restart; an input given up as late (GFLOW_LATE_S, default 3 s) on a heavily
# loaded machine is another mechanism, whose coasting frames differ from the undisturbed run's
ENV = {**os.environ, "GFLOW_LATE_S": "60"}


def _track(caviar1: Path, tmp: Path, name: str) -> list[str]:
    return [sys.executable, "-m", "pipeline.cli.main", "track", str(caviar1), "--init", "129,71,30,79",
            "--tracker", "chamfer", "--out", str(tmp / f"{name}.csv"), "--record", str(tmp / f"{name}.mcap"), "--stop", str(STOP),
            "--listen", "tcp/127.0.0.1:0"]


def _rows(path: Path) -> dict[int, tuple[str, ...]]:
    with open(path) as f:
        return {int(r[0]): tuple(r[1:]) for r in list(csv.reader(f))[1:]}


def _named_frames(report: str) -> set[int]:
    """Every frame number the report lists in a 'frame(s) ...: 3, 7-9' line."""
    out: set[int] = set()
    for line in report.splitlines():
        m = re.search(r"frame\(s\)[^:]*: ([0-9, -]+)$", line.strip())
        if not m:
            continue
        for part in m.group(1).split(","):
            a, _, b = part.strip().partition("-")
            out.update(range(int(a), int(b or a) + 1))
    return out


@pytest.fixture(scope="module")
def undisturbed(tmp_path_factory) -> dict[int, tuple[str, ...]]:
    from conftest import data_dir

    caviar1 = data_dir("caviar1")
    tmp = tmp_path_factory.mktemp("undisturbed")
    # inline: an undisturbed run's results are the processes' bit for bit, without starting five processes
    out = cli_fork.run_command([*_track(caviar1, tmp, "base"), "-q", "--inline"], capture_output=True, text=True,
                               timeout=300, env=ENV)
    assert out.returncode == 0, out.stderr
    return _rows(tmp / "base.csv")


@pytest.mark.parametrize("stage", ["source", "preprocess", "proposal", "filter", "recorder"])
def test_a_killed_stage_resumes_and_the_result_is_unchanged(caviar1, tmp_path, undisturbed, stage):
    rec = tmp_path / "run.mcap"
    # played at 25 fps: a fast pipeline would otherwise finish before the kill (the estimates
    # reach the recording at its 0.5 s flushes); the results do not depend on the pace
    p = subprocess.Popen([*_track(caviar1, tmp_path, "run"), "--realtime"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=ENV)
    deadline = time.monotonic() + 120
    while not (rec.exists() and rec.stat().st_size > 64 and len(estimates(rec)) >= KILL_AT):
        assert time.monotonic() < deadline and p.poll() is None, "the pipeline did not get going"
        time.sleep(0.1)
    victim = [c for c in psutil.Process(p.pid).children() if c.cmdline()[-1] == stage]
    assert len(victim) == 1
    victim[0].send_signal(signal.SIGKILL)
    out, err = p.communicate(timeout=180)
    assert p.returncode == 0, out + err
    assert f"stage {stage} was restarted 1 time(s)" in out
    # what it sends again on resuming (its last step's outputs) is no error where it had arrived
    assert "duplicate_seq" not in out + err, out + err
    rows = _rows(tmp_path / "run.csv")
    assert sorted(rows) == list(range(STOP))  # one row per frame
    differ = {f for f in rows if rows[f] != undisturbed[f]}
    assert len(differ) <= WINDOW, f"frames {sorted(differ)} differ after killing {stage}"
    assert differ <= _named_frames(out), f"frames {sorted(differ)} differ but the report does not name them:\n{out}"
    if stage == "recorder":
        assert len(segments(rec)) == 2  # the restarted recorder wrote a second segment, read as one


def test_a_stage_killed_after_its_last_frame_restarts_and_the_run_ends(caviar1, tmp_path, monkeypatch):
    """The peers it would wait to hear from may have finished: it must not wait for them, nor
    for them to drain what it sends (they exited before it could hear them finish)."""
    import os
    import threading

    from pipeline.runtime.graph import load_graph
    from pipeline.runtime.launcher import Launcher
    from pipeline.runtime.transport import ZenohSettings, free_port

    box = [129, 71, 30, 79]
    plan = load_graph("chamfer", overrides={"source": {"kind": "folder", "path": str(caviar1 / "frames"), "stop": 30},
                                            "filter": {"init": box}, "preprocess": {"calibrate_box": box}})
    rec = tmp_path / "run.mcap"
    monkeypatch.setenv("GFLOW_DRAIN_S", "150")  # waiting for a finished consumer would take all of it
    la = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=str(rec),
                  progress=False)
    out: dict = {}
    th = threading.Thread(target=lambda: out.setdefault("r", la.run()), daemon=True)
    th.start()
    deadline = time.monotonic() + 120
    while not (la.status.get("filter") and la.status["filter"].last_seq >= 29):
        assert time.monotonic() < deadline and th.is_alive()
        time.sleep(0.001)
    os.kill(la.pids["filter"][0], signal.SIGKILL)
    th.join(120)
    assert not th.is_alive(), "the run hung after the restart (the restarted filter waited to drain)"
    r = out["r"]
    assert r.ok and r.exits["filter"].restarts == 1, r.exits
    assert sorted(estimates(rec)) == list(range(30))
    # its progress goes on from its checkpoint: 30 frames done, not the restarted process's 0
    assert r.status["filter"].steps == 30, r.status["filter"]


@pytest.mark.parametrize("stage,extra", [("filter", []), ("proposal", ["--background", "--experts", "8"])])
def test_a_killed_gflow_stage_resumes_and_the_result_is_unchanged(tmp_path, stage, extra):
    """The G-flow graph too (its filter's restart is slow: the proposal stage must wait for it);
    a killed proposal stage resumes with its background replica from its checkpoint."""
    from conftest import data_dir

    david = data_dir("david_indoor")
    cmd = [sys.executable, "-m", "pipeline.cli.main", "track", str(david), "--tracker", "gflow", "--init", "169,76,46,60",
           "--stop", str(GFLOW_STOP), "--listen", "tcp/127.0.0.1:0", *extra]
    env = ENV
    # the undisturbed run inline (its results are the processes' bit for bit; starting them is most of a run's CPU)
    base = cli_fork.run_command([*cmd, "--out", str(tmp_path / "base.csv"), "--record", str(tmp_path / "base.mcap"),
                                 "-q", "--inline"], capture_output=True, text=True, timeout=300, env=env)
    assert base.returncode == 0, base.stderr
    rec = tmp_path / "run.mcap"
    p = subprocess.Popen([*cmd, "--out", str(tmp_path / "run.csv"), "--record", str(rec)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 120
    # frame GFLOW_KILL_AT recorded (the recording trails by up to its 0.5 s flush): 30 frames left for the kill
    while not (rec.exists() and rec.stat().st_size > 64 and len(estimates(rec)) >= GFLOW_KILL_AT):
        assert time.monotonic() < deadline and p.poll() is None, "the pipeline did not get going"
        time.sleep(0.1)
    [victim] = [c for c in psutil.Process(p.pid).children() if c.cmdline()[-1] == stage]
    victim.send_signal(signal.SIGKILL)
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, out + err
    assert f"stage {stage} was restarted 1 time(s)" in out, out
    # no input fed twice: neither the resend of its last outputs nor the recorded inputs it caught
    # up on before its checkpoint (the proposal's state port joins frame t + 1)
    assert "duplicate_seq" not in out + err and "old_seq" not in out + err, out + err
    rows, undisturbed = _rows(tmp_path / "run.csv"), _rows(tmp_path / "base.csv")
    assert sorted(rows) == sorted(undisturbed) == list(range(GFLOW_STOP))
    differ = {f for f in rows if rows[f] != undisturbed[f]}
    assert len(differ) <= WINDOW and differ <= _named_frames(out), (sorted(differ), out)


def test_a_repeat_of_the_last_message_is_no_error_but_another_of_its_frame_is() -> None:
    """A restarted producer sends its last step's outputs again: a consumer that had them takes
    the byte-identical copy for a repeat; a different message of that frame is still refused."""
    import numpy as np

    from gflow_msgs.messages import Frame, Header, NDArray, encode
    from pipeline.runtime.stage_host import StageHost
    from stages.base import StageContext
    from stages.preprocess import PreprocessParams, PreprocessStage

    errors: list[str] = []
    st = PreprocessStage(PreprocessParams(canny_low=20, canny_high=60), StageContext("preprocess", "s"))
    h = StageHost(st, {"frames": "frames"}, {"features": "features"}, "errors",
                  lambda t, p, s, n="": errors.append(n) if t == "errors" else None)

    def frame(seq: int, value: int = 0) -> bytes:
        return encode(Frame(Header("s", seq, 0), NDArray.of(np.full((24, 32, 3), value, np.uint8))))

    for s in range(3):
        h.deliver("frames", frame(s))
    h.deliver("frames", frame(2))  # the resend
    assert h.stats.repeats == 1 and not h.stats.rejected and not errors
    h.deliver("frames", frame(2, value=9))  # another frame 2
    assert h.stats.rejected == {"duplicate_seq": 1} and errors == ["ErrorReport"]
    # killed after sending frame 3, before its checkpoint: it resends frame 2 (its checkpoint's
    # outputs) and then steps frame 3 again, the same bytes as before the kill
    h.deliver("frames", frame(3))
    h.deliver("frames", frame(2))
    h.deliver("frames", frame(3))
    assert h.stats.repeats == 3 and h.stats.rejected == {"duplicate_seq": 1}, (h.stats.repeats, h.stats.rejected)
