"""Answers a user can trust: a mistake on the command line is one line naming it, found before
any work; no command writes over a recording; a restarted recorder's count goes on.

The mistakes run in this process (``main([...])``, as ``gflow`` runs them, without the start-up
of a new interpreter per case) on tiny image folders and a short recording of the synthetic
scene written into tmp folders; the restarted recorder is a real multi-process run.
"""

from __future__ import annotations

import importlib.util
import os
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
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.launcher import Launcher
from pipeline.runtime.transport import ZenohSettings, free_port
import cli_fork


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """A folder with frames/ (six 64x48 textured frames), broken/ (the same, frame 3 not an
    image), demo.mcap (10 frames of the synthetic scene, inline) and dcf.mcap (gflow track of frames/)."""
    d = tmp_path_factory.mktemp("trust")
    rng = np.random.default_rng(0)
    for name in ("frames", "broken"):
        (d / name).mkdir()
        for i in range(6):
            cv2.imwrite(str(d / name / f"{i:04d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    (d / "broken" / "0003.png").write_bytes(b"not a png")
    assert main(["demo", "--frames", "10", "--inline", "--record", str(d / "demo.mcap")]) == 0
    assert main(["track", str(d / "frames"), "--init", "10,10,20,20", "--out", str(d / "dcf.csv"), "--inline", "-q",
                 "--record", str(d / "dcf.mcap")]) == 0
    return d




def one_line_error(rc: int, err: str, *words: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc != 0 and len(lines) == 1, (rc, err)
    assert "internal error" not in lines[0] and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("argv,words", [
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "b.csv", "--tracker", "gflow", "--shards", "0"],
     ["--shards", ">= 1"]),
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "b.csv", "--record-topics", "estimat"],
     ["--record-topics", "'estimat'", "estimate"]),
    (["demo", "--frames", "3", "--inline", "--record-topics", "nosuch"], ["--record-topics", "'nosuch'"]),
    (["demo", "--frames", "3", "--inline", "--seed", "-1"], ["--seed -1"]),
    (["replay", "{d}/demo.mcap", "--max", "--start", "-1"], ["--start", ">= 0"]),
    (["replay", "{d}/demo.mcap", "--max", "--start", "nan"], ["--start", ">= 0"]),
    (["replay", "{d}/demo.mcap", "--max", "--lockstep", "filter", "--ack-timeout", "-1"], ["--ack-timeout"]),
    (["render", "{d}/demo.mcap", "o.mp4", "--scale", "0", "-q"], ["--scale", ">= 1"]),
    (["render", "{d}/demo.mcap", "o.mp4", "--fps", "nan", "-q"], ["--fps", ">= 0.01"]),
    (["foxglove", "{d}/demo.mcap", "f.mcap", "--quality", "0"], ["--quality", "1-100"]),
    (["foxglove", "{d}/demo.mcap", "f.mcap", "--quality", "101"], ["--quality", "1-100"]),
    (["frame", "{d}/frames", "0", "f.xyz"], ["f.xyz", "'.xyz'"]),
    (["frame", "{d}/frames", "0", "f.png", "--grid", "-5"], ["--grid", ">= 1"]),
    (["frame", "{d}/frames", "0", "f.png", "--scale", "0"], ["--scale", ">= 1"]),
    (["eval", "--gt", "{d}/gt.csv", "--pred", "{d}/gt.csv", "--threshold", "2"], ["--threshold", "[0, 1]"]),
    (["eval", "--gt", "{d}/gt.csv", "--pred", "{d}/gt.csv", "--threshold", "nan"], ["--threshold", "[0, 1]"]),
    (["eval", "--gt", "{d}/gt.csv", "--pred", "{d}/demo.mcap"], ["demo.mcap", "not a box CSV"]),
    (["learn", "m2", "{d}/frames", "-K", "2", "--blur", "-1", "--out", "m.npz", "-q"], ["--blur", ">= 0"]),
    (["learn", "m2", "{d}/frames", "-K", "2", "--g0", "nan", "--out", "m.npz", "-q"], ["--g0", "> 0"]),
    (["echo", "demo/estimate", "-n", "0", "--timeout", "0.5"], ["--count", ">= 1"]),
    (["pub", "gflow/demo/_control", "Control", '{"command": "stop"}', "-n", "0"], ["--count", ">= 1"]),
    (["pub", "gflow/demo/_control", "Control", '{"command": "stop"}', "--seq", "-1"], ["--seq", ">= 0"]),
    (["view", "--port", "99999", "--duration", "0.5"], ["--port", "1-65535"]),
    (["benchmark", "{d}", "--json", "--markdown"], ["--markdown", "--json"]),
    # the CSV was written over the recording at the end of the run; the points over the boxes
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "r.mcap", "--record", "r.mcap"],
     ["--record r.mcap is also --out"]),
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "b.csv", "--points-out", "./b.csv", "--tracker",
      "gflow"], ["--points-out ./b.csv is also --out"]),
    # the model was written over a training frame
    (["learn", "m2", "{d}/frames", "--metric", "l2", "-K", "2", "--out", "{d}/frames/0001.png", "-q"],
     ["0001.png", "ends in .npz"]),
])
def test_mistake_is_one_line_before_any_work(files: Path, tmp_path: Path, monkeypatch, capsys, argv: list[str],
                                             words: list[str]) -> None:
    (files / "gt.csv").write_text("frame,x,y,w,h\n0,10,10,20,20\n1,11,10,20,20\n")
    monkeypatch.chdir(tmp_path)
    frame = (files / "frames" / "0001.png").read_bytes()
    rc, err = cli([a.replace("{d}", str(files)) for a in argv], capsys)
    one_line_error(rc, err, *words)
    assert not list(tmp_path.iterdir()), "nothing is written before a mistake is found"
    assert (files / "frames" / "0001.png").read_bytes() == frame


