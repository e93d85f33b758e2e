"""What the tools answer can be trusted: on a real recording of a real sequence (caviar1, the
default tracker, 12 frames inline),

* no command replaces an existing recording (``gflow foxglove`` OUT, ``gflow recover`` FIXED);
* a frame window that selects nothing (``replay --from-seq/--to-seq/--start``, ``rerun --from``,
  ``step --start``, ``render --frames``) is a one-line error naming the frames the recording holds,
  not a run over nothing that exits 0;
* a recording whose writer was killed (its footer missing) is named in one line by every command
  that reads only what is before the cut, and a command left with nothing to do exits non-zero,
  naming the cut rather than blaming the run (``boxes``: not "no estimates" alone; ``rerun``: not
  "record every topic");
* a landmark file that is not an .npz archive is called that (not "pickled data").

Every case runs the CLI as a subprocess, as a user would.
"""

from __future__ import annotations

import hashlib
import struct
from pathlib import Path

import pytest

from conftest import data_dir
from test_cli_errors import assert_one_line_error, gflow

FRAMES = 12


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """caviar1's first frames tracked inline and recorded: frames 0..FRAMES-1."""
    seq = data_dir("caviar1")
    where = tmp_path_factory.mktemp("trust")
    r = gflow("track", str(seq), "--init", "129,71,30,79", "--out", "boxes.csv", "--inline", "--stop", str(FRAMES),
              "--record", "run.mcap", "-q", cwd=where)
    assert r.returncode == 0, r.stderr
    return where / "run.mcap"


@pytest.fixture(scope="module")
def chunked(tmp_path_factory) -> Path:
    """The same run recorded with a chunk closed after every message: the layout the recorder's 0.5 s flush
    timer gives a run on a machine so loaded that the run outlasts it (on an idle one the run is done in
    0.2 s and its chunks are closed by size, 4 MB, alone)."""
    seq = data_dir("caviar1")
    where = tmp_path_factory.mktemp("trust-chunked")
    r = gflow("track", str(seq), "--init", "129,71,30,79", "--out", "boxes.csv", "--inline", "--stop", str(FRAMES),
              "--record", "run.mcap", "--set", "recorder.flush_interval=0.0001", "-q", cwd=where)
    assert r.returncode == 0, r.stderr
    return where / "run.mcap"


@pytest.fixture(params=["recording", "chunked"])
def any_layout(request) -> Path:
    """The run's recording as the recorder lays it out on an idle machine, and on a loaded one."""
    return request.getfixturevalue(request.param)


def _chunks(data: bytes) -> list[tuple[int, int]]:
    """(start, end) byte offsets of the chunk records of an MCAP file, in file order: where a cut falls is said by
    the file's own layout, not by a fraction of its size (the layout depends on how fast the run went)."""
    out, pos = [], 8  # after the magic bytes; each record: opcode u8, length u64, content
    while pos + 9 <= len(data):
        op, n = struct.unpack_from("<BQ", data, pos)
        if op == 0x06:  # Chunk
            out.append((pos, pos + 9 + n))
        elif op == 0x0F:  # DataEnd
            break
        pos += 9 + n
    assert out, "a recording holds its messages in chunks"
    return out


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.mark.parametrize("cmd", ["foxglove", "recover"])
def test_no_command_replaces_an_existing_recording(recording: Path, tmp_path: Path, cmd: str) -> None:
    other = tmp_path / "other.mcap"
    other.write_bytes(recording.read_bytes())
    before = _digest(other)
    r = gflow(cmd, str(recording), str(other), cwd=tmp_path)
    assert_one_line_error(r, "other.mcap is a recording", "never writes over one")
    assert _digest(other) == before


