"""A user's mistakes on the real ``gflow`` command line: each is one line on stderr naming what
was wrong, a non-zero exit, no traceback, and nothing run or written before it is found.

Every case runs the CLI in a process of its own, as a user would: forked from one that has imported the
command line once (``tests/cli_fork.py``: a new interpreter's start and imports were most of each case's
CPU), or a new interpreter where a case limits the process (its file sizes). The sources are tiny image
folders written into tmp_path, so no case needs ../shared/data.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

import cli_fork

ROOT = Path(__file__).resolve().parent.parent


def gflow(*args: str, cwd: Path, timeout: float = 60.0, env: dict[str, str] | None = None,
          **popen) -> subprocess.CompletedProcess:
    """``gflow ARGS`` in a process of its own: forked from a process that has imported the command line
    (:mod:`cli_fork`), or, given ``subprocess.run`` options (``preexec_fn``...), a new interpreter."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), **(env or {}))
    if not popen:
        return cli_fork.run(list(args), cwd=cwd, env=env, timeout=timeout)
    return subprocess.run([sys.executable, "-m", "pipeline.cli.main", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout, **popen)


def assert_one_line_error(r: subprocess.CompletedProcess, *words: str) -> str:
    assert r.returncode != 0, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


@pytest.fixture()
def frames(tmp_path: Path) -> Path:
    """Five 64x48 textured frames in a folder."""
    d = tmp_path / "frames"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(5):
        cv2.imwrite(str(d / f"{i:04d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    return d


@pytest.fixture(scope="module")
def demo_mcap(tmp_path_factory) -> Path:
    """A closed recording of 20 frames of the synthetic scene (``gflow demo --inline``); tests cut copies of it."""
    where = tmp_path_factory.mktemp("demo")
    r = gflow("demo", "--frames", "20", "--inline", "--record", "demo.mcap", cwd=where)
    assert r.returncode == 0, r.stderr
    return where / "demo.mcap"


def one_sequence(tmp_path: Path, frames: Path) -> Path:
    """``tmp_path/data/s``, a sequence folder: ``frames`` moved into it and a box of ground truth on each of them."""
    seq = tmp_path / "data" / "s"
    seq.mkdir(parents=True)
    frames.rename(seq / "frames")
    (seq / "groundtruth.csv").write_text("".join(f"{f},10,10,20,20\n" for f in range(5)))
    return seq


def torn_copy(rec: Path, dest: Path, size: int) -> Path:
    """The first ``size`` bytes of ``rec`` in ``dest``: a recording whose writer was killed there."""
    dest.write_bytes(rec.read_bytes()[:size])
    return dest


def _no_recording(cwd: Path) -> None:
    assert not list(cwd.rglob("*.mcap")), "a mistake found before the start must not leave a recording"


@pytest.mark.parametrize("opt", ["--out", "--record"])
def test_track_output_is_a_folder(tmp_path: Path, frames: Path, opt: str) -> None:
    other = ["--out", "b.csv"] if opt == "--record" else []
    r = gflow("track", str(frames), "--init", "10,10,20,20", opt, str(tmp_path), *other, cwd=tmp_path)
    assert_one_line_error(r, opt, "folder")
    _no_recording(tmp_path)


def test_track_output_unwritable_is_refused_before_tracking(tmp_path: Path, frames: Path) -> None:
    (tmp_path / "afile").write_text("x")
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", str(tmp_path / "afile" / "b.csv"), cwd=tmp_path)
    assert_one_line_error(r, "--out", "cannot")
    _no_recording(tmp_path)


def test_box_outside_the_first_frame(tmp_path: Path, frames: Path) -> None:
    r = gflow("track", str(frames), "--init", "100,10,20,20", "--out", "b.csv", "--inline", cwd=tmp_path)
    assert_one_line_error(r, "--init", "outside", "64x48")
    assert not (tmp_path / "b.csv").exists()
    _no_recording(tmp_path)


def test_start_beyond_the_source(tmp_path: Path, frames: Path) -> None:
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--start", "500", cwd=tmp_path)
    assert_one_line_error(r, "--start 500", "5 frames")
    _no_recording(tmp_path)


def test_text_file_named_mp4(tmp_path: Path) -> None:
    (tmp_path / "clip.mp4").write_text("not a video\n")
    r = gflow("track", "clip.mp4", "--init", "10,10,20,20", "--out", "b.csv", cwd=tmp_path)
    line = assert_one_line_error(r, "clip.mp4")  # FFmpeg's own line was left out; its reason is now in gflow's
    assert "video" in line and line.endswith("moov atom not found)") and " @ 0x" not in r.stderr, line
    _no_recording(tmp_path)


@pytest.mark.parametrize("tracker,extra,named", [
    ("chamfer", ["--model", "m.npz"], "--model"),
    ("chamfer", ["--experts", "3"], "--experts"),
    ("gflow", ["--particles", "300"], "--particles"),
    ("m2", ["--experts", "3", "--model", "m.npz"], "--experts"),
])
def test_option_of_another_tracker(tmp_path: Path, frames: Path, tracker: str, extra: list[str], named: str) -> None:
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--tracker", tracker, *extra,
              cwd=tmp_path)
    assert_one_line_error(r, named, f"not of --tracker {tracker}")


def test_graph_feeding_a_stage_its_own_output(tmp_path: Path) -> None:
    (tmp_path / "cycle.yaml").write_text(
        "name: cyc\nstream: cam0\nstages:\n"
        "  source: {kind: source, params: {kind: synthetic, frames: 5}}\n"
        "  preprocess: {kind: preprocess, inputs: {frames: frames}}\n"
        "  filter:\n    kind: particle.filter\n    inputs: {features: features, proposals: particles}\n"
        "    params: {init: [10, 20, 30, 40]}\n")
    r = gflow("run", "cycle.yaml", cwd=tmp_path, timeout=30)
    assert_one_line_error(r, "cycle.yaml:", "filter", "its own output", "never start")


@pytest.mark.parametrize("argv,named", [
    (["run", "demo", "--record", "{tmp}"], "--record"),
    (["demo", "--record", "{tmp}"], "--record"),
    (["recover", "x.mcap", "{tmp}"], "folder"),
    (["rerun", "x.mcap", "--graph", "--out", "{tmp}"], "--out"),
    (["render", "x.mcap", "{tmp}/out.xyz"], ".xyz"),
    (["plot", "x.mcap", "{tmp}"], "folder"),
])
def test_other_commands_refuse_bad_outputs_first(tmp_path: Path, argv: list[str], named: str) -> None:
    (tmp_path / "x.mcap").write_bytes(b"")  # the input exists; the output is what is wrong
    r = gflow(*(a.replace("{tmp}", str(tmp_path)) for a in argv), cwd=tmp_path)
    assert_one_line_error(r, named)
    assert not (tmp_path / "out.xyz").exists()


@pytest.mark.parametrize("speed", ["0", "-1", "nan"])
def test_replay_speed_must_be_positive(tmp_path: Path, speed: str) -> None:
    r = gflow("replay", "x.mcap", f"--speed={speed}", cwd=tmp_path)
    assert_one_line_error(r, "--speed", "> 0")


@pytest.mark.parametrize("opt,value,named", [("--loop", "-1", ">= 0"), ("--from-seq", "-3", ">= 0"),
                                              ("--to-seq", "x", "whole number")])
def test_replay_counts_must_be_whole_and_not_negative(tmp_path: Path, opt: str, value: str, named: str) -> None:
    """``--loop -1`` replayed nothing and said so as a success."""
    r = gflow("replay", "x.mcap", f"{opt}={value}", cwd=tmp_path)
    assert_one_line_error(r, opt, named)


@pytest.mark.parametrize("endpoint", ["foo", "tcp/127.0.0.1", "tcp/127.0.0.1:99999"])
def test_malformed_endpoint(tmp_path: Path, endpoint: str) -> None:
    r = gflow("topics", "--connect", endpoint, cwd=tmp_path)
    assert_one_line_error(r, "--connect", repr(endpoint)[1:-1])


def test_version(tmp_path: Path) -> None:
    r = gflow("--version", cwd=tmp_path)
    assert r.returncode == 0
    assert r.stdout.startswith("gflow ") and "zenoh" in r.stdout


@pytest.mark.parametrize("argv,said", [
    (["track", "data/s/frames", "--init", "10,10,20,20", "--out", "b.csv", "--tracker", "gflow", "--model", "nosuch"],
     "--model nosuch: model file not found, and not a built-in model of --tracker gflow (face, ellipsoid)"),
    (["track", "data/s/frames", "--init", "10,10,20,20", "--out", "b.csv", "--tracker", "m2", "--model", "nosuch"],
     "--model nosuch: model file not found"),
    (["benchmark", "data", "--trackers", "gflow", "--gflow-model", "nosuch"],
     "--gflow-model nosuch: model file not found, and not a built-in model of --tracker gflow (face, ellipsoid)"),
    (["export", "vot", "data", "ws", "--gflow-model", "nosuch"],
     "--gflow-model nosuch: model file not found, and not a built-in model of --tracker gflow (face, ellipsoid)"),
    (["trax", "--tracker", "gflow", "--model", "nosuch"],
     "--model nosuch: model file not found, and not a built-in model of --tracker gflow (face, ellipsoid)"),
])
def test_a_model_that_names_nothing_names_its_option(tmp_path: Path, frames: Path, argv: list[str], said: str) -> None:
    """``--tracker gflow --model nosuch`` said "model file not found: nosuch", naming neither the option nor the
    built-in models (face, ellipsoid); m2's and gflow trax's said the same, and ``gflow export vot --gflow-model
    nosuch`` wrote a workspace whose gflow tracker could never start."""
    if argv[0] == "trax":
        pytest.importorskip("trax")
    one_sequence(tmp_path, frames)
    r = gflow(*argv, cwd=tmp_path)
    assert_one_line_error(r, f" error: {said}")
    assert r.returncode == 2 and sorted(p.name for p in tmp_path.iterdir()) == ["data"], "nothing written"


def test_whole_frame_model_on_other_video(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    for name, shape in (("small", (24, 32)), ("big", (48, 64))):
        (tmp_path / name).mkdir()
        for i in range(8):
            cv2.imwrite(str(tmp_path / name / f"{i:03d}.png"), rng.integers(0, 255, shape, dtype=np.uint8))
    r = gflow("learn", "m2", "small", "--metric", "l2", "-K", "2", "--out", "m.npz", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = gflow("track", "big", "--tracker", "m2", "--model", "m.npz", "--init", "1,1,10,10", "--out", "o.csv",
              "--inline", cwd=tmp_path)
    assert_one_line_error(r, "m.npz", "32x24", "64x48")
    _no_recording(tmp_path)


def test_default_recording_folder_unusable(tmp_path: Path, frames: Path) -> None:
    (tmp_path / "recordings").write_text("a file where the default recordings/ folder would go")
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", cwd=tmp_path)
    assert_one_line_error(r, "the recording", "recordings")
    assert not (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("argv,named", [
    (["replay", "junk.mcap"], "not an MCAP file"),
    (["replay", "missing.mcap"], "not found"),
    (["hz", "demo/frames", "--window", "0"], "--window"),
    (["pub", "gflow/demo/_control", "Control", "{not json"], "JSON"),
    (["pub", "gflow/demo/_control", "NoSuchType", "{}"], "NoSuchType"),
])
def test_live_tool_mistakes(tmp_path: Path, argv: list[str], named: str) -> None:
    (tmp_path / "junk.mcap").write_text("junk\n")
    r = gflow(*argv, cwd=tmp_path)
    assert_one_line_error(r, named)


@pytest.mark.parametrize("index", [0, 3])
def test_frame_of_a_corrupt_image_is_named(tmp_path: Path, frames: Path, index: int) -> None:
    (frames / f"{index:04d}.png").write_bytes(b"not a png")
    r = gflow("frame", str(frames), str(index), "f.png", cwd=tmp_path)
    line = assert_one_line_error(r, f"frame {index}", "cannot be read")
    assert ("first frame" in line) == (index == 0), line
    assert not (tmp_path / "f.png").exists()


@pytest.mark.parametrize("argv", [["track", "frames", "--init", "1,1,5,5", "--out", "b.csv"],
                                  ["benchmark", "data"], ["trax"]])
def test_a_negative_seed_is_refused_as_the_option(tmp_path: Path, argv: list[str]) -> None:
    """``--seed -1`` was refused by a stage of the built-in graph, naming its YAML file and line."""
    r = gflow(*argv, "--seed=-1", cwd=tmp_path)
    line = assert_one_line_error(r, "--seed", ">= 0")
    assert ".yaml" not in line


@pytest.mark.parametrize("argv,named,hint", [
    (["track", "frames", "--init", "1,1,5,5", "--out", "b.csv", "--trakcer", "dcf"], "--trakcer", "--tracker?"),
    (["track", "frames", "--init", "1,1,5,5", "--out", "b.csv", "--seeed=3"], "--seeed=3", "--seed?"),
    (["render", "r.mcap", "--out", "x.mp4"], "--out", "without --out"),
    (["boxes", "r.mcap", "--out", "b.csv", "extra"], "extra", None),
])
def test_an_unknown_argument_is_named_by_its_command(tmp_path: Path, frames: Path, argv: list[str], named: str,
                                                     hint: str | None) -> None:
    """argparse reports an argument no option takes as the top-level ``gflow``'s mistake, pointing at
    ``gflow --help``, which does not list the command's options; it is the command's, with its closest
    option (or, for an option that is a positional, how it is given)."""
    r = gflow(*argv, cwd=tmp_path)
    line = assert_one_line_error(r, f"gflow {argv[0]}: error: unrecognized arguments:", named,
                                 f"'gflow {argv[0]} --help'")
    if hint is not None:
        assert hint in line, line
    else:
        assert "did you mean" not in line, line
    _no_recording(tmp_path)
    assert not (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("content", [b"", b"garbage\n"])
def test_foxglove_refuses_a_non_mcap_input_before_writing_out(tmp_path: Path, content: bytes) -> None:
    """``gflow foxglove junk.mcap out.mcap`` created out.mcap (46 bytes) before it found the input was
    not MCAP, and left it there, so the next try was refused as writing over it."""
    (tmp_path / "junk.mcap").write_bytes(content)
    r = gflow("foxglove", "junk.mcap", "out.mcap", cwd=tmp_path)
    assert_one_line_error(r, "junk.mcap", "not an MCAP file")
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("source", [["--camera", "99"], ["tcp://127.0.0.1:1", "--open-timeout", "5"]])
def test_inline_live_source_that_cannot_open_leaves_no_recording(tmp_path: Path, source: list[str]) -> None:
    """``gflow track --camera 99 --inline`` (or a stream that refuses on loopback) left an empty
    recording in recordings/, where the same run as processes removes it."""
    if source[0] == "--camera" and Path("/dev/video99").exists():
        pytest.skip("this machine has a /dev/video99")
    r = gflow("track", *source, "--init", "10,10,20,20", "--out", "b.csv", "--inline", "-q", cwd=tmp_path)
    assert_one_line_error(r, source[0].removeprefix("--"))
    _no_recording(tmp_path)
    assert not (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("extra,named", [(["--frames", "50:60"], "no box for frame 50"),
                                         (["--set", "foo"], "--set"),
                                         (["--stress", "--set", "foo"], "--set")])
def test_benchmark_error_is_not_preceded_by_a_skipped_folder_note(tmp_path: Path, frames: Path, extra: list[str],
                                                                  named: str) -> None:
    """A DATA folder holding a folder that is no sequence (../shared/data has avletters/) printed
    "benchmark: skipped ..." on stderr before every mistake's error, which took two lines."""
    seq = tmp_path / "data" / "seq1"
    seq.mkdir(parents=True)
    frames.rename(seq / "frames")
    (seq / "groundtruth.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(5)))
    (tmp_path / "data" / "notes").mkdir()
    r = gflow("benchmark", "data", "--trackers", "dcf", "--opencv", "none", "--inline", *extra, cwd=tmp_path)
    assert_one_line_error(r, named)


@pytest.mark.parametrize("argv,named", [
    (["render", "r.mcap", "out.mp4", "--frames", "10:3"], "--frames 10:3"),
    (["render", "r.mcap", "out.mp4", "--frames", "5:5"], "--frames 5:5"),
    (["eval", "--gt", "gt.csv", "--pred", "gt.csv", "--frames=-2:3"], "--frames -2:3"),
    (["eval", "--gt", "gt.csv", "--pred", "gt.csv", "--frames", "4:1"], "--frames 4:1"),
])
def test_an_empty_or_reversed_frame_range_is_refused_first(tmp_path: Path, argv: list[str], named: str) -> None:
    """render read the whole recording before saying a reversed --frames held no frame; eval took a negative
    A; both read ``--frames 5`` as frames 5 on, where benchmark and learn read it as frame 5 alone."""
    (tmp_path / "r.mcap").write_bytes(b"")  # not read: the range is refused before the recording is opened
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(6)))
    r = gflow(*argv, cwd=tmp_path)
    assert_one_line_error(r, named, "0 <= A < B")
    assert not (tmp_path / "out.mp4").exists()


def test_eval_frames_a_alone_is_frame_a(tmp_path: Path) -> None:
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(6)))
    r = gflow("eval", "--gt", "gt.csv", "--pred", "gt.csv", "--frames", "2", "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    import json

    assert json.loads(r.stdout)["frames"] == 1


@pytest.mark.parametrize("extra,named", [
    (["--frames", "0:2"], "(gt.csv: frames 0..1) and a prediction (p.csv: frames 2..5) in --frames 0:2; are the "),
    ([], "(gt.csv: frames 0..5) and a prediction (p.csv: frames 10..11); are the frame numbers aligned?"),
])
def test_eval_of_predictions_on_no_frame_of_the_truth_names_the_frames_of_each(tmp_path: Path, extra: list[str],
                                                                               named: str) -> None:
    """"no frame has both a ground-truth box and a prediction (are the frame numbers aligned?)": neither the frames
    each file holds nor the --frames that chose the truth's were said (the face points' eval says them)."""
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(6)))
    rows = range(10, 12) if not extra else range(2, 6)
    (tmp_path / "p.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in rows))
    r = gflow("eval", "--gt", "gt.csv", "--pred", "p.csv", *extra, cwd=tmp_path)
    assert_one_line_error(r, "gflow eval: error: no frame has both a ground-truth box ", named)
    assert r.returncode == 2 and not r.stdout


@pytest.mark.parametrize("extra,named", [
    (["--max-points", "0"], "--max-points"),
    (["--background-frames", "4:1"], "--background-frames 4:1"),
    (["--metric", "shuffle", "--shuffle-radius=-1"], "--shuffle-radius"),
])
def test_learn_m2_values_are_refused_by_their_option_first(tmp_path: Path, frames: Path, extra: list[str],
                                                           named: str) -> None:
    """``--max-points 0`` was refused as ``max_points`` and ``--background-frames 4:1`` as "frame range"
    (naming no option), after the training frames were read; ``--shuffle-radius -1`` after them too."""
    r = gflow("learn", "m2", str(frames), "-K", "2", "--out", "m.npz", *extra, cwd=tmp_path)
    assert_one_line_error(r, named)
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("size", [3000, 20000])  # cut before the metadata, and after it inside the first chunk
def test_recover_with_nothing_to_recover_leaves_no_output(tmp_path: Path, demo_mcap: Path, size: int) -> None:
    """It printed "recovered 0 messages ... into out.mcap", then "nothing could be recovered", and left
    out.mcap holding only the metadata, to be taken for a recording (and refused as one next time)."""
    torn_copy(demo_mcap, tmp_path / "trunc.mcap", size)
    r = gflow("recover", "trunc.mcap", "out.mcap", cwd=tmp_path)
    assert r.returncode == 1 and not r.stdout, r.stdout
    assert_one_line_error(r, "gflow recover: error: nothing could be recovered from trunc.mcap", "no chunk is complete",
                          "out.mcap not written")
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("argv", [["ps", "--stream", "nosuch"], ["ps", "--stream", "nosuch", "--json"]])
def test_ps_of_a_stream_not_running_is_an_error_of_ps(tmp_path: Path, argv: list[str]) -> None:
    """It printed the bare sentence (not ``gflow ps: error: ...``) and exited 1, where topics, echo and view
    refuse a stream that is not running as a mistake (exit 2)."""
    r = gflow(*argv, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, "gflow ps: error:", "'nosuch'")


@pytest.mark.parametrize("argv,kind", [
    (["run", "adir"], "graph file"),
    (["verify", "adir"], "recording file"),
    (["foxglove", "adir", "out.mcap"], "recording file"),
    (["rerun", "adir", "--graph"], "recording file"),
    (["recover", "adir", "out.mcap"], "recording file"),
    (["info", "adir"], "recording file"),  # said "do not know how to describe adir"
    (["info", "adir.npz"], "model file"),  # said "model file not found"
])
def test_a_folder_given_for_a_file_is_called_a_folder(tmp_path: Path, argv: list[str], kind: str) -> None:
    """They said "not found" of a folder that is there, sending the user to look for a file that exists."""
    (tmp_path / argv[1]).mkdir()
    r = gflow(*argv, cwd=tmp_path)
    line = assert_one_line_error(r, f"gflow {argv[0]}: error: {argv[1]} is a folder, not a {kind}")
    assert "not found" not in line, line
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("folder,words", [("nosuch", ["nosuch does not exist"]), ("afile", ["afile is not a folder"])])
def test_clean_names_a_missing_folder_as_missing(tmp_path: Path, folder: str, words: list[str]) -> None:
    """``gflow clean --keep 1 nosuch`` said "is not a folder" of a path that is not there at all."""
    (tmp_path / "afile").write_text("x")
    r = gflow("clean", "--keep", "1", folder, cwd=tmp_path)
    assert r.returncode == 2
    assert_one_line_error(r, "gflow clean: error:", *words)
    assert (tmp_path / "afile").read_text() == "x"


@pytest.mark.parametrize("value,words", [("0", [">= 1, got 0"]), ("-3", [">= 1, got -3"]), ("x", ["whole number"])])
def test_demo_frames_is_refused_as_the_option(tmp_path: Path, value: str, words: list[str]) -> None:
    """``gflow demo --frames 0`` said "synthetic scene needs at least one frame", naming no option."""
    r = gflow("demo", f"--frames={value}", cwd=tmp_path)
    assert r.returncode == 2
    assert_one_line_error(r, "gflow demo: error: argument --frames:", *words)
    _no_recording(tmp_path)


@pytest.mark.parametrize("argv,size,words", [
    # cut before the metadata: "no gflow.config metadata: it was not written by gflow's recorder"
    (["rerun", "trunc.mcap", "--graph"], 1000, ["holds no gflow.config metadata"]),
    (["step", "trunc.mcap", "--stage", "filter"], 1000, ["holds no gflow.config metadata"]),
    # cut inside the first chunk: "holds no input", "no frame at or after", as of what the run recorded
    (["step", "trunc.mcap", "--stage", "filter"], 20000, ["holds no input of stage filter"]),
    (["track", "trunc.mcap", "--init", "10,10,20,20", "--out", "b.csv"], 20000, ["no frame at or after --start 0"]),
    (["frame", "trunc.mcap", "0", "f.png"], 20000, ["no frame at or after frame 0"]),
    # rerun said "which ends early (its writer was killed); `gflow recover` salvages what is before the cut"
    (["rerun", "trunc.mcap", "--graph"], 20000, ["cannot re-run the graph: gflow/demo/frames: it is not in what can "
                                                 "be read of trunc.mcap: it ends early, torn where its writer was "
                                                 "killed (or is still writing); `gflow recover` salvages its complete "
                                                 "chunks"]),
    (["rerun", "trunc.mcap", "--stage", "filter"], 20000, ["cannot re-run stage filter:", "not in what can be read"]),
])
def test_a_torn_recording_is_said_to_be_torn_in_the_error(tmp_path: Path, demo_mcap: Path, argv: list[str], size: int,
                                                          words: list[str]) -> None:
    """A recording cut by a killed writer was said to be not gflow's, or to hold no frame, after a warning line
    that it was torn; the one error line now says it ends early and that `gflow recover` salvages it."""
    torn_copy(demo_mcap, tmp_path / "trunc.mcap", size)
    r = gflow(*argv, cwd=tmp_path)
    assert r.returncode == 2
    line = assert_one_line_error(r, f"gflow {argv[0]}: error:", *words, "it ends early", "`gflow recover` salvages")
    assert "not written by gflow" not in line, line
    assert not (tmp_path / "b.csv").exists() and not (tmp_path / "f.png").exists()
    _no_recording(tmp_path.joinpath("recordings"))


def test_the_commands_check_a_recording_through_the_public_name() -> None:
    """foxglove and replay refused a missing or non-MCAP input through ``pipeline.io.mcap_io._check``, a
    private name a change inside the module could rename; the check is the module's public ``check_recording``."""
    import ast

    from pipeline.io import mcap_io

    assert "check_recording" in mcap_io.__all__ and not hasattr(mcap_io, "_check")
    for f in (ROOT / "pipeline").rglob("*.py"):
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.ImportFrom) and node.module == "pipeline.io.mcap_io":
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, f"{f.relative_to(ROOT)}:{node.lineno} imports {private} of pipeline.io.mcap_io"


@pytest.mark.parametrize("keep,words", [("-1", ["must be >= 0, got -1"]), ("x", ["whole number", "'x'"])])
def test_clean_refuses_a_bad_keep_before_looking_at_the_folder(tmp_path: Path, keep: str, words: list[str]) -> None:
    """``gflow clean --keep -1 nosuch`` said ``nosuch does not exist``: fixed, the next try met the bad --keep."""
    r = gflow("clean", f"--keep={keep}", "nosuch", cwd=tmp_path)
    assert r.returncode == 2
    line = assert_one_line_error(r, "gflow clean: error: argument --keep:", *words)
    assert "nosuch" not in line, line


@pytest.mark.parametrize("argv", [["learn", "gflow", "lm.npz", "--out", "m.npz"], ["benchmark", "data"]])
@pytest.mark.parametrize("value,words", [("4:1", ["0 <= A < B"]), ("abc", ["must look like A:B"])])
def test_a_bad_frame_range_names_frames(tmp_path: Path, argv: list[str], value: str, words: list[str]) -> None:
    """``gflow learn gflow --frames 4:1`` (and benchmark's) said "frame range needs 0 <= A < B", naming no option,
    where learn m2, render and eval say ``--frames 4:1: ...``."""
    r = gflow(*argv, "--frames", value, cwd=tmp_path)
    assert r.returncode == 2
    said_as = " ".join(argv[:2]) if argv[0] == "learn" else argv[0]  # a command's own command is named too
    assert_one_line_error(r, f"gflow {said_as}: error: --frames {value}: frame range", *words)
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("extra,named", [
    (["--shuffle-radius", "1"], "--shuffle-radius is an option of --metric shuffle, not of --metric chamfer"),
    (["--metric", "l2", "--shuffle-radius", "2"],
     "--shuffle-radius is an option of --metric shuffle, not of --metric l2"),
    (["--metric", "shuffle", "--canny", "50,150"], "--canny is an option of --metric chamfer, not of --metric shuffle"),
    (["--metric", "l2", "--no-appearance"], "--no-appearance is an option of --metric chamfer, not of --metric l2"),
    (["--patch-size", "10x10"], "--patch-size is an option of --metric shuffle / l2, not of --metric chamfer"),
])
def test_learn_m2_refuses_an_option_its_metric_does_not_use(tmp_path: Path, frames: Path, extra: list[str],
                                                            named: str) -> None:
    """``--shuffle-radius`` with chamfer, or ``--canny`` with shuffle, was taken and ignored: the model was
    learned without it, and nothing said so (even typed with its default value, it says the user meant it)."""
    r = gflow("learn", "m2", str(frames), "-K", "2", "--out", "m.npz", *extra, cwd=tmp_path)
    assert r.returncode == 2
    assert_one_line_error(r, f"gflow learn m2: error: {named}")
    assert not (tmp_path / "m.npz").exists()


def _files_up_to(limit: int):
    """A ``preexec_fn`` under which a write past ``limit`` bytes of a file fails (EFBIG), as on a full disk."""
    def limit_files() -> None:
        import resource
        import signal

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails instead of the signal killing the process
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return limit_files


def test_recover_failing_midway_leaves_no_partial_file(tmp_path: Path, demo_mcap: Path) -> None:
    """``gflow recover SRC FIXED`` wrote straight into FIXED: stopped midway (a full disk), it left the part
    written, a recording that looks like one. It now writes beside FIXED and takes the name once closed."""
    room = demo_mcap.stat().st_size // 4
    r = gflow("recover", str(demo_mcap), "out.mcap", cwd=tmp_path, preexec_fn=_files_up_to(room))
    assert r.returncode == 1
    assert_one_line_error(r, f"gflow recover: error: recovering {demo_mcap} failed: File too large;",
                          "out.mcap not written")
    assert not list(tmp_path.iterdir()), "neither FIXED nor its temporary file may be left"
    r = gflow("recover", str(demo_mcap), "out.mcap", cwd=tmp_path)  # with room: the whole recording
    assert r.returncode == 0 and "recovered" in r.stdout, r.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["out.mcap"]
    assert gflow("verify", "out.mcap", cwd=tmp_path).returncode == 0


def _no_pipelines(tmp_path: Path) -> dict[str, str]:
    """The environment of a live tool that finds no pipeline announced (an empty runtime folder of its own)."""
    (tmp_path / "rt").mkdir()
    return {"GFLOW_RUNTIME_DIR": str(tmp_path / "rt")}


@pytest.mark.parametrize("argv,words", [
    (["echo", "", "--timeout", "30"], ["topic '' is empty"]),
    (["echo", "x//y", "--timeout", "30"], ["topic 'x//y' is malformed (key expression gflow/x//y): empty chunks"]),
    (["echo", "cam0/a#b", "--timeout", "30"], ["topic 'cam0/a#b' is malformed", "forbidden characters"]),
    (["hz", "x//y", "--wait", "30"], ["topic 'x//y' is malformed (key expression gflow/x//y)"]),
    (["hz", " ", "--wait", "30"], ["topic ' ' is empty"]),
    (["pub", "x//y", "Control", "{}", "--wait", "30"], ["topic 'x//y' is malformed"]),
])
def test_a_malformed_topic_is_refused_before_any_wait(tmp_path: Path, argv: list[str], words: list[str]) -> None:
    """``gflow echo 'x//y' --timeout 30`` waited its 30 s for a pipeline, then said none runs; with one running,
    zenoh's own error came out as an internal error of gflow. The topic is checked before anything else."""
    t0 = time.monotonic()
    r = gflow(*argv, cwd=tmp_path, env=_no_pipelines(tmp_path), timeout=20)
    assert r.returncode == 2 and time.monotonic() - t0 < 10
    assert_one_line_error(r, f"gflow {argv[0]}: error:", *words)


def test_an_echo_or_hz_wait_that_runs_out_is_no_mistake(tmp_path: Path) -> None:
    """``gflow echo demo/estimate --timeout 0.5`` with no pipeline started in that time ended in ``gflow echo: error:
    no running gflow pipeline ...``, exit 2, as a mistyped command would; it is an answer (exit 1), said as echo
    says that a topic stayed silent."""
    env = _no_pipelines(tmp_path)
    for argv, key in ((["echo", "demo/estimate", "--timeout", "0.5"], "gflow/demo/estimate"),
                      (["hz", "demo/frames", "--wait", "0.5"], "gflow/demo/frames")):
        r = gflow(*argv, cwd=tmp_path, env=env)
        last = r.stderr.strip().splitlines()[-1]
        assert r.returncode == 1 and "Traceback" not in r.stderr and "error" not in r.stderr, r.stderr
        assert last.startswith(f"gflow {argv[0]}: no message on {key} in 0.5 s: no running gflow pipeline with "
                               f"stream 'demo'"), last
    r = gflow("echo", "demo/estimate", cwd=tmp_path, env=env)  # not waited for: a stream not running is a mistake
    assert r.returncode == 2
    assert_one_line_error(r, "gflow echo: error: no running gflow pipeline with stream 'demo'")


def test_echo_on_a_silent_topic_of_a_reached_peer_exits_1(tmp_path: Path) -> None:
    """The same answer when the network is reached (loopback, multicast scouting off, an explicit endpoint)
    and nothing comes on the topic: ``no message on KEY in N s``, exit 1, never ``error:``."""
    from pipeline.runtime.transport import ZenohSettings, free_port, open_session

    port = free_port()
    peer = open_session(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",), multicast=False))
    try:
        r = gflow("echo", "gflow/quiet/estimate", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "0.3",
                  cwd=tmp_path, env=_no_pipelines(tmp_path))
    finally:
        peer.close()
    assert r.returncode == 1 and "error" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("gflow echo: no message on gflow/quiet/estimate in 0.3 s")


def test_pub_with_no_subscriber_is_no_mistake(tmp_path: Path) -> None:
    """``gflow pub`` on a topic nobody took within ``--wait`` said ``gflow pub: error: no subscriber ...`` and exited 2,
    as a mistyped command would; nothing arriving is an answer (exit 1), said as echo says a topic stayed silent."""
    from pipeline.runtime.transport import ZenohSettings, free_port, open_session

    port = free_port()
    peer = open_session(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",), multicast=False))
    try:
        r = gflow("pub", "gflow/quiet/_control", "Control", '{"command": "stop"}', "--connect",
                  f"tcp/127.0.0.1:{port}", "--wait", "0.3", cwd=tmp_path, env=_no_pipelines(tmp_path))
    finally:
        peer.close()
    assert r.returncode == 1 and "error" not in r.stderr, r.stderr
    assert_one_line_error(r, "gflow pub: no subscriber of gflow/quiet/_control appeared within 0.3 s; nothing sent")


@pytest.mark.parametrize("argv,room,words", [
    (["boxes", "{rec}", "--out", "b.csv"], 20, ["gflow boxes: error: b.csv: File too large"]),
    (["frame", "{frames}", "0", "f.png"], 100, ["gflow frame: error: f.png: File too large"]),
    (["learn", "m2", "{frames}", "--metric", "l2", "-K", "2", "--out", "m.npz", "-q"], 100,
     ["gflow learn m2: error: m.npz: File too large"]),
])
def test_a_write_failing_during_the_work_is_a_failed_run(tmp_path: Path, frames: Path, demo_mcap: Path,
                                                         argv: list[str], room: int, words: list[str]) -> None:
    """Every OSError was exit 2, a mistake in the command, also a write that failed once the work was done (a
    full disk); ``gflow frame`` said ``OpenCV cannot write f.png (use .png or .jpg)`` after libpng's own line.
    The paths named are checked first (exit 2); the system failing during the work is exit 1. ``gflow learn`` left
    m.npz.tmp behind and did not name the model file; it now leaves nothing and names it."""
    out = tmp_path / "out"
    out.mkdir()
    args = [a.replace("{rec}", str(demo_mcap)).replace("{frames}", str(frames)) for a in argv]
    r = gflow(*args, cwd=out, preexec_fn=_files_up_to(room))
    assert r.returncode == 1, r.stderr
    assert_one_line_error(r, *words)
    assert not list(out.iterdir()), "neither the output nor a temporary file may be left (learn left m.npz.tmp)"
    # the same output in a folder that does not exist: refused before any work, exit 2
    r = gflow(*[a.replace("b.csv", "no/b.csv").replace("f.png", "no/f.png").replace("m.npz", "no/m.npz")
                for a in args], cwd=tmp_path)
    assert r.returncode == 2
    assert_one_line_error(r, "the folder no does not exist")


@pytest.mark.parametrize("before", [[], ["good.mcap"]])
def test_verify_of_a_folder_is_a_mistake_in_the_command(tmp_path: Path, demo_mcap: Path, before: list[str]) -> None:
    """``gflow verify adir`` exited 1, as for a damaged file, where every other command refuses a folder given for a
    recording as a mistake (exit 2); now it says so in the same words before it reads any file."""
    (tmp_path / "adir").mkdir()
    (tmp_path / "good.mcap").write_bytes(demo_mcap.read_bytes())
    r = gflow("verify", *before, "adir", cwd=tmp_path)
    assert r.returncode == 2 and not r.stdout, r.stdout
    assert_one_line_error(r, "gflow verify: error: adir is a folder, not a recording file (give an .mcap file)")


@pytest.mark.parametrize("tool,opt,said", [
    ("echo", "--timeout", "gflow echo: no message on gflow/quiet/estimate in 4 s"),
    ("hz", "--wait", "gflow hz: fewer than 2 messages on gflow/quiet/estimate (waited 4 s for the first)"),
])
def test_echo_timeout_bounds_the_wait_for_a_pipeline_and_its_messages(tmp_path: Path, monkeypatch, tool: str,
                                                                      opt: str, said: str) -> None:
    """``gflow echo --timeout T`` (and ``gflow hz --wait T``) waited up to T s for a pipeline to start, then T s more
    for its messages: a run announced just before T made the wait nearly 2T. T now counts from the start, the
    pipeline's wait included."""
    import threading

    from pipeline.runtime.running import announce
    from pipeline.runtime.transport import ZenohSettings, free_port, open_session

    env = _no_pipelines(tmp_path)
    monkeypatch.setenv("GFLOW_RUNTIME_DIR", env["GFLOW_RUNTIME_DIR"])
    port = free_port()
    peer = open_session(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",), multicast=False))  # publishes nothing
    cmd = [sys.executable, "-m", "pipeline.cli.main", tool, "gflow/quiet/estimate", opt, "4"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env=dict(os.environ, PYTHONPATH=str(ROOT), **env))
    lines: list[tuple[float, str]] = []
    reader = threading.Thread(target=lambda: lines.extend((time.monotonic(), ln) for ln in proc.stderr), daemon=True)
    reader.start()
    announcement = None
    try:
        deadline = time.monotonic() + 30
        while not lines and time.monotonic() < deadline:  # "waiting up to 4 s for a pipeline of stream quiet ..."
            time.sleep(0.02)
        assert lines and "waiting up to 4 s" in lines[0][1], lines
        time.sleep(3.6)  # the run starts 3.6 s into the 4
        announcement = announce("quiet", [f"tcp/127.0.0.1:{port}"], name="quiet")
        proc.wait(timeout=30)
        reader.join(timeout=5)
    finally:
        if announcement is not None:
            announcement.close()
        peer.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, lines
    last_at, last = lines[-1]
    assert last.startswith(said), last
    # 4 s, then 1.5 s listening to what the stream has for the line (5.5 s measured); before, 3.6 + 4 + 1.5 s
    assert last_at - lines[0][0] < 7.5, [(round(t - lines[0][0], 2), ln) for t, ln in lines]


@pytest.mark.parametrize("extra,said", [
    (["--no-appearance"], "--no-appearance does not apply without --boxes: appearance exemplars are learned from "
                          "the boxes only"),
    (["--no-background-mask"], "--no-background-mask does not apply without --boxes: it keeps every edge in a box"),
    (["--boxes", "gt.csv", "--no-background-mask", "--threshold", "20"],
     "--threshold does not apply with --no-background-mask: it is the background subtraction's"),
    (["--boxes", "gt.csv", "--no-background-mask", "--background-frames", "0:3"],
     "--background-frames does not apply with --no-background-mask: the background masks the edges in the boxes"),
    (["--g0", "50"], "--g0 does not apply with --profile quadratic (the default): it is the truncation level of "
                     "--profile truncated"),
    (["--profile", "quadratic", "--g0", "50"], "--g0 does not apply with --profile quadratic: it is"),
])
def test_learn_m2_refuses_a_contour_option_its_way_of_training_leaves_unused(tmp_path: Path, frames: Path,
                                                                             extra: list[str], said: str) -> None:
    """``--no-appearance`` and ``--no-background-mask`` without ``--boxes``, ``--threshold`` and ``--background-frames``
    with ``--no-background-mask``, and ``--g0`` with the quadratic profile were taken and ignored without a word."""
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(5)))
    r = gflow("learn", "m2", str(frames), "-K", "2", "--out", "m.npz", *extra, cwd=tmp_path)
    assert r.returncode == 2
    assert_one_line_error(r, f"gflow learn m2: error: {said}")
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("out,said", [
    ("o.mp4", "gflow render: error: o.mp4: the video was not written whole (0 of its 20 frames can be read back; "
              "a full disk?); nothing written"),
    ("o.avi", "gflow render: error: o.avi: the video was not written whole"),
    ("pngs", "gflow render: error: pngs/000000.png: File too large"),
])
def test_render_failing_midway_is_a_failed_run_that_leaves_nothing(tmp_path: Path, demo_mcap: Path, out: str,
                                                                   said: str) -> None:
    """``gflow render`` ignored a write that failed: ``cv2.imwrite``'s answer was not looked at and OpenCV's video
    writer says nothing, so on a full disk it exited 0 with a broken video under the name asked for. The video is
    now written beside its name, read back and moved there whole; a picture that fails takes the others with it."""
    r = gflow("render", str(demo_mcap), out, "-q", cwd=tmp_path, preexec_fn=_files_up_to(100_000))
    assert r.returncode == 1, r.stderr
    assert_one_line_error(r, said)
    assert not list(tmp_path.iterdir()), "neither the output nor a temporary file may be left"
    r = gflow("render", str(demo_mcap), out, "-q", cwd=tmp_path)  # with room: the whole of it, the retry not refused
    assert r.returncode == 0, r.stderr
    assert [p.name for p in tmp_path.iterdir()] == [out]


def test_boxes_failing_midway_leaves_no_partial_csv(tmp_path: Path, demo_mcap: Path) -> None:
    """``gflow boxes REC --out b.csv`` wrote straight into b.csv: stopped midway (a full disk), it left the rows
    written, and the retry was refused as b.csv existing. It now writes beside b.csv and takes the name once whole."""
    r = gflow("boxes", str(demo_mcap), "--out", "b.csv", cwd=tmp_path, preexec_fn=_files_up_to(200))
    assert r.returncode == 1, r.stderr
    assert_one_line_error(r, "gflow boxes: error: b.csv: File too large")
    assert not list(tmp_path.iterdir()), "neither b.csv nor its temporary file may be left"
    r = gflow("boxes", str(demo_mcap), "--out", "b.csv", cwd=tmp_path)  # with room: the retry is not refused
    assert r.returncode == 0 and "20 boxes" in r.stdout, r.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["b.csv"]
    assert len((tmp_path / "b.csv").read_text().splitlines()) == 21


@pytest.mark.parametrize("argv,out", [
    (["foxglove", "{rec}", "f.mcap"], "f.mcap"),
    (["plot", "{rec}", "p.svg"], "p.svg"),
    (["plot", "{rec}", "p.pdf"], "p.pdf"),
])
def test_a_copy_or_plot_failing_midway_leaves_nothing_under_its_name(tmp_path: Path, demo_mcap: Path,
                                                                     argv: list[str], out: str) -> None:
    """``gflow foxglove`` and ``gflow plot`` (SVG, PDF) wrote straight into OUT: stopped midway (a full disk), they
    left the part written under its name (a copy that looks like a recording, a cut picture), and the retry was
    refused as OUT existing. They now write beside OUT and take the name once whole."""
    args = [a.replace("{rec}", str(demo_mcap)) for a in argv]
    (tmp_path / "first").mkdir()  # matplotlib's font cache written first, by a run with room (it is not the test)
    assert gflow(*args, cwd=tmp_path / "first").returncode == 0
    cut = tmp_path / "cut"
    cut.mkdir()
    r = gflow(*args, cwd=cut, preexec_fn=_files_up_to(2000))
    assert r.returncode == 1, r.stderr
    assert_one_line_error(r, f"gflow {argv[0]}: error: {out}: File too large")
    assert not list(cut.iterdir()), "neither the output nor its temporary file may be left"
    r = gflow(*args, cwd=cut)  # with room: the retry is not refused
    assert r.returncode == 0, r.stderr
    assert [p.name for p in cut.iterdir()] == [out]


#: ``gflow ARGS`` with a Ctrl-C as the encoded picture's bytes are taken to be written
_CTRL_C_AT_THE_WRITE = """
import sys

import cv2

encode = cv2.imencode


class Cut:
    def tobytes(self):
        raise KeyboardInterrupt


cv2.imencode = lambda kind, pic: (encode(kind, pic)[0], Cut())
from pipeline.cli.main import main

sys.exit(main(sys.argv[1:]))
"""


def test_a_frame_picture_interrupted_midway_leaves_nothing_under_its_name(tmp_path: Path, frames: Path) -> None:
    """``gflow frame`` opened OUT, then wrote the picture: a Ctrl-C between the two left an empty OUT, a picture no
    viewer opens, and the retry was refused as OUT existing. It now writes beside OUT and takes the name once
    whole, as plot and foxglove do."""
    out = tmp_path / "out"
    out.mkdir()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", _CTRL_C_AT_THE_WRITE, "frame", str(frames), "0", "f.png"], cwd=out,
                       env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 130 and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    assert not list(out.iterdir()), "neither a picture cut short under its name nor its temporary file"
    r = gflow("frame", str(frames), "0", "f.png", cwd=out)  # the retry is not refused
    assert r.returncode == 0 and [p.name for p in out.iterdir()] == ["f.png"], r.stderr
    assert (out / "f.png").stat().st_size > 100


@pytest.mark.parametrize("argv", [
    ["eval", "--gt", "adir", "--pred", "b.csv"],
    ["eval", "--gt", "b.csv", "--pred", "adir"],
    ["plot", "{rec}", "p.png", "--gt", "adir"],
])
def test_a_folder_given_for_a_box_file_is_called_a_folder(tmp_path: Path, demo_mcap: Path, argv: list[str]) -> None:
    """``gflow eval --gt adir`` and ``gflow plot --gt adir`` said ``box file not found: adir`` of a folder that is
    there; a folder given for a file is a mistake in the command, said as the other commands say it."""
    (tmp_path / "adir").mkdir()
    (tmp_path / "b.csv").write_text("frame,x,y,w,h\n0,10,10,20,20\n")
    r = gflow(*[a.replace("{rec}", str(demo_mcap)) for a in argv], cwd=tmp_path)
    assert r.returncode == 2
    line = assert_one_line_error(r, f"gflow {argv[0]}: error: adir is a folder, not a box file (give a .csv file)")
    assert "not found" not in line, line
    assert not (tmp_path / "p.png").exists()


def test_track_failing_to_write_its_boxes_leaves_no_partial_csv(tmp_path: Path, frames: Path) -> None:
    """``gflow track ... --out b.csv`` wrote straight into b.csv: a write that failed midway (a full disk) left the
    rows written, and the retry was refused as b.csv existing. It now writes beside b.csv, as ``gflow boxes`` does."""
    out = tmp_path / "out"
    out.mkdir()
    args = ["track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--inline", "--no-record", "-q"]
    r = gflow(*args, cwd=out, preexec_fn=_files_up_to(100))
    assert r.returncode == 1, r.stderr
    assert_one_line_error(r, "gflow track: error: b.csv: File too large")
    assert not list(out.iterdir()), "neither b.csv nor its temporary file may be left"
    r = gflow(*args, cwd=out)  # with room: the retry is not refused
    assert r.returncode == 0, r.stderr
    assert [p.name for p in out.iterdir()] == ["b.csv"]
    assert len((out / "b.csv").read_text().splitlines()) == 6


@pytest.mark.parametrize("argv", [
    ["run", "demo", "--inline"],
    ["demo", "--frames", "3", "--inline"],
    ["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--inline"],
])
def test_inline_refuses_a_bad_security_option_as_processes_do(tmp_path: Path, frames: Path, argv: list[str]) -> None:
    """``gflow run demo --security adir --inline`` ran and exited 0: --inline opens no zenoh session, so the
    security options were never read. They are now checked as without --inline, before the run."""
    (tmp_path / "adir").mkdir()
    r = gflow(*[a.replace("{frames}", str(frames)) for a in argv], "--security", "adir", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, f"gflow {argv[0]}: error: adir is a folder, not a security file")
    assert not (tmp_path / "b.csv").exists()
    _no_recording(tmp_path)


def test_pub_to_an_endpoint_that_leads_nowhere_says_so(tmp_path: Path) -> None:
    """``gflow pub ... --connect`` an endpoint nobody listens on said ``no subscriber of ... appeared``, as if a
    pipeline had been reached that did not take the topic. A session opens there without error; pub now asks
    whether anything was reached and says that nothing was, in the words and with the exit status (2) of topics,
    echo and hz reaching nothing (it said so with exit 1, as a wait that ran out)."""
    from pipeline.runtime.transport import free_port

    port = free_port()  # nobody listens there
    r = gflow("pub", "gflow/quiet/_control", "Control", '{"command": "stop"}', "--connect", f"tcp/127.0.0.1:{port}",
              "--wait", "0.3", cwd=tmp_path, env=_no_pipelines(tmp_path))
    assert r.returncode == 2, r.stderr
    line = assert_one_line_error(r, f"gflow pub: error: reached nothing at tcp/127.0.0.1:{port} within 3 s")
    assert "subscriber" not in line, line


@pytest.mark.parametrize("tool,topic,opt,said", [
    ("echo", "cam0/est*", "--timeout", "gflow echo: no message on gflow/cam0/est* in 0.5 s"),
    ("echo", "cam0/est$*", "--timeout", "gflow echo: no message on gflow/cam0/est$* in 0.5 s"),
    ("hz", "cam0/est?", "--wait", "gflow hz: no message on gflow/cam0/est? in 0.5 s"),
    ("hz", "cam0/*$*ate", "--wait", "gflow hz: no message on gflow/cam0/*$*ate in 0.5 s"),
])
def test_a_wildcard_topic_is_named_as_typed(tmp_path: Path, tool: str, topic: str, opt: str, said: str) -> None:
    """A topic's shell wildcards were named in zenoh's escaped form (``est*`` as ``gflow/cam0/est$*``), and zenoh's
    own ``$*``, typed as such, was escaped again (``est$$*``) and refused as malformed. ``$*`` is now kept, and the
    messages name the topic as typed (its stream and ``gflow/`` filled in)."""
    r = gflow(tool, topic, opt, "0.5", cwd=tmp_path, env=_no_pipelines(tmp_path))
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr and "$$" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(said), r.stderr


@pytest.mark.parametrize("argv,item,close", [
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--inline"], "tracker.search_siz=2",
     "did you mean 'search_sizes'? also close: "),
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--inline"], "tracker.zzz=1", None),
    (["run", "dcf", "--inline"], "tracker.partcles=4", "did you mean 'particles'?"),
])
def test_an_unknown_tracker_parameter_names_the_closest_not_all(tmp_path: Path, frames: Path, argv: list[str],
                                                                 item: str, close: str | None) -> None:
    """``--set tracker.NOSUCH=1`` listed every parameter of the tracker on the one line (93 of dcf's). It now names
    the closest (difflib) and the command that lists them all, ``gflow info TRACKER``."""
    r = gflow(*[a.replace("{frames}", str(frames)) for a in argv], "--set", item, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    name = item.split(".", 1)[1].split("=")[0]
    line = assert_one_line_error(r, f"--set {item}: DCFParams has no parameter {name!r} (", "`gflow info dcf` lists all")
    assert (close in line) if close else ("did you mean" not in line), line
    assert "known:" not in line and "admm_iterations" not in line and len(line) < 250, line
    assert not (tmp_path / "b.csv").exists()
    _no_recording(tmp_path)


def test_a_value_the_learning_refuses_is_a_failed_run_not_a_mistake(tmp_path: Path) -> None:
    """A ValueError was exit 2, a mistake in the command, wherever it was raised: also one the learning itself
    raised, once every option and the training frames had been checked. Raised after the work began it is now the
    work failing, exit 1; the mistakes found before (here -K too large) stay exit 2."""
    same = tmp_path / "same"
    same.mkdir()
    for i in range(6):  # six black frames: every patch alike, so no distance to learn a kernel width from
        cv2.imwrite(str(same / f"{i:04d}.png"), np.zeros((48, 64, 3), np.uint8))
    r = gflow("learn", "m2", str(same), "--metric", "l2", "-K", "2", "--out", "m.npz", "-q", cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    assert_one_line_error(r, "gflow learn m2: error: need at least 2 non-zero validation distances")
    assert not (tmp_path / "m.npz").exists()
    r = gflow("learn", "m2", str(same), "--metric", "l2", "-K", "6", "--out", "m.npz", "-q", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, "gflow learn m2: error: -K 6 exemplars but only 6 training item(s)")


def test_a_bad_recordings_limit_is_refused_before_the_track_runs(tmp_path: Path, frames: Path) -> None:
    """``GFLOW_RECORDINGS_WARN_MB=abc`` is read when the recording is kept, after the run; it was met only then,
    and the run that had tracked every frame failed without writing its boxes. It is checked with the other
    options, before any work (exit 2, nothing written); a bad --set value is the same mistake."""
    env = {"GFLOW_RECORDINGS_WARN_MB": "abc"}
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--inline", "-q", cwd=tmp_path, env=env)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, "gflow track: error: GFLOW_RECORDINGS_WARN_MB must be a number of MB >= 0, got 'abc'")
    assert not (tmp_path / "b.csv").exists()
    assert not list(tmp_path.glob("recordings/*.mcap")), "a recording was made before the mistake was said"
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--inline", "--set",
              "tracker.particles=0", cwd=tmp_path, env=env)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, "--set tracker.particles=0: particles must be >= 1, got 0")

@pytest.mark.parametrize("rows,named", [
    ("0,10,10,20,20\n1,10,10,-20,20\n", ["boxes.csv:2", "negative width or height"]),
    (None, ["box file not found", "nosuch.csv"]),
])
def test_learn_m2_refuses_damaged_or_missing_boxes_before_reading_frames(tmp_path: Path, frames: Path, rows: str | None,
                                                                         named: list[str]) -> None:
    """A negative width in --boxes was taken as a box (and learning failed later with "no edge points"), and a
    missing --boxes file was named only after every training frame was read: both are said first, by file and line,
    as `gflow eval` says them."""
    name = "nosuch.csv"
    if rows is not None:
        (tmp_path / "boxes.csv").write_text(rows)
        name = "boxes.csv"
    r = gflow("learn", "m2", str(frames), "-K", "2", "--out", "m.npz", "--boxes", name, cwd=tmp_path)
    assert_one_line_error(r, *named)  # one line: not "read N training frame(s)" before it
    assert r.returncode == 2 and not (tmp_path / "m.npz").exists()


def test_learn_m2_leaves_out_the_frames_whose_box_row_says_the_target_is_absent(tmp_path: Path, frames: Path) -> None:
    """A NaN row (the target absent, as `gflow eval` reads ground truth) stopped the learning ("box has NaN"), and a
    row of no size (w, h 0) was cut as a training item; both frames are now left out: three items from five frames."""
    (tmp_path / "boxes.csv").write_text("0,10,10,30,30\n1,nan,nan,nan,nan\n2,12,10,30,30\n3,14,10,0,0\n4,16,10,30,30\n")
    r = gflow("learn", "m2", str(frames), "-K", "2", "--out", "m.npz", "--boxes", "boxes.csv", "--metric", "l2",
              "--patch-size", "8x8", cwd=tmp_path)
    assert "box has NaN" not in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert "training items: 3 patches" in r.stderr, r.stderr


@pytest.mark.parametrize("extra,named", [
    (["--frames", "90:99"], "--frames 90:99: no decodable frame"),
    (["--background-frames", "90:99"], "--background-frames 90:99: no decodable frame"),
])
def test_learn_m2_frame_range_past_the_end_names_its_option(tmp_path: Path, frames: Path, extra: list[str],
                                                            named: str) -> None:
    """"no decodable frame ... for frames 90:99" named neither option: --frames and --background-frames were not
    told apart; nor did it say the frames there are."""
    r = gflow("learn", "m2", str(frames), "-K", "2", "--out", "m.npz", "-q", *extra, cwd=tmp_path)
    assert assert_one_line_error(r, named).endswith("for frames 90:99 (it has 5 frames: 0..4)"), r.stderr
    assert r.returncode == 2 and not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("argv,said", [
    (["learn", "m2", "data/s/frames", "-K", "2", "--out", "m.npz", "-q", "--frames", "1:9"],
     "--frames 1:9: data/s/frames holds frames 0..4; learning from 1..4"),
    (["learn", "m2", "data/s/frames", "-K", "2", "--out", "m.npz", "-q", "--background-frames", "2:9"],
     "--background-frames 2:9: data/s/frames holds frames 0..4; the background of 2..4"),
    (["learn", "gflow", "lm.npz", "-k", "2", "--vertices", "30", "--out", "g.npz", "-q", "--frames", "2:9"],
     "--frames 2:9: lm.npz holds frames 0..5; learning from 2..5"),
    (["benchmark", "data", "--trackers", "dcf", "--inline", "-q", "--frames", "1:9"],
     "--frames 1:9: data/s holds frames 0..4; tracking 1..4"),
])
def test_a_frame_range_partly_past_the_source_says_what_it_took(tmp_path: Path, frames: Path, argv: list[str],
                                                                said: str) -> None:
    """``--frames 1:9`` of five frames learned from (or tracked) frames 1..4 without a word, exit 0, as though the
    range had been there: a model's frames or a benchmark's table could be taken for the eight asked for. A note
    now says the option, the frames the source holds and those taken, once; the exit is still 0."""
    one_sequence(tmp_path, frames)
    rng = np.random.default_rng(0)  # a face's points in 6 frames, each a small change of the same shape
    np.savez(tmp_path / "lm.npz", landmarks=rng.uniform(0, 100, (1, 468, 3)) + rng.normal(0, 1, (6, 468, 3)))
    r = gflow(*argv, cwd=tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    assert [ln for ln in r.stderr.splitlines() if ln.startswith("note: ")] == [f"note: {said}"], r.stderr


def _letters_file(path: Path) -> Path:
    """A small AVLetters speaker file: letters A, B, C in repetition 1, B, C in repetition 2, six 12x16 frames each."""
    rng = np.random.default_rng(0)
    np.savez(path, frames=rng.integers(0, 255, (30, 12, 16), dtype=np.uint8), starts=np.arange(0, 30, 6),
             letters=np.array(list("ABCBC")), repetitions=np.array([1, 1, 1, 2, 2]))
    return path


@pytest.mark.parametrize("extra,named", [
    (["--reps", "5"], "--reps 5: av.npz has no repetition 5 (its repetitions: 1, 2)"),
    (["--reps", "1,5"], "--reps 1,5: av.npz has no repetition 5 (its repetitions: 1, 2)"),
    (["--letters", "A,X"], "--letters A,X: av.npz has no utterance of X (its letters: A, B, C)"),
    (["--letters", "A,D-F"], "--letters A,D-F: av.npz has no utterance of D-F (its letters: A, B, C)"),
    (["--reps", "2", "--letters", "A"], "--reps 2 --letters A: av.npz has no utterance of those letters in those "
                                        "repetitions (they hold letters B, C)"),
    (["--letters", "C", "--frames", "0:4"], "--frames 0:4: no frame of the utterances chosen lies in it (they span "
                                            "frames 12..29)"),
])
def test_learn_m2_names_the_utterances_a_selection_finds_none_of(tmp_path: Path, extra: list[str], named: str) -> None:
    """``--reps 1,5`` or ``--letters A,X`` of a file without repetition 5 or letter X learned from the rest without a
    word (exit 0); ``--reps 5`` and ``--letters X`` named neither option, and said the file's repetitions for a
    letter it does not hold."""
    _letters_file(tmp_path / "av.npz")
    r = gflow("learn", "m2", "av.npz", "--metric", "l2", "-K", "2", "--out", "m.npz", "-q", *extra, cwd=tmp_path)
    assert_one_line_error(r, f"gflow learn m2: error: {named}")
    assert r.returncode == 2 and not (tmp_path / "m.npz").exists()
    whole = gflow("learn", "m2", "av.npz", "--metric", "l2", "-K", "2", "--out", "m.npz", "-q", "--reps", "1,2",
                  "--letters", "A-Z", cwd=tmp_path)  # a range is the letters of it the file holds, as before
    assert whole.returncode == 0 and "from 30 items" in whole.stdout, whole.stderr


@pytest.mark.parametrize("frames,note", [
    ("10:100", "note: --frames 10:100: av.npz (the utterances chosen) holds frames 12..29; learning from 12..29"),
    ("0:20", "note: --frames 0:20: av.npz (the utterances chosen) holds frames 12..29; learning from 12..17"),
    ("12:30", ""),
])
def test_learn_m2_says_a_frame_range_past_the_utterances_chosen(tmp_path: Path, frames: str, note: str) -> None:
    """``--frames`` running past the frames of the utterances chosen learned from those there without a word, where a
    range past an image folder's frames says what it took (exit 0 both)."""
    _letters_file(tmp_path / "av.npz")
    r = gflow("learn", "m2", "av.npz", "--metric", "l2", "-K", "2", "--out", "m.npz", "-q", "--letters", "C",
              "--frames", frames, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert [ln for ln in r.stderr.splitlines() if ln.startswith("note: ")] == ([note] if note else []), r.stderr


@pytest.mark.parametrize("source,extra,named", [
    ("udp://127.0.0.1:notaport", [], ["udp://127.0.0.1:notaport", "Port could not be cast"]),
    ("rtsp://127.0.0.1:99999/x", [], ["rtsp://127.0.0.1:99999/x", "Port out of range"]),
    ("rtsp://127.0.0.1:1/x", ["--reconnect", "-1"], ["argument --reconnect", ">= 0"]),
    ("rtsp://127.0.0.1:1/x", ["--reconnect", "nan"], ["argument --reconnect", ">= 0"]),
    ("rtsp://127.0.0.1:1/x", ["--open-timeout", "0"], ["argument --open-timeout", "> 0"]),
    ("rtsp://127.0.0.1:1/x", ["--camera", "-1"], ["argument --camera", ">= 0"]),
])
def test_a_live_source_mistake_is_refused_before_anything_is_opened(tmp_path: Path, source: str, extra: list[str],
                                                                    named: list[str]) -> None:
    """A URL whose port is no number was waited on for --open-timeout, then "nothing received" (exit 1); --reconnect
    -1 (or NaN) and --open-timeout 0 were refused by the source stage, naming the graph file's line and its
    parameters, not the option; --camera -1 said "no camera at /dev/video-1"."""
    r = gflow("track", source, "--init", "1,1,10,10", "--out", "b.csv", "--inline", "--no-record", *extra,
              cwd=tmp_path)
    assert_one_line_error(r, *named)
    assert r.returncode == 2 and not (tmp_path / "b.csv").exists()


def test_benchmark_refuses_ground_truth_past_the_last_frame(tmp_path: Path, frames: Path) -> None:
    """A ground-truth box for frame 7 of a five-frame sequence was scored as a frame the tracker missed (a success
    of 5 / 6 at best), where `gflow export vot` refuses the same folder."""
    seq = tmp_path / "data" / "s"
    seq.mkdir(parents=True)
    frames.rename(seq / "frames")
    (seq / "groundtruth.csv").write_text("".join(f"{f},10,10,20,20\n" for f in (0, 1, 2, 3, 4, 7)))
    for argv in (["benchmark", "data", "--trackers", "appearance", "--inline", "--opencv", "none", "-q"],
                 ["export", "vot", "data", "ws"]):
        r = gflow(*argv, cwd=tmp_path)
        assert_one_line_error(r, "ground truth for frame 7, after the last frame of", "(4)")
        assert r.returncode == 2 and not (tmp_path / "ws").exists()


@pytest.mark.parametrize("argv,named", [
    (["track", "data/s/frames", "--init", "10,10,20,20", "--out", "b.csv", "--inline"], "the graph dcf has no stage "
     "'nosuch' (its stages: source, proposal, filter, recorder; tracker.PARAM sets the tracker's parameters)"),
    (["run", "demo", "--inline"], "the graph demo has no stage 'nosuch' (its stages: source, preprocess, proposal, "
                                  "filter, render, recorder)"),
    (["benchmark", "data", "--trackers", "dcf", "--inline", "-q"], "the graph dcf has no stage 'nosuch'"),
    (["rerun", "{rec}", "--graph"], "demo.mcap has no stage 'nosuch' (its stages: source, preprocess, proposal, "
                                    "filter, render, recorder)"),
])
def test_a_set_of_a_stage_the_graph_lacks_names_the_option(tmp_path: Path, frames: Path, demo_mcap: Path,
                                                           argv: list[str], named: str) -> None:
    """``--set nosuch.x=1`` said "/.../pipeline/graphs/dcf.yaml: override for stage 'nosuch', which the graph does
    not have" (a file the user never named) and ``gflow rerun --graph`` "--set names stage 'nosuch', which the
    recording does not have" (without the stages it has); neither named the value given."""
    one_sequence(tmp_path, frames)
    args = [a.replace("{rec}", str(demo_mcap)) for a in argv]
    r = gflow(*args, "--set", "nosuch.x=1", cwd=tmp_path)
    assert_one_line_error(r, f"{argv[0]}: error: --set nosuch.x=1: ", named)
    assert r.returncode == 2 and sorted(p.name for p in tmp_path.iterdir()) == ["data"], "nothing written"


@pytest.mark.parametrize("item,named", [
    ("tracker.x=1", "the graph demo has no tracker block, and its stage filter has no parameter 'x'; set a stage's "
                    "parameter with --set STAGE.PARAM=VALUE (its stages: source, preprocess, proposal, filter, render, "
                    "recorder)"),
    ("tracker.particles=0", "particles must be >= 1, got 0"),
])
def test_a_tracker_set_of_a_graph_without_a_tracker_block_names_the_option(tmp_path: Path, item: str,
                                                                          named: str) -> None:
    """``gflow run demo --set tracker.x=1`` (the demo graph has no tracker block: tracker.PARAM goes to its stage
    filter) said "/.../pipeline/graphs/demo.yaml:26: stage 'filter': bad parameter for stage kind 'particle.filter':
    no parameter 'x' (known parameters: ...)", quoting a file the user never named."""
    r = gflow("run", "demo", "--inline", "--set", item, cwd=tmp_path)
    line = assert_one_line_error(r, f"gflow run: error: --set {item}: {named}")
    assert r.returncode == 2 and "demo.yaml" not in line and not list(tmp_path.iterdir()), line


@pytest.mark.parametrize("item,named", [
    ("tracker.x=1", "the graph demo has no tracker block, and its stage filter has no parameter 'x'; set a stage's "
                    "parameter with --set STAGE.PARAM=VALUE (its stages: source, preprocess, proposal, filter, render, "
                    "recorder)"),
    ("tracker.particles=0", "particles must be >= 1, got 0"),
])
def test_a_tracker_set_of_a_track_graph_without_a_tracker_block_names_the_option(tmp_path: Path, frames: Path,
                                                                                item: str, named: str) -> None:
    """``gflow track --graph g.yaml --set tracker.x=1`` of a graph file without a tracker block said "g.yaml:26: stage
    'filter': bad parameter for stage kind 'particle.filter': no parameter 'x' (known parameters: ...)", where `gflow
    run` already named the option."""
    (tmp_path / "g.yaml").write_text((ROOT / "pipeline" / "graphs" / "demo.yaml").read_text())
    r = gflow("track", str(frames), "--graph", "g.yaml", "--init", "10,10,20,20", "--out", "b.csv", "--no-record",
              "--inline", "--set", item, cwd=tmp_path)
    line = assert_one_line_error(r, f"gflow track: error: --set {item}: {named}")
    assert r.returncode == 2 and "g.yaml" not in line and not (tmp_path / "b.csv").exists(), line


@pytest.mark.parametrize("argv,named", [
    (["benchmark", "data", "--trackers", "dcf", "--inline", "-q", "--frames", "7:9"],
     "--frames 7:9: data/s/groundtruth.csv has no box for frame 7, the first frame to track (its boxes: frames 0..4)"),
    (["benchmark", "--list-cases", "--cases", "occlude,nosuch"], "unknown stress case 'nosuch' in --cases (known: "),
])
def test_a_benchmark_filter_matching_nothing_names_its_option(tmp_path: Path, frames: Path, argv: list[str],
                                                              named: str) -> None:
    """``--frames 7:9`` past the ground truth said "... has no box for frame 7, the first frame to track", and
    ``--cases occlude,nosuch`` "unknown stress case 'nosuch'": neither named the option (nor the frames there are)."""
    one_sequence(tmp_path, frames)
    r = gflow(*argv, cwd=tmp_path)
    assert_one_line_error(r, f"gflow benchmark: error: {named}")
    assert r.returncode == 2 and not r.stdout and sorted(p.name for p in tmp_path.iterdir()) == ["data"]


@pytest.mark.parametrize("argv,named", [
    (["eval", "--gt", "gt.csv", "--pred", "gt.csv", "--pred", "other.csv"], "--pred given 2 times"),
    (["eval", "--gt", "gt.csv", "--pred=gt.csv", "--pr", "other.csv"], "--pred given 2 times"),
    (["learn", "m2", "frames", "--out", "a.npz", "--out", "b.npz", "-K", "2"], "--out given 2 times"),
    (["track", "frames", "--init", "1,1,9,9", "--init", "2,2,9,9", "--out", "b.csv", "--inline"], "--init given 2"),
])
def test_an_option_of_one_value_given_twice_is_refused(tmp_path: Path, frames: Path, argv: list[str],
                                                       named: str) -> None:
    """argparse kept the last value without a word: `eval --pred a.csv --pred b.csv` scored b.csv alone."""
    (tmp_path / "gt.csv").write_text("0,10,10,20,20\n")
    r = gflow(*argv, cwd=tmp_path)
    assert_one_line_error(r, named, "give it once")
    assert r.returncode == 2 and sorted(p.name for p in tmp_path.iterdir()) == ["frames", "gt.csv"]


def test_options_that_add_up_may_be_given_again(tmp_path: Path, frames: Path) -> None:
    r = gflow("track", "frames", "--init", "20,10,20,20", "--out", "b.csv", "--inline", "--no-record", "-q", "--set",
              "tracker.particles=50", "--set", "tracker.rate=0.03", cwd=tmp_path)
    assert r.returncode == 0, r.stderr


def test_view_on_a_port_in_use_is_refused_before_waiting_for_a_pipeline(tmp_path: Path) -> None:
    """It waited for a pipeline to start (until --duration, or for ever), and only then found the port taken."""
    pytest.importorskip("foxglove", reason="gflow view needs the foxglove-sdk package")
    import socket

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        r = gflow("view", "--port", str(port), "--duration", "30", cwd=tmp_path,
                  env={"GFLOW_RUNTIME_DIR": str(tmp_path)})  # no pipeline announced here: it would wait 30 s
    assert_one_line_error(r, f"cannot serve on 127.0.0.1:{port}", "in use")
    assert r.returncode == 2


@pytest.mark.parametrize("argv", [["run", "demo", "--inline", "--no-record", "--stream", ""],
                                  ["boxes", "x.mcap", "--out", "b.csv", "--stream", ""],
                                  ["replay", "x.mcap", "--max", "--stream", ""], ["ps", "--stream", ""]])
def test_an_empty_stream_name_is_refused(tmp_path: Path, argv: list[str]) -> None:
    """`--stream ''` (an empty shell variable) was taken for no --stream at all: `run` made a run of the default
    stream, `boxes` wrote every stream's estimates, and nothing said so."""
    r = gflow(*argv, cwd=tmp_path)
    assert_one_line_error(r, "argument --stream", "non-empty name")
    assert r.returncode == 2 and not list(tmp_path.iterdir())


@pytest.mark.parametrize("argv,named", [
    (["render", "{rec}", ""], "argument OUT: empty"),
    (["diff", "{rec}", "{rec}", "--topics", ""], "argument --topics: empty"),
    (["track", "frames", "--init", "20,10,20,20", "--out", "b.csv", "--inline", "--record", ""],
     "argument --record: empty"),
    (["boxes", "{rec}", "--out", ""], "argument --out: empty"),
])
def test_an_empty_argument_is_refused_naming_it(tmp_path: Path, frames: Path, demo_mcap: Path, argv: list[str],
                                                named: str) -> None:
    """An argument given as '' (an unset shell variable) was read as not given or as the current folder: `render
    run.mcap ''` drew its PNGs into the current folder, `--record ''` kept the default recording, `--topics ''`
    compared every topic, `boxes --out ''` said "PosixPath('.') has an empty name"."""
    before = sorted(p.name for p in tmp_path.iterdir())
    r = gflow(*[a.replace("{rec}", str(demo_mcap)) for a in argv], cwd=tmp_path)
    assert_one_line_error(r, named, "give a non-empty name or value")
    assert r.returncode == 2 and sorted(p.name for p in tmp_path.iterdir()) == before