@pytest.mark.parametrize("argv,option", [
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "{x}", "--no-record", "--inline", "-q"], "--out"),
    (["track", "{d}/frames", "--init", "10,10,20,20", "--out", "b.csv", "--points-out", "{x}", "--tracker",
      "gflow", "--no-record", "--inline", "-q"], "--points-out"),
    (["boxes", "{d}/demo.mcap", "--out", "{x}"], "--out"),
    (["learn", "m2", "{d}/frames", "--metric", "l2", "-K", "2", "--out", "{x}", "-q"], "--out"),
    (["frame", "{d}/frames", "0", "{x}"], "OUT"),
    (["trax", "--out", "{x}"], "--out"),  # in a process of its own: gflow trax execs its server
])
def test_no_command_writes_over_a_recording(files: Path, tmp_path: Path, monkeypatch, capsys, argv: list[str],
                                            option: str) -> None:
    """A CSV, model or picture given the name of an existing recording (whatever its name) is refused
    and the recording is left as it was: these commands wrote over it."""
    if argv[0] == "trax" and importlib.util.find_spec("trax") is None:
        pytest.skip("gflow trax needs the vot-trax package")
    monkeypatch.chdir(tmp_path)
    x = tmp_path / "kept.csv"  # a recording under any name is one
    before = (files / "demo.mcap").read_bytes()
    x.write_bytes(before)
    args = [a.replace("{d}", str(files)).replace("{x}", str(x)) for a in argv]
    if argv[0] == "trax":
        r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args], capture_output=True, text=True,
                                 timeout=60, stdin=subprocess.DEVNULL)
        rc, err = r.returncode, r.stderr
    else:
        rc, err = cli(args, capsys)
    one_line_error(rc, err, option, "is a recording", "never writes over")
    assert x.read_bytes() == before


@pytest.mark.parametrize("graph", ["gflow", "dcf", "chamfer"])
def test_a_graph_without_its_initial_box_is_one_message(files: Path, tmp_path: Path, monkeypatch, capsys,
                                                        graph: str) -> None:
    """The same words for every tracker, naming every stage that lacks the box; the G-flow graph ran
    without one, warned at frame 0 that it could not start and exited 0."""
    monkeypatch.chdir(tmp_path)
    rc, err = cli(["run", graph, "--inline", "--set", f"source.path={files / 'frames'}"], capsys)
    line = one_line_error(rc, err, "need", "an initial box: set init: [x, y, w, h]", ".init=[X,Y,W,H]",
                          "--init X,Y,W,H")
    assert ("'proposal'" in line) == (graph != "chamfer") and "'filter'" in line, line
    assert not list(tmp_path.rglob("*.mcap"))