@pytest.mark.parametrize("args, words", [
    # the frames recorded, 0..11 (it said 0..12: the proposals for the next frame carry its number)
    (["replay", "--max", "--from-seq", "500"], ["--from-seq 500", f"frames 0..{FRAMES - 1} over"]),
    (["replay", "--max", "--from-seq", "500", "--topics", "estimate"], ["--from-seq 500", "no frame",
                                                                        f"sequence numbers 0..{FRAMES - 1}"]),
    (["replay", "--max", "--from-seq", "5", "--to-seq", "3"], ["--from-seq 5, --to-seq 3"]),
    (["replay", "--max", "--start", "1000"], ["--start 1000"]),
    (["rerun", "--stage", "filter", "--from", "500"], ["--from 500", f"frames 0..{FRAMES - 1} for stage filter"]),
    (["step", "--stage", "filter", "--start", "500"], ["--start", "no frame 500", f"frames 0..{FRAMES - 1} for stage"]),
    (["render", "OUT.mp4", "--frames", "500:600"], ["--frames 500:600", "no frame to draw"]),
    (["render", "OUT.mp4", "--frames", "x:3"], ["--frames x:3", "A:B"]),
])
def test_a_window_that_selects_nothing_is_an_error(recording: Path, tmp_path: Path, args: list[str],
                                                   words: list[str]) -> None:
    cmd, *rest = args
    r = gflow(cmd, str(recording), *rest, cwd=tmp_path)
    assert_one_line_error(r, *words)
    assert not list(tmp_path.iterdir()), "nothing is written for a window that selects nothing"


def test_a_window_inside_the_recording_still_works(recording: Path, tmp_path: Path) -> None:
    r = gflow("render", str(recording), "out.mp4", "--frames", "3:5", "-q", cwd=tmp_path)
    assert r.returncode == 0 and "drew 2 frames" in r.stdout, r.stderr
    r = gflow("rerun", str(recording), "--stage", "filter", "--from", "4", "--check", cwd=tmp_path)
    assert r.returncode == 0 and "all identical" in r.stdout, r.stdout + r.stderr


