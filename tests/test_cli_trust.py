"""Answers a user can trust, from the command line as a user types it: Ctrl-C stops every
long-running command however it was started, and no command writes over an output file that is
already there.

A background job of a non-interactive shell (``nohup gflow replay ... &``) inherits SIGINT ignored:
each test here starts the command that way, waits until it is at work (the line it prints then),
sends SIGINT and waits for it to end by itself. The refusals run in this process (``main([...])``).
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import cli

from pipeline.cli.main import main
from pipeline.runtime.transport import free_port

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """A folder with frames/ (six 64x48 textured frames), gt.csv (a box per frame) and demo.mcap
    (10 frames of the synthetic scene, inline)."""
    d = tmp_path_factory.mktemp("cli-trust")
    rng = np.random.default_rng(0)
    (d / "frames").mkdir()
    for i in range(6):
        cv2.imwrite(str(d / "frames" / f"{i:04d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    (d / "gt.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(6)))
    assert main(["demo", "--frames", "10", "--inline", "--record", str(d / "demo.mcap")]) == 0
    return d


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as `nohup CMD &` in a non-interactive shell


class _Started:
    """``gflow ARGS`` started (with SIGINT ignored, by default); its output (stdout and stderr) read on a thread, line by line."""

    def __init__(self, args: list[str], cwd: Path, ignore_sigint: bool = True) -> None:
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.p = subprocess.Popen([sys.executable, "-m", "pipeline.cli", *args], cwd=cwd, env=env, text=True,
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  preexec_fn=_ignore_sigint if ignore_sigint else None)
        self.lines: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.err: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.p.stdout:
            self.err.append(line)
            self.lines.put(line)

    def wait_for(self, marker: str, timeout: float = 60) -> None:
        """Until a line of its output holds ``marker`` (the command is at work)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                if marker in self.lines.get(timeout=0.2):
                    return
            except queue.Empty:
                assert self.p.poll() is None, f"ended before {marker!r}: {''.join(self.err)}"
        pytest.fail(f"no {marker!r} in {timeout} s: {''.join(self.err)}")

    def stop(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait()


@pytest.fixture
def replaying(files: Path):
    """A recording replayed until stopped (SIGINT as usual): a live stream for echo, hz and view."""
    r = _Started(["replay", str(files / "demo.mcap"), "--loop", "0", "--stream", f"live{os.getpid()}"], files,
                 ignore_sigint=False)
    r.wait_for("replaying")
    yield f"live{os.getpid()}"
    r.p.send_signal(signal.SIGINT)
    try:
        r.p.wait(30)
    finally:
        r.stop()


def _stops_on_sigint(args: list[str], marker: str, cwd: Path) -> tuple[int, str]:
    c = _Started(args, cwd)
    try:
        c.wait_for(marker)
        c.p.send_signal(signal.SIGINT)
        try:
            rc = c.p.wait(30)
        except subprocess.TimeoutExpired:
            pytest.fail(f"gflow {args[0]} started with SIGINT ignored did not stop on SIGINT in 30 s")
        c.reader.join(10)  # the last lines, up to the end of the output
        return rc, "".join(c.err)
    finally:
        c.stop()


def test_replay_started_with_sigint_ignored_stops_on_it(files: Path) -> None:
    rc, err = _stops_on_sigint(["replay", str(files / "demo.mcap"), "--loop", "0"], "replaying", files)
    assert rc in (0, 130) and "Traceback" not in err, err


def test_step_started_with_sigint_ignored_stops_on_it(files: Path) -> None:
    rc, err = _stops_on_sigint(["step", str(files / "demo.mcap"), "--stage", "filter"], "stepping filter", files)
    assert rc == 130 and "Traceback" not in err, err


# echo stopped before its first message says so and exits 1, so it is stopped after one it printed
@pytest.mark.parametrize("tool,marker", [("echo", "/frames: "), ("hz", "pipeline")])
def test_live_tools_started_with_sigint_ignored_stop_on_it(files: Path, replaying: str, tool: str,
                                                           marker: str) -> None:
    rc, err = _stops_on_sigint([tool, f"{replaying}/frames"], marker, files)
    assert rc in (0, 130) and "Traceback" not in err, err


def test_view_started_with_sigint_ignored_stops_on_it(files: Path, replaying: str) -> None:
    pytest.importorskip("foxglove")
    rc, err = _stops_on_sigint(["view", "--stream", replaying, "--port", str(free_port())], "Foxglove: open", files)
    assert rc in (0, 130) and "forwarded" in err and "Traceback" not in err, err




@pytest.mark.parametrize("tool", [["echo", "{s}/estimate", "--timeout", "120"], ["hz", "{s}/estimate", "--wait", "120"],
                                  ["view", "--stream", "{s}", "--port", "{port}"]])
def test_ctrl_c_while_waiting_for_a_pipeline_is_an_interruption(files: Path, tool: list[str]) -> None:
    """Ctrl-C while ``gflow view`` waited for a pipeline to start said 'no pipeline started' and exited 1, as if
    a --duration had run out; echo and hz waiting said 'interrupted', exit 130. All three say it alike."""
    if tool[0] == "view":
        pytest.importorskip("foxglove")
    stream = f"notyet{os.getpid()}"  # started by no one: the tool waits until the SIGINT
    rc, err = _stops_on_sigint([a.format(s=stream, port=free_port()) for a in tool], "waiting", files)
    lines = err.strip().splitlines()
    assert rc == 130 and lines[-1] == f"gflow {tool[0]}: interrupted", err
    assert "no pipeline started" not in err and "Traceback" not in err, err


@pytest.mark.parametrize("argv,kept", [
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "old.csv", "--inline", "--no-record", "-q"],
     "old.csv"),
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "b.csv", "--points-out", "old.csv",
      "--tracker", "gflow", "--inline", "--no-record", "-q"], "old.csv"),
    (["boxes", "{d}/demo.mcap", "--out", "old.csv"], "old.csv"),
    (["learn", "m2", "{d}/frames", "--boxes", "{d}/gt.csv", "-K", "2", "--out", "old.npz", "-q"], "old.npz"),
    (["learn", "gflow", "{d}/nothing.npz", "--out", "old.npz", "-q"], "old.npz"),
    (["benchmark", "{d}/data", "--trackers", "dcf", "--opencv", "none", "--inline", "-q", "--plot", "old.png"],
     "old.png"),
    (["benchmark", "{d}/data", "--trackers", "dcf", "--opencv", "none", "--inline", "-q", "--precision-plot",
      "old.png"], "old.png"),
    (["benchmark", "{d}/data", "--trackers", "dcf", "--opencv", "none", "--inline", "-q", "--out-dir", "od"],
     "od/seqA/dcf.csv"),
    (["benchmark", "{d}/data", "--trackers", "dcf", "--opencv", "none", "--inline", "-q", "--out-dir", "od"],
     "od/seqA/static_box.csv"),
])
def test_no_command_writes_over_an_earlier_output(files: Path, tmp_path: Path, monkeypatch, capsys,
                                                   argv: list[str], kept: str) -> None:
    """Boxes, face points, a model or a plot already there were replaced without a word (a recording,
    picture or video already was refused); the earlier file is kept, and nothing is run."""
    seq = files / "data" / "seqA"
    if not seq.exists():  # a sequence folder for gflow benchmark
        (seq / "frames").mkdir(parents=True)
        for p in (files / "frames").iterdir():
            (seq / "frames" / p.name).write_bytes(p.read_bytes())
        (seq / "groundtruth.csv").write_bytes((files / "gt.csv").read_bytes())
    monkeypatch.chdir(tmp_path)
    (tmp_path / kept).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / kept).write_text("an earlier answer\n")
    rc, err = cli([a.replace("{d}", str(files)) for a in argv], capsys)
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("benchmark: skipped")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert kept in lines[0] and "exists" in lines[0] and ("never writes over" in lines[0]
                                                         or "never overwritten" in lines[0]), lines[0]
    assert (tmp_path / kept).read_text() == "an earlier answer\n"
    assert sorted(p.name for p in (tmp_path / kept).parent.iterdir()) == [Path(kept).name], "nothing written"