def test_learn_says_a_skipped_frame_even_when_quiet(files: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    """-q silences progress, not damaged input: the model was written from five of six frames
    without a word."""
    monkeypatch.chdir(tmp_path)
    rc, err = cli(["learn", "m2", str(files / "broken"), "--metric", "l2", "-K", "2", "--out", "m.npz", "-q"], capsys)
    assert rc == 0 and (tmp_path / "m.npz").is_file()
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        "warning: frame 3 skipped: 0003.png is not a decodable image (9 bytes)"], err


def test_a_restarted_recorder_counts_on(tmp_path: Path) -> None:
    """The recorder's heartbeat counts its messages; one killed and restarted (a new segment file)
    goes on from what the one before reported, as a restarted stage's steps do, instead of from 0."""
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 150, "realtime": True, "fps": 30},
                                                        "filter": {"particles": 100}}))
    seen: list[tuple[int, int]] = []  # (pid, steps) of the recorder's heartbeats, in order
    launcher = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)),
                        recording=str(tmp_path / "run.mcap"), progress=False,
                        on_status=lambda st: seen.append((st["recorder"].pid, st["recorder"].steps))
                        if "recorder" in st else None)
    th = threading.Thread(target=launcher.run, daemon=True)
    th.start()
    deadline = time.monotonic() + 120
    while not seen or seen[-1][1] < 150:
        assert time.monotonic() < deadline and th.is_alive(), f"the recorder reported only {seen[-1:]}"
        time.sleep(0.05)
    first = launcher.pids["recorder"][0]
    os.kill(first, signal.SIGKILL)
    while not any(pid != first for pid, _ in seen):
        assert time.monotonic() < deadline and th.is_alive(), "the recorder was not restarted"
        time.sleep(0.05)
    th.join(120)
    before = max(steps for pid, steps in seen if pid == first)
    after = [steps for pid, steps in seen if pid != first]
    assert after[0] >= before, (before, after[:5])
    assert after == sorted(after)
    assert (tmp_path / "run.part1.mcap").is_file()  # the restarted recorder wrote the rest to its segment


def test_a_foxglove_copy_verifies(files: Path, tmp_path: Path, capsys) -> None:
    """gflow verify read the Foxglove images of a gflow foxglove copy (protobuf) as gflow's own
    messages and called every copy DAMAGED, with nothing to salvage."""
    copy = tmp_path / "fox.mcap"
    assert cli(["foxglove", str(files / "demo.mcap"), str(copy)], capsys)[0] == 0
    capsys.readouterr()
    assert main(["verify", str(copy)]) == 0
    out = capsys.readouterr().out
    assert "OK" in out and "DAMAGED" not in out, out
    # and a payload that is not the schema's message is still found (a protobuf varint tag running past the end)
    from mcap.reader import make_reader

    from pipeline.recording.verify import _protobuf_decoder

    with open(copy, "rb") as f:
        schema = next(s for s in make_reader(f).get_summary().schemas.values()
                      if s.name == "foxglove.CompressedImage")
    with pytest.raises(Exception, match="not a protobuf foxglove.CompressedImage"):
        _protobuf_decoder(schema)(b"\x0a\xff\xff\xff\xff\x0f")


