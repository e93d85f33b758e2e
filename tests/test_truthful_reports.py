"""Tools that never give a wrong answer: what ``gflow foxglove`` copied, what ``rerun --check``
cannot check, ``gflow step`` jumping without warnings, a demo scored over the frames it ran,
m2's coasting report, a stream's end, the counts after Ctrl-C, ``gflow run`` without an initial
box, and CSV line endings."""

from __future__ import annotations

import io
import logging
from pathlib import Path

import pytest
from mcap.reader import make_reader

from pipeline.cli.main import main
from pipeline.io.mcap_io import iter_records
from gflow_msgs.messages import Estimate, decode
import cli_fork


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("demo") / "run.mcap"
    assert main(["demo", "--frames", "60", "--particles", "100", "--inline", "--record", str(p)]) == 0
    return p


def test_foxglove_says_what_it_copied_and_draws_the_box(demo_run: Path, tmp_path: Path, capsys) -> None:
    from tests.foxglove_protobuf import decode_with_schema

    out = tmp_path / "fox.mcap"
    assert main(["foxglove", str(demo_run), str(out)]) == 0
    said = capsys.readouterr().out
    left = said.split("left out:", 1)[1]
    assert "features" in left and "estimate" not in left and "frames " not in left, said
    boxes = {}
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic.endswith("/box"):
                assert schema.name == "foxglove.ImageAnnotations"
                ann = decode_with_schema(schema.name, schema.data, message.data)
                boxes[len(boxes)] = ann
    est = [m for r in iter_records(demo_run) if r.topic.endswith("/estimate")
           for m in [decode(r.data)] if isinstance(m, Estimate)]
    assert len(boxes) == len(est) == 60
    x, y, w, h = est[0].box
    loop = boxes[0]["points"][-1]["points"]  # the estimate's box, drawn last (pixel edges: Foxglove's)
    assert [(p["x"], p["y"]) for p in loop][0] == pytest.approx((x, y))
    assert [(p["x"], p["y"]) for p in loop][2] == pytest.approx((x + w, y + h))


def test_rerun_check_says_what_it_cannot_check(tmp_path: Path, capsys) -> None:
    p = tmp_path / "few.mcap"
    assert main(["demo", "--frames", "8", "--particles", "100", "--inline", "--record", str(p),
                 "--record-topics", "estimate,particles"]) == 0
    capsys.readouterr()
    assert main(["rerun", str(p), "--stage", "filter", "--check"]) == 2
    err = capsys.readouterr().err
    assert "cannot re-run stage filter" in err and "/proposals" in err and "--record-topics estimate,particles" in err
    assert main(["rerun", str(p), "--graph", "--check"]) == 2
    assert "/frames" in capsys.readouterr().err


def test_step_jumps_to_a_frame_without_warnings(demo_run: Path, capsys, monkeypatch, caplog) -> None:
    monkeypatch.setattr("sys.stdin", io.StringIO("j 50\ns\nq\n"))
    with caplog.at_level(logging.WARNING):
        assert main(["step", str(demo_run), "--stage", "filter"]) == 0
    jumped = capsys.readouterr().out
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING], caplog.text
    assert "--- frame 50" in jumped and "  error " not in jumped
    monkeypatch.setattr("sys.stdin", io.StringIO("\n" * 51 + "q\n"))  # frame by frame from the start
    assert main(["step", str(demo_run), "--stage", "filter"]) == 0
    walked = capsys.readouterr().out
    frame = lambda text: text.split("--- frame 50", 1)[1].split("step>", 1)[0]  # noqa: E731
    assert frame(jumped) == frame(walked)