def test_a_torn_recording_is_named_by_what_reads_it(any_layout: Path, tmp_path: Path) -> None:
    """Cut inside its last chunk (so what is before the cut is there to read, whatever the layout; a cut at 80 %
    of the bytes fell wherever the run's timing had put the chunks), every output in this test's own folder."""
    recording = any_layout
    data = recording.read_bytes()
    torn = tmp_path / "torn.mcap"
    start, end = _chunks(data)[-1]
    torn.write_bytes(data[: (start + end) // 2])
    for args in (["plot", str(torn), str(tmp_path / "p.png")], ["render", str(torn), str(tmp_path / "v.mp4"), "-q"],
                 ["foxglove", str(torn), str(tmp_path / "f.mcap")], ["diff", str(torn), str(recording)]):
        r = gflow(*args, cwd=tmp_path)
        assert "Traceback" not in r.stderr, r.stderr
        warned = [ln for ln in r.stderr.splitlines() if "not closed properly" in ln]
        assert len(warned) == 1 and "torn.mcap" in warned[0], (args, r.stderr)
    whole = gflow("plot", str(recording), str(tmp_path / "q.png"), cwd=tmp_path)
    assert whole.returncode == 0 and "not closed" not in whole.stderr, whole.stderr


def test_a_torn_recording_with_nothing_readable_fails(any_layout: Path, tmp_path: Path) -> None:
    """Cut inside its first chunk, wherever the run's timing put that chunk's end: a cut at a fixed 3 MB was inside
    it only when the run was fast (on a loaded machine the 0.5 s flush timer closed the first chunk sooner, and
    the "nothing readable" file held messages)."""
    from pipeline.io.mcap_io import iter_records

    data = any_layout.read_bytes()
    head = tmp_path / "head.mcap"
    start, end = _chunks(data)[0]
    head.write_bytes(data[: (start + end) // 2])  # the header and metadata, cut inside the first chunk
    assert not list(iter_records(head, on_truncated=lambda note: None))
    r = gflow("step", str(head), "--stage", "filter", cwd=tmp_path)
    assert r.returncode == 2 and "holds no input of stage filter" in r.stderr.splitlines()[-1], r.stderr
    r = gflow("foxglove", str(head), "f.mcap", cwd=tmp_path)
    assert r.returncode == 1 and "no message of" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "f.mcap").exists()
    # the cut is named, not taken for what the run recorded ("no estimates", "record every topic")
    r = gflow("boxes", str(head), "--out", "b.csv", cwd=tmp_path)
    assert_one_line_error(r, "head.mcap holds no estimates", "ends early", "gflow recover")
    for scope in (["--stage", "filter"], ["--graph"]):
        r = gflow("rerun", str(head), *scope, "--check", cwd=tmp_path)
        assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
        last = r.stderr.strip().splitlines()[-1]
        assert "not in what can be read of" in last and "ends early" in last and "record every topic" not in last, last
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr  # the cut said once, in the error itself
    assert not (tmp_path / "b.csv").exists()


def test_a_landmark_file_that_is_not_an_archive_is_called_that(tmp_path: Path) -> None:
    (tmp_path / "ref.npz").write_text("frame,x,y\n")
    (tmp_path / "p.csv").write_text("frame,landmark,x,y\n0,0,1,1\n")
    r = gflow("eval", "--landmarks", "ref.npz", "--points", "p.csv", cwd=tmp_path)
    line = assert_one_line_error(r, "ref.npz", "not a zip archive")
    assert "pickle" not in line



def _without_tracker_block(rec: Path, out: Path) -> None:
    """A copy of ``rec`` whose plan is written as before the tracker block: each stage of the
    tracker holds its own copy of the tracker's values, and there is no ``tracker`` entry."""
    import json

    from pipeline.io.mcap_io import iter_records, read_metadata
    from pipeline.io.recorder import McapRecorder

    md = read_metadata(rec)
    config = dict(md["gflow.config"])
    block = json.loads(config.pop("tracker"))
    for key, val in config.items():
        if key.startswith("stage."):
            sp = json.loads(val)
            if sp["kind"].startswith(block["name"] + "."):
                sp["params"] = {**block["params"], **sp["params"]}
                config[key] = json.dumps(sp, sort_keys=True)
    with McapRecorder(out, metadata={"gflow.graph": md["gflow.graph"], "gflow.config": config}) as w:
        for r in iter_records(rec):
            w.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, log_ns=r.log_ns)


def test_set_tracker_on_a_recording_from_before_the_tracker_block(recording: Path, tmp_path: Path) -> None:
    """``rerun --graph --set tracker.X=V`` on a plan that names its tracker's values per stage sets
    every stage's copy: the re-run is the one of a recording with the block."""
    from pipeline.io.mcap_io import iter_records

    old = tmp_path / "old.mcap"
    _without_tracker_block(recording, old)
    outs = {}
    for name, rec in (("old", old), ("new", recording)):
        r = gflow("rerun", str(rec), "--graph", "--set", "tracker.particles=50", "--out", f"{name}-50.mcap",
                  cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert "outputs differ" in r.stdout, r.stdout  # 50 particles, not the recorded 200
        outs[name] = [(x.topic, x.seq, x.data) for x in iter_records(tmp_path / f"{name}-50.mcap")
                      if x.topic.endswith(("/estimate", "/proposals", "/particles"))]
    assert outs["old"] and outs["old"] == outs["new"]


def test_a_value_set_for_another_stage_is_not_given_to_the_one_rerun(recording: Path, tmp_path: Path) -> None:
    """``--stage proposal --set filter.seed=7`` set the proposal's seed; it is an error naming both."""
    r = gflow("rerun", str(recording), "--stage", "proposal", "--set", "filter.seed=7", cwd=tmp_path)
    assert_one_line_error(r, "--set filter.seed", "--stage proposal", "--graph")
    r = gflow("rerun", str(recording), "--stage", "proposal", "--set", "proposal.seed=1", "--check", cwd=tmp_path)
    assert r.returncode == 0 and "all identical" in r.stdout, r.stdout + r.stderr


@pytest.mark.parametrize("given, flag, kind, wanted", [
    ("frame,x,y,w,h,confidence,state\n0,40.00,40.00,20.00,50.00,1.000,tracked\n", "--points", "box", "points"),
    ("frame,landmark,x,y\n0,33,10.0,20.0\n", "--pred", "points", "box"),
])
def test_a_csv_of_another_kind_is_called_that(tmp_path: Path, given: str, flag: str, kind: str, wanted: str) -> None:
    """A boxes file given for face points (or the reverse) is named as such, not "not numbers" at its line 2."""
    (tmp_path / "f.csv").write_text(given)
    if flag == "--points":
        args = ["eval", "--landmarks", str(data_dir("david_indoor") / "landmarks.npz"), "--points", "f.csv"]
    else:
        (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n0,1,1,5,5\n")
        args = ["eval", "--gt", "gt.csv", "--pred", "f.csv"]
    r = gflow(*args, cwd=tmp_path)
    line = assert_one_line_error(r, "f.csv is a", f"{kind} file", f"not a {wanted} file")
    assert "not numbers" not in line