def test_a_new_output_is_still_written(files: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    rc, err = cli(["boxes", str(files / "demo.mcap"), "--out", "new.csv"], capsys)
    assert rc == 0 and (tmp_path / "new.csv").read_text().startswith("frame,x,y,w,h"), err


@pytest.mark.parametrize("argv", [["echo", "{s}/estimat", "--timeout", "1"],
                                  ["hz", "{s}/estimat", "--duration", "1", "--wait", "1"]])
def test_a_live_topic_that_nothing_publishes_is_named_with_what_does(replaying: str, capsys, argv: list[str]) -> None:
    """A mistyped topic waited in silence and then said only that nothing came."""
    rc, err = cli([a.replace("{s}", replaying) for a in argv], capsys)
    last = err.strip().splitlines()[-1]
    assert rc == 1 and f"gflow/{replaying}/estimat" in last, err
    assert f"gflow/{replaying}/ has:" in last and "estimate" in last.split("has:")[1] and "_status" not in last, last


def _refused_eval(files: Path, bad: Path, flag: str, capsys) -> str:
    """``gflow eval`` with ``bad`` as ``flag`` (the other file the good ground truth): its one line of refusal,
    asserted exit 2."""
    other = {"--pred": "--gt", "--gt": "--pred"}[flag]
    rc, err = cli(["eval", flag, str(bad), other, str(files / "gt.csv")], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("flag", ["--pred", "--gt"])
def test_a_frame_given_twice_in_a_boxes_file_is_refused(files: Path, tmp_path: Path, capsys, flag: str) -> None:
    """The later row replaced the earlier one without a word and was scored."""
    twice = tmp_path / "twice.csv"
    twice.write_text("frame,x,y,w,h\n0,10,10,20,20\n1,11,10,20,20\n0,40,40,20,20\n")
    assert f"{twice}:4: frame 0 again (first at line 2)" in _refused_eval(files, twice, flag, capsys)


def test_a_boxes_file_with_a_byte_order_mark_keeps_its_first_row(tmp_path: Path, capsys) -> None:
    """A file saved with a byte-order mark (some editors and spreadsheets write one) and no header had its first row
    skipped as a header: frame 0 was left out of the scores without a word."""
    from pipeline.evaluation.scored_boxes import read_scored_boxes

    plain, bom = tmp_path / "plain.csv", tmp_path / "bom.csv"
    plain.write_text("0,10,10,20,20\n1,10,10,20,20\n")
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    assert read_scored_boxes(bom).boxes == read_scored_boxes(plain).boxes == {0: (10.0, 10.0, 20.0, 20.0),
                                                                              1: (10.0, 10.0, 20.0, 20.0)}
    rc, err = cli(["eval", "--gt", str(bom), "--pred", str(plain)], capsys)
    assert rc == 0, err


@pytest.mark.parametrize("text", ["0\t10\t10\t20\t20\n", "0;10;10;20;20\n1;10;10;20;20\n", "0 10 10 20 20\n"])
def test_a_boxes_file_separated_by_other_than_commas_is_named_so(tmp_path: Path, capsys, text: str) -> None:
    """Its first line was skipped as a header: a one-row file was called "no boxes", and a longer one refused at its
    second line for its column count, neither naming the separator."""
    f = tmp_path / "tabs.csv"
    f.write_text(text)
    rc, err = cli(["eval", "--gt", str(f), "--pred", str(f)], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and f"{f}:1: numbers separated by tabs, semicolons or spaces" in lines[0], err


@pytest.mark.parametrize("flag", ["--pred", "--gt"])
def test_a_negative_frame_in_a_boxes_file_is_refused(files: Path, tmp_path: Path, capsys, flag: str) -> None:
    """A ground-truth row of frame -1 (no source has one) was scored as a frame the tracker missed."""
    neg = tmp_path / "neg.csv"
    neg.write_text("frame,x,y,w,h\n-1,10,10,20,20\n0,11,10,20,20\n")
    assert f"{neg}:2: frame -1: frame numbers start at 0" in _refused_eval(files, neg, flag, capsys)
    vis = tmp_path / "visible.csv"
    vis.write_text("frame,visible\n-1,1.0\n0,0.5\n")
    from pipeline.recording.results import read_visibility

    with pytest.raises(ValueError, match=r"visible.csv:2: frame -1: frame numbers start at 0"):
        read_visibility(vis)


def test_a_frame_given_twice_in_a_visibility_or_points_file_is_refused(tmp_path: Path) -> None:
    """As in a boxes file: the later row of a frame (or of a frame's landmark) replaced the earlier one."""
    from pipeline.io.landmarks import read_points
    from pipeline.recording.results import read_visibility

    vis = tmp_path / "visible.csv"
    vis.write_text("frame,visible\n0,1.0\n1,0.5\n0,0.0\n")
    with pytest.raises(ValueError, match=r"visible.csv:4: frame 0 again \(first at line 2\)"):
        read_visibility(vis)
    pts = tmp_path / "points.csv"
    pts.write_text("frame,landmark,x,y\n0,0,1,2\n0,1,3,4\n0,0,5,6\n")
    with pytest.raises(ValueError, match=r"points.csv:4: frame 0 landmark 0 again \(first at line 2\)"):
        read_points(pts)
    pts.write_text("frame,landmark,x,y\n0,0,1,2\n0,1,3,4\n1,0,5,6\n")  # the same landmark on another frame
    assert read_points(pts) == {0: {0: (1.0, 2.0), 1: (3.0, 4.0)}, 1: {0: (5.0, 6.0)}}


@pytest.mark.parametrize("stop,said", [("99", True), ("6", False), ("4", False)])
def test_a_stop_past_the_end_of_the_frames_is_said(files: Path, tmp_path: Path, capsys, stop: str, said: bool) -> None:
    """--stop 99 on six frames tracked frames 0-5 and said only "tracked 6 frames", as if --stop had been met."""
    from pipeline.cli.main import main

    capsys.readouterr()
    assert main(["track", str(files / "frames"), "--init", "10,10,20,20", "--out", str(tmp_path / "b.csv"), "--inline",
                 "--no-record", "-q", "--stop", stop]) == 0
    out = capsys.readouterr().out
    assert (f"--stop {stop} is past the end of {files / 'frames'}: its last frame is 5, tracked to it" in out) == said, out


@pytest.mark.parametrize("extra,words", [
    (["--start", "4", "--stop", "2"], ["--start 4 --stop 2", "no frame to track"]),
    (["--stop", "0"], ["--stop", ">= 1"]),
    (["--start=-1"], ["--start", ">= 0"]),
    (["--fps", "0"], ["--fps", ">= 0.001"]),
])
def test_a_frame_range_or_rate_out_of_range_names_the_option(files: Path, tmp_path: Path, capsys, extra: list[str],
                                                             words: list[str]) -> None:
    """These were refused naming the built-in graph file and its source stage, not the option typed."""
    rc, err = cli(["track", str(files / "frames"), "--init", "10,10,20,20", "--out", str(tmp_path / "b.csv"),
                    "--inline", "--no-record", "-q", *extra], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and ".yaml" not in lines[0], err
    assert all(w in lines[0] for w in words), lines[0]
    assert not (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("argv,what", [
    (["boxes", "{d}/demo.mcap", "--out", "{link}"], "--out"),
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "{link}", "--inline", "--no-record", "-q"], "--out"),
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "b.csv", "--record", "{link}", "--inline", "-q"],
     "--record"),
    (["demo", "--frames", "3", "--inline", "--record", "{link}"], "--record"),
    (["rerun", "{d}/demo.mcap", "--graph", "--out", "{link}"], "--out"),
    (["recover", "{d}/demo.mcap", "{link}"], "FIXED"),
    (["foxglove", "{d}/demo.mcap", "{link}"], "OUT"),
    (["render", "{d}/demo.mcap", "{link}.mp4"], "OUT"),
    (["render", "{d}/demo.mcap", "{link}"], "OUT"),  # a folder of PNG frames
    (["plot", "{d}/demo.mcap", "{link}.png"], "OUT"),
    (["frame", "{d}/frames", "0", "{link}.png"], "OUT"),
    (["learn", "m2", "{d}/frames", "--boxes", "{d}/gt.csv", "-K", "2", "--out", "{link}.npz", "-q"], "--out"),
    (["learn", "gflow", "{d}/nothing.npz", "--out", "{link}.npz", "-q"], "--out"),
    (["benchmark", "{d}/frames", "--plot", "{link}.png"], "--plot"),
    (["benchmark", "{d}/frames", "--out-dir", "{link}"], "--out-dir"),
    (["export", "vot", "{d}/frames", "{link}"], "OUT"),
    (["trax", "--out", "{link}"], "--out"),  # refused before the server starts (its folder is not there either)
])
def test_an_output_named_by_a_dangling_link_is_refused_as_one(files: Path, tmp_path: Path, monkeypatch, capsys,
                                                             argv: list[str], what: str) -> None:
    """An output path that is a symbolic link to nothing was refused with the system's 'File exists' (of a file
    that is not there), or, for a folder, as 'folder . does not exist' or a failed run. It is named as a
    dangling symbolic link, with where it points, before any work; nothing is written through it."""
    if argv[0] == "trax":
        pytest.importorskip("trax")
    monkeypatch.chdir(tmp_path)
    args = [a.replace("{d}", str(files)).replace("{link}", "out") for a in argv]
    link = next(a for a in args if a.startswith("out"))
    (tmp_path / link).symlink_to(tmp_path / "gone" / "nothing")
    rc, err = cli(args, capsys)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert f"{what} {link} is a dangling symbolic link (to {tmp_path / 'gone' / 'nothing'}" in lines[0], lines[0]
    assert "File exists" not in lines[0] and (tmp_path / link).is_symlink() and not (tmp_path / "gone").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [link], list(tmp_path.iterdir())


def test_a_frame_past_the_end_of_a_torn_recording_says_it_is_torn(files: Path, tmp_path: Path, capsys) -> None:
    """It said only that there is no such frame, as of a recording that ended there (then after a
    warning line that the file was torn: the error itself says it now, in one line)."""
    torn = tmp_path / "torn.mcap"
    data = (files / "demo.mcap").read_bytes()
    torn.write_bytes(data[: len(data) // 2])
    rc, err = cli(["frame", str(torn), "9", str(tmp_path / "f.png")], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert "no frame at or after frame 9: it ends early" in lines[0] and "gflow recover" in lines[0], lines[0]


@pytest.mark.parametrize("argv", [["ps", "--stream", "nosuch"], ["topics", "--stream", "nosuch", "--duration", "0.5"],
                                  ["echo", "nosuch/estimate", "--timeout", "0.5"],
                                  ["view", "--stream", "nosuch", "--duration", "0.5"]])
def test_a_stream_that_is_not_running_is_named_with_those_that_are(replaying: str, capsys, argv: list[str]) -> None:
    """A mistyped stream was said to run nowhere 'on this machine', as if nothing ran at all."""
    capsys.readouterr()
    try:
        rc = main(argv)
    except SystemExit as e:
        rc = int(e.code or 0)
    out = capsys.readouterr()
    last = (out.out + out.err).strip().splitlines()[-1]
    assert rc != 0 and "nosuch" in last and "running: " in last and replaying in last.split("running: ")[1], last


def test_boxes_of_a_stream_the_recording_lacks_names_the_one_it_has(files: Path, tmp_path: Path, capsys) -> None:
    rc, err = cli(["boxes", str(files / "demo.mcap"), "--out", str(tmp_path / "b.csv"), "--stream", "cam9"], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "'cam9'" in lines[0], err
    assert lines[0].endswith("it holds estimates of stream demo"), lines[0]


def test_an_inline_track_stopped_by_ctrl_c_keeps_its_boxes(tmp_path: Path) -> None:
    """As a multi-process run: the boxes of the frames tracked are written, and the recording is
    closed. Inline, the run ended in 'interrupted' with no boxes at all."""
    rng = np.random.default_rng(1)
    (tmp_path / "frames").mkdir()
    for i in range(200):
        cv2.imwrite(str(tmp_path / "frames" / f"{i:04d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    c = _Started(["track", "frames", "--init", "10,10,20,20", "--inline", "--realtime", "--fps", "20", "--out", "b.csv",
                  "--record", "r.mcap"], tmp_path, ignore_sigint=False)
    try:
        c.wait_for("/200 frames")  # the progress line: frames are being tracked
        c.p.send_signal(signal.SIGINT)
        rc = c.p.wait(60)
        c.reader.join(10)
    finally:
        c.stop()
    out = "".join(c.err)
    assert rc == 130 and "interrupted: stages closed, recording closed" in out and "Traceback" not in out, out
    rows = (tmp_path / "b.csv").read_text().splitlines()
    assert rows[0].startswith("frame,x,y,w,h") and 2 <= len(rows) < 201, out
    assert main(["verify", str(tmp_path / "r.mcap")]) == 0