def test_a_demo_stopped_early_is_scored_over_the_frames_it_ran(tmp_path: Path) -> None:
    import json
    import os
    import re
    import subprocess
    import sys
    import time

    rt = tmp_path / "rt"
    env = dict(os.environ, GFLOW_RUNTIME_DIR=str(rt), PYTHONPATH=str(Path(__file__).resolve().parent.parent))
    cmd = [sys.executable, "-m", "pipeline.cli.main"]
    demo = subprocess.Popen([*cmd, "demo", "--frames", "5000", "--particles", "100", "--no-record"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (rt.is_dir() and list(rt.glob("*.json"))):
            assert demo.poll() is None and time.monotonic() < deadline, "the demo did not start"
            time.sleep(0.1)
        stream = json.loads(next(rt.glob("*.json")).read_text())["stream"]
        echo = cli_fork.run_command([*cmd, "echo", "estimate", "-n", "20", "--timeout", "60"], env=env, capture_output=True,
                                    text=True, timeout=90)  # tracking: then stop it
        assert echo.returncode == 0, echo.stderr
        pub = cli_fork.run_command([*cmd, "pub", f"gflow/{stream}/_control", "Control", '{"command": "stop"}', "--wait",
                                    "30"], env=env, capture_output=True, text=True, timeout=60)
        assert pub.returncode == 0, pub.stderr
        out, err = demo.communicate(timeout=120)
    finally:
        if demo.poll() is None:
            demo.kill()
    assert demo.returncode == 0, err
    ran = int(re.search(r"frames: (\d+)", out).group(1))
    scored = re.search(r"success@0.5 ([\d.]+) over (\d+) frames", out)
    assert ran < 5000 and f"stopped after {ran} of 5000 frames" in out, out
    flight = re.search(r"\((\d+) in flight when it stopped", out)
    assert int(scored.group(2)) == ran - (int(flight.group(1)) if flight else 0) and float(scored.group(1)) > 0.8, out


def test_coasting_says_whether_the_input_was_unusable_or_blank(tmp_path: Path, capsys) -> None:
    """Blank frames (no edge pixels) coast on the dynamics with their input read; the report says
    so, and not "no usable input"."""
    p = tmp_path / "blank.mcap"
    assert main(["run", "demo", "--inline", "--set", "source.frames=30", "--set", "source.blank_every=10",
                 "--set", "source.blank_count=2", "--record", str(p)]) == 0
    capsys.readouterr()
    assert main(["boxes", str(p), "--out", str(tmp_path / "b.csv")]) == 0
    out = capsys.readouterr().out
    assert "6 frame(s) coasted" in out and "held no evidence" in out and "8-9, 18-19, 28-29" in out, out
    assert "no usable input" not in out
    from pipeline.recording.results import completeness

    est = {f: type("E", (), {"state": "coast" if f in (2, 3) else "track"})() for f in range(6)}  # the state: all it reads
    lines = completeness(est, range(6), {3})  # frame 3 was reported (a missing input); frame 2 was blank
    assert any("no usable input" in ln and ln.endswith(": 3") for ln in lines), lines
    assert any("held no evidence" in ln and ln.endswith(": 2") for ln in lines), lines


def test_a_dim_frame_is_not_called_blank_but_named_by_the_fixed_canny_thresholds(tmp_path: Path, capsys) -> None:
    """A frame too dim for fixed Canny thresholds (an m2 model's 50/150) coasts like a blank one, but
    the report says which it was: the dim frames with the thresholds and how to change them, a
    uniform frame with the blank-frame wording. The boxes are those of the run without the report."""
    import cv2
    import numpy as np

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(10):
        img = np.full((96, 128), 60, np.uint8)
        contrast = {4: 6, 5: 6, 8: 0}.get(i, 140)  # 4-5: a faint box, 8: a uniform frame
        img[30:70, 50:80] = 60 + contrast
        cv2.imwrite(str(folder / f"{i:04d}.png"), img)
    assert main(["track", str(folder), "--tracker", "chamfer", "--init", "50,30,30,40", "--set", "preprocess.canny_low=50",
                 "--set", "preprocess.canny_high=150", "--out", str(tmp_path / "b.csv"), "--inline", "--no-record"]) == 0
    out = capsys.readouterr().out
    dim = next((ln for ln in out.splitlines() if "not blank" in ln), "")
    assert dim.strip().startswith("2 frame(s) coasted") and "Canny thresholds 50/150" in dim and ": 4-5;" in dim, out
    assert "--set preprocess.canny_low=LOW --set preprocess.canny_high=HIGH" in dim, dim
    assert any("held no evidence" in ln and "a blank frame" in ln and ln.endswith(": 8") for ln in out.splitlines()), out


def test_the_live_figures_add_up() -> None:
    """After Ctrl-C, frames captured = tracked + skipped + in flight; the rate leaves the waits out."""
    from pipeline.recording.live_record import LiveSummary

    s = LiveSummary(frames={i: i for i in range(100)}, captured=121, skipped=19, latency_ms=[10.0] * 99)
    line = s.lines()[0]
    assert "121 frames captured, 99 tracked, 19 skipped" in line and "3 in flight when the run stopped" in line, line


@pytest.fixture
def stream_frames() -> Path:
    from tests.conftest import data_dir
    from tests.stream_server import ffmpeg_exe

    if ffmpeg_exe() is None:
        pytest.skip("no FFmpeg to serve streams: pip install imageio-ffmpeg (a test extra)")
    return data_dir("crossing") / "frames"


def test_a_stream_that_ends_is_no_error(tmp_path: Path, stream_frames: Path) -> None:
    import os
    import sys

    from tests.stream_server import StreamServer

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parent.parent))
    cmd = [sys.executable, "-m", "pipeline.cli.main", "track"]
    with StreamServer(stream_frames, fps=25, count=40) as srv:
        r = cli_fork.run_command([*cmd, srv.url, "--init", "204,150,17,50", "--out", "a.csv", "--reconnect", "0",
                                  "--record", "a.mcap"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "error from source" not in r.stderr and "source: " + srv.url in r.stderr, r.stderr
    assert "errors reported" not in r.stdout and "stream_ended:" in r.stdout, r.stdout
    assert "s the stream was tracked" in r.stdout, r.stdout
    with StreamServer(stream_frames, fps=50, count=30) as srv:
        r = cli_fork.run_command([*cmd, srv.url, "--init", "204,150,17,50", "--out", "b.csv", "--inline", "--stop", "150",
                                  "--reconnect", "0", "--no-record"], cwd=tmp_path, env=env, capture_output=True,
                                 text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "errors reported" not in r.stdout and "WARNING" not in r.stderr, (r.stdout, r.stderr)