def test_an_out_dir_used_before_is_refused_not_skipped(files: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    """gflow benchmark --out-dir where a run's recording already is: every such run was 'skipped' and
    the benchmark exited 0 having run no tracker."""
    seq = tmp_path / "data" / "seqA"
    (seq / "frames").mkdir(parents=True)
    for p in (files / "frames").iterdir():
        (seq / "frames" / p.name).write_bytes(p.read_bytes())
    (seq / "groundtruth.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(6)))
    kept = tmp_path / "od" / "seqA" / "dcf.mcap"
    kept.parent.mkdir(parents=True)
    kept.write_bytes((files / "demo.mcap").read_bytes())
    monkeypatch.chdir(tmp_path)
    rc, err = cli(["benchmark", str(tmp_path / "data"), "--trackers", "dcf", "--inline", "-q", "--out-dir", "od"],
                  capsys)
    one_line_error(rc, err, "--out-dir od", "dcf.mcap exists", "never overwritten")
    assert kept.read_bytes() == (files / "demo.mcap").read_bytes()
    assert sorted(p.name for p in kept.parent.iterdir()) == ["dcf.mcap"], "nothing run before the refusal"


def test_output_to_a_closed_pipe_is_no_error(files: Path) -> None:
    """``gflow info r.mcap | head -1``: the reader going away printed 'gflow info: error: Broken pipe'."""
    p = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "info", str(files / "demo.mcap")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()  # before it writes: its first line goes to a pipe nobody reads
    err = p.stderr.read().decode()
    assert p.wait(60) == 141 and err == "", err


def test_a_negative_value_is_explained(files: Path, capsys) -> None:
    """--init -5,50,20,30 (a box from left of the image) said only 'expected one argument'."""
    rc, err = cli(["track", str(files / "frames"), "--init", "-5,10,20,20", "--out", "b.csv"], capsys)
    one_line_error(rc, err, "--init", "--init=-5")


@pytest.mark.parametrize("argv,words", [
    # a box outside the frame ran, warned on every frame and exited 0 (gflow track checked --init)
    (["run", "demo", "--inline", "--set", "source.frames=3", "--set", "filter.init=[1000,1000,5,5]"],
     ["stage 'filter' init:", "outside the 320x240 image"]),
    # the first frame of a graph's folder cannot be read: said before the run, as gflow track does
    (["run", "dcf", "--inline", "--set", "source.path={d}/broken", "--set", "source.start=3", "--set",
      "filter.init=[1,1,9,9]", "--set", "proposal.init=[1,1,9,9]"], ["frame 3 cannot be read"]),
    # a file that is not a model went into trackers.ini and failed when the toolkit ran it
    (["export", "vot", "{d}", "ws", "--m2-model", "{d}/gt.csv"], ["--m2-model", "gt.csv"]),
    # named '--set tracker.NAME', not the value refused
    (["rerun", "{d}/dcf.mcap", "--graph", "--set", "tracker.particles=0"], ["--set tracker.particles=0", ">= 1"]),
    # an empty file was also 'not closed properly', a warning line before the error
    (["track", "{d}/empty.mcap", "--init", "1,1,5,5", "--out", "b.csv"], ["empty.mcap", "not an MCAP file"]),
])
def test_more_mistakes_before_any_work(files: Path, tmp_path: Path, monkeypatch, capsys, argv: list[str],
                                       words: list[str]) -> None:
    (files / "gt.csv").write_text("frame,x,y,w,h\n0,10,10,20,20\n")
    (files / "empty.mcap").write_bytes(b"")
    monkeypatch.chdir(tmp_path)
    rc, err = cli([a.replace("{d}", str(files)) for a in argv], capsys)
    one_line_error(rc, err, *words)
    assert not list(tmp_path.iterdir()), "nothing is written before a mistake is found"


def test_damage_inside_a_recording_is_said(files: Path, tmp_path: Path) -> None:
    """A chunk that fails its CRC in the middle of a recording (its end intact, so not 'torn'): plot,
    render, replay, foxglove, diff and track --inline showed or computed what came before it and said
    nothing; now one warning line names the file and the byte."""
    from conftest import damaged_copy

    bad = damaged_copy(files / "demo.mcap", tmp_path / "bad.mcap")
    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "plot", str(bad), str(tmp_path / "p.png")],
                             capture_output=True, text=True, timeout=120)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    # the plot of what came before the damage is kept, but not reported as the whole run's (exit 1), in one line
    assert r.returncode == 1 and (tmp_path / "p.png").is_file(), r.stderr
    assert len(lines) == 1 and "p.png holds only what was read before the damage: " in lines[0], r.stderr
    assert "bad.mcap: recording is damaged at byte" in lines[0], r.stderr


def test_trax_checks_the_values_it_is_given(tmp_path: Path) -> None:
    """gflow trax --set particles=abc started the TraX server, which ended in a traceback."""
    if importlib.util.find_spec("trax") is None:
        pytest.skip("gflow trax needs the vot-trax package")
    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "trax", "--set", "particles=abc"],
                             capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL, cwd=tmp_path)
    one_line_error(r.returncode, r.stderr, "--set particles=abc", "particles must be a whole number")
    assert "@@TRAX" not in r.stdout, "refused before the server starts"
