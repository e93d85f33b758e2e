"""Live sources end to end with real streams: an FFmpeg process serves caviar1's frames on
loopback (H.264 MPEG-TS over TCP, MJPEG over HTTP), ``gflow track`` tracks them as processes
over zenoh or ``--inline``, and the recording, the boxes and the reports are checked.

Streams are short (60 to 150 frames, a few seconds each). Bounds on latency are loose: the
machine runs other jobs, and what is checked is that latency stays bounded when the stream is
faster than the tracker (queued frames would make it grow with the length of the stream).
"""

from __future__ import annotations

import csv
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import cli_fork
from stream_server import StreamServer, ffmpeg_exe, free_port

ROOT = Path(__file__).resolve().parent.parent
INIT = "129,71,30,79"  # caviar1's ground-truth box of frame 0

pytestmark = pytest.mark.skipif(ffmpeg_exe() is None,
                                reason="no FFmpeg to serve streams: pip install imageio-ffmpeg (a test extra)")


def gflow(*args: str, cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """``gflow ARGS`` run to its end in ``cwd`` (forked from a process that has imported the command line:
    tests/cli_fork.py)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args], cwd=cwd, env=env,
                                capture_output=True, text=True, timeout=timeout)


def read_csv(path: Path) -> dict[int, tuple[float, ...]]:
    with open(path) as f:
        return {int(r[0]): tuple(float(v) for v in r[1:5]) for r in list(csv.reader(f))[1:]}


def cle(a, b) -> float:
    return math.hypot(a[0] + a[2] / 2 - b[0] - b[2] / 2, a[1] + a[3] / 2 - b[1] - b[3] / 2)


def live_of(recording: Path):
    from pipeline.recording.live_record import live_summary

    s = live_summary(recording)
    assert s is not None, f"{recording} holds no Capture messages"
    return s


def test_track_tcp_mpegts_matches_the_file_run(tmp_path: Path, caviar1: Path) -> None:
    """Processes over zenoh: rows for at least half the frames (the rest counted as skipped), under the camera's frame numbers, as close to the
    ground truth as the file run on the same rows; the recording re-runs bit for bit."""
    n = 150
    started = time.monotonic()
    file_run = gflow("track", str(caviar1), "--init", INIT, "--out", "file.csv", "--stop", str(n), "--inline",
                     "--no-record", "-q", cwd=tmp_path)
    assert file_run.returncode == 0, file_run.stderr
    # frames/s this machine tracks at now, start-up included (so no more than it can do): a busy machine's pace
    pace = n / (time.monotonic() - started)
    with StreamServer(caviar1 / "frames", "tcp", fps=25, count=n) as srv:
        r = gflow("track", srv.url, "--init", INIT, "--out", "live.csv", "--record", "live.mcap",
                  "--reconnect", "0.5", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    live, ref = read_csv(tmp_path / "live.csv"), read_csv(tmp_path / "file.csv")
    gt = read_csv(caviar1 / "groundtruth.csv")
    assert 0 in live and set(live) <= set(range(n)), sorted(live)[:5]  # the camera's frame numbers
    # a speed bound, kept loose: a busy machine skips frames (counted exactly below); the server's
    # start-up burst alone is about 20 frames, so "most frames" is what a quiet 2-core machine gives. The share
    # is of the frames this machine could track at the pace it tracked the file (at most all 25 a second): on a
    # machine loaded by other work the stream skips more, and is not to be failed for it
    assert len(live) >= 0.5 * n * min(1.0, pace / 25.0), f"{len(live)} rows of {n} frames (the file at {pace:.1f}/s)"
    rows = sorted(live)
    err_live = np.mean([cle(live[k], gt[k]) for k in rows])
    err_file = np.mean([cle(ref[k], gt[k]) for k in rows])
    assert abs(err_live - err_file) <= 1.0, (err_live, err_file)
    s = live_of(tmp_path / "live.mcap")
    assert s.captured == n and s.sent == len(live) and s.skipped == n - len(live)
    assert sorted(s.frames.values()) == rows
    assert any(kind == "stream_ended" for kind, _ in s.reports), s.reports
    assert "stream_ended" in r.stdout and "captured" in r.stdout  # the run says why it ended
    # the skips are in the recording: the stages re-run bit for bit
    for stage in ("proposal", "filter"):
        rr = gflow("rerun", "live.mcap", "--stage", stage, "--check", cwd=tmp_path)
        assert rr.returncode == 0 and "identical bit for bit" in rr.stdout, (rr.args, rr.stdout, rr.stderr)


def test_http_mjpeg_inline_accounts_for_every_frame(tmp_path: Path, caviar1: Path) -> None:
    """MJPEG over HTTP, one process: every frame decoded is either tracked or counted as skipped,
    and the rows are the camera's frames in order."""
    n = 60
    with StreamServer(caviar1 / "frames", "mjpeg", fps=25, count=n) as srv:
        r = gflow("track", srv.url, "--init", INIT, "--out", "b.csv", "--record", "m.mcap", "--inline",
                  "--reconnect", "0.5", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    boxes = read_csv(tmp_path / "b.csv")
    s = live_of(tmp_path / "m.mcap")
    assert s.captured == n, s.captured
    assert s.sent + s.skipped == n and len(boxes) == s.sent
    assert list(s.frames) == list(range(s.sent))  # the frames sent are numbered 0, 1, 2, ...
    assert sorted(boxes) == sorted(s.frames.values()) and boxes.keys() >= {0}


def _frames_recorded(path: Path) -> int:
    """Frames in a recording still being written (0 before it exists)."""
    from pipeline.io.mcap_io import iter_records

    try:
        return sum(1 for r in iter_records(path, on_truncated=lambda note: None) if r.type == "Frame")
    except (OSError, ValueError):
        return 0


def test_server_killed_and_restarted_reconnects_and_reports_the_gap(tmp_path: Path, caviar1: Path) -> None:
    """The server dies mid-stream and comes back: the source reconnects, reports the gap in
    seconds and frames, numbers on from where it was, and the run ends normally when the second
    stream ends (exit 0, boxes written, the recording closed)."""
    port = free_port()
    first = StreamServer(caviar1 / "frames", "tcp", fps=25, port=port).start()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "track", first.url, "--init", INIT,
                             "--out", "r.csv", "--record", "r.mcap", "--reconnect", "6"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    second = None
    try:
        deadline = time.monotonic() + 60
        while _frames_recorded(tmp_path / "r.mcap") < 25:  # the source is receiving the first stream
            assert time.monotonic() < deadline and proc.poll() is None, "no frame of the first stream was recorded"
            time.sleep(0.1)
        first.stop()
        killed = time.monotonic()
        time.sleep(1.0)
        second = StreamServer(caviar1 / "frames", "tcp", fps=25, start=200, count=50, port=port).start()
        out, err = proc.communicate(timeout=90)
        down = time.monotonic() - killed
    finally:
        if proc.poll() is None:
            proc.kill()
        for srv in (first, second):
            if srv is not None:
                srv.stop()
    assert proc.returncode == 0, err[-2000:]
    s = live_of(tmp_path / "r.mcap")
    assert s.reconnects == 1 and len(s.gaps) == 1, (s.reconnects, s.gaps, s.reports)
    frame_after, gap_s = s.gaps[0]
    assert 0.8 <= gap_s <= 6.0 and gap_s < down, (gap_s, down)
    kinds = [k for k, _ in s.reports]
    assert kinds == ["reconnected", "stream_ended"], s.reports
    said = s.reports[0][1]
    assert first.url in said and "frames missed" in said and f"{gap_s:.2f} s" in said, said
    # numbering skips the frames missed (the second server's clock starts again: estimated by the
    # host clock), and the second stream's 50 frames follow
    assert s.missed > 0 and f"{s.missed} frames missed" in said, (s.missed, said)
    last = int(said.split("lost after frame ")[1].split(" ")[0])  # the first stream's last frame
    resumed = int(said.split("tracking resumes at frame ")[1].split(" ")[0])
    assert resumed == last + 1 + s.missed, (last, resumed, s.missed)
    # the gap rides on the first frame sent after it: the reconnect's, or a later one when the frames
    # between were skipped (a second server sends what it encoded before the client came in a burst)
    assert resumed <= frame_after < resumed + 50, (resumed, frame_after)
    # every frame of both streams was captured (TCP loses none), and the frames captured and missed
    # add up to the camera's span
    assert s.captured == last + 1 + 50, (s.captured, last)
    assert s.captured + s.missed == max(s.frames.values()) + 1, (s.captured, s.missed, max(s.frames.values()))
    boxes = read_csv(tmp_path / "r.csv")
    assert max(boxes) >= frame_after and min(boxes) == 0
    assert "reconnected" in out


@pytest.mark.parametrize("tracker, fps", [("appearance", 200), ("gflow", 100)])
def test_stream_faster_than_the_tracker_skips_and_keeps_latency_bounded(tmp_path: Path, caviar1: Path, tracker: str,
                                                                        fps: int) -> None:
    """A stream faster than the tracker: many frames are skipped, every one counted (in the
    heartbeats and the recording), latency stays far below the stream's length, and with
    --record-topics '*,skipped' the recording keeps every frame captured and re-runs bit for bit."""
    n = 300  # 1.5 s (3 s) of stream; queued, the last frames would wait for seconds
    with StreamServer(caviar1 / "frames", "tcp", fps=fps, count=n) as srv:
        r = gflow("track", srv.url, "--tracker", tracker, "--init", INIT, "--out", "f.csv", "--record", "f.mcap",
                  "--fps", str(fps), "--reconnect", "0.5", "--record-topics", "*,skipped", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    s = live_of(tmp_path / "f.mcap")
    assert s.captured == n and s.skipped > n // 3 and s.sent + s.skipped == n, (s.captured, s.sent, s.skipped)
    assert "skipped=" in r.stderr  # the progress line
    from pipeline.io.mcap_io import iter_records

    recs = list(iter_records(tmp_path / "f.mcap"))
    # bounded latency: a frame waits at most for the step in progress, then takes its own step, so
    # no estimate comes later than a few steps after its capture. The step is measured in this run
    # (the gap between estimates), since the machine may be loaded; queued frames would instead
    # wait for every frame before them, and the run would last until all n were tracked. Queued, latency
    # would grow frame after frame: its median would be seconds (the n frames would take n steps, about
    # 16 s for the appearance tracker against a 1.5 s stream), and its 90th percentile longer than the
    # whole stream. One stall of a loaded machine moves the median little and the 90th percentile by no
    # more than itself: on a loaded machine a run tracked 5 frames, one of them 0.9 s late, and the 90th
    # percentile of the five was 0.76 s against a bound of 0.66 s made of the 54 ms step.
    logged = sorted(x.log_ns for x in recs if x.type in ("Estimate", "PoseEstimate"))
    step_ms = float(np.median(np.diff(logged))) / 1e6 if len(logged) > 1 else 1000.0
    assert np.median(s.latency_ms) < 3 * step_ms + 500.0, (s.latency_ms, step_ms)
    assert np.percentile(s.latency_ms, 90) < 1000.0 * n / fps + 3 * step_ms, (s.latency_ms, step_ms)
    frames = sum(1 for x in recs if x.type == "Frame" and x.topic.endswith("/frames"))
    kept = sum(1 for x in recs if x.type == "Frame" and x.topic.endswith("/skipped"))
    assert frames == s.sent and frames + kept == n  # every frame captured is in the recording
    hb = [x for x in recs if x.type == "StageStatus" and x.topic.endswith("/_status/source")]
    from gflow_msgs.messages import decode

    assert max(decode(x.data).skipped for x in hb) == s.skipped  # and in the source's heartbeats
    rr = gflow("rerun", "f.mcap", "--stage", "source", "--check", cwd=tmp_path)
    assert rr.returncode == 0 and "identical bit for bit" in rr.stdout, (rr.stdout, rr.stderr)


def test_stream_that_never_opens_is_one_line_within_15_s(tmp_path: Path) -> None:
    port = free_port()  # nothing listens there
    t0 = time.monotonic()
    r = gflow("track", f"tcp://127.0.0.1:{port}", "--init", INIT, "--out", "b.csv", cwd=tmp_path)
    took = time.monotonic() - t0
    assert r.returncode != 0 and "Traceback" not in r.stderr
    lines = [x for x in r.stderr.splitlines() if x.startswith("gflow")]
    assert len(lines) == 1 and f"tcp://127.0.0.1:{port}" in lines[0] and "Connection refused" in lines[0], r.stderr
    assert took < 15.0, took
    assert not list(tmp_path.glob("recordings/*.mcap"))  # nothing ran: no recording left behind


@pytest.mark.parametrize("argv, named", [
    (["--camera", "97"], "/dev/video97"),
    (["/dev/video98", "--inline"], "/dev/video98"),
    (["--camera", "1", "/dev/video1"], "not both"),
    (["tcp://127.0.0.1:9", "--start", "5"], "--start"),
])
def test_live_source_mistakes(tmp_path: Path, argv: list[str], named: str) -> None:
    r = gflow("track", *argv, "--init", INIT, "--out", "b.csv", cwd=tmp_path, timeout=60)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    lines = [x for x in r.stderr.splitlines() if x.startswith("gflow")]
    assert len(lines) == 1 and named in lines[0], r.stderr


def test_live_option_on_a_file_is_refused(tmp_path: Path, caviar1: Path) -> None:
    r = gflow("track", str(caviar1), "--init", INIT, "--out", "b.csv", "--reconnect", "3", cwd=tmp_path)
    assert r.returncode == 2 and "--reconnect is an option of live sources" in r.stderr, r.stderr
