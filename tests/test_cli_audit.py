"""The recording tools' answers, checked against mistakes and damaged input on the real command line:
a filter that matches nothing, a file damaged or not what it is named for, an option out of range,
an output already there -- each a non-zero exit with a line naming the file or option and what is
wrong (never a traceback, never an empty success), and nothing written over.

Every case runs ``gflow`` as a subprocess on real MCAP files: one short recording of the synthetic
scene made once (``gflow demo --inline``) and copies of it cut, flipped or rewritten.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

import cli_fork
from conftest import damaged_copy

ROOT = Path(__file__).resolve().parent.parent


def gflow(*args: str, cwd: Path, timeout: float = 60.0, stdin: str | None = None) -> subprocess.CompletedProcess:
    """``gflow ARGS`` in a process of its own, forked from one that has imported the command line (:mod:`cli_fork`)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return cli_fork.run(list(args), cwd=cwd, env=env, timeout=timeout, input=stdin if stdin is not None else "")


def error_line(r: subprocess.CompletedProcess, *words: str, rc: int | None = None) -> str:
    """The last line of stderr, of a command that failed without a traceback, holding ``words``."""
    assert r.returncode != 0 and (rc is None or r.returncode == rc), (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert lines, r.stdout
    for w in words:
        assert w in lines[-1], lines[-1]
    return lines[-1]


def one_line_error(r: subprocess.CompletedProcess, *words: str, rc: int | None = None) -> str:
    line = error_line(r, *words, rc=rc)
    assert len([ln for ln in r.stderr.splitlines() if ln.strip()]) == 1, r.stderr
    return line


@pytest.fixture(scope="module")
def rec(tmp_path_factory) -> Path:
    """A folder holding demo.mcap (8 frames of the synthetic scene, closed) and damaged copies of it:
    damaged.mcap (a chunk in the middle fails its CRC; many small chunks), head.mcap (the header's
    bytes flipped: the file still ends as a closed one does), torn.mcap (its first 300 bytes: no
    message)."""
    d = tmp_path_factory.mktemp("audit")
    r = gflow("demo", "--frames", "8", "--inline", "--record", "demo.mcap", cwd=d)
    assert r.returncode == 0, r.stderr
    data = (d / "demo.mcap").read_bytes()
    damaged_copy(d / "demo.mcap", d / "damaged.mcap")
    head = bytearray(data)
    head[20:36] = bytes(b ^ 0xFF for b in head[20:36])
    (d / "head.mcap").write_bytes(bytes(head))
    (d / "torn.mcap").write_bytes(data[:300])
    return d


# -- damage the readers must not take for an empty recording ----------------------------------------------


def test_a_closed_recording_damaged_near_its_start_is_called_damaged(rec: Path, tmp_path: Path) -> None:
    """A damaged record length had the reader run to the end of the file, which it took for a torn end:
    `gflow info` said the file 'was not closed properly', and diff, plot and the rest read it as a
    recording with no message, without a word of damage."""
    r = gflow("info", str(rec / "head.mcap"), cwd=tmp_path)
    assert r.returncode == 1 and "damaged" in r.stdout and "not closed properly" not in r.stdout, r.stdout
    r = gflow("plot", str(rec / "head.mcap"), "p.png", cwd=tmp_path)
    error_line(r, "has no estimates to plot", "head.mcap: recording is damaged", rc=2)
    assert not (tmp_path / "p.png").exists()


# -- gflow diff --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("a,b", [("torn.mcap", "torn.mcap"), ("head.mcap", "torn.mcap")])
def test_diff_of_recordings_with_nothing_to_compare_is_an_error(rec: Path, tmp_path: Path, a: str, b: str) -> None:
    """Two recordings with no message that can be read were 'identical' (exit 0)."""
    r = gflow("diff", str(rec / a), str(rec / b), cwd=tmp_path)
    line = error_line(r, "nothing to compare", rc=2)
    assert "identical" not in r.stdout
    assert ("damaged" in line) == (a == "head.mcap"), line


def test_diff_of_a_damaged_recording_says_what_was_not_compared(rec: Path, tmp_path: Path) -> None:
    """A damaged recording diffed with itself was 'identical' (exit 0), though nothing after the damage
    was compared."""
    for args in ([], ["--json"]):
        r = gflow("diff", str(rec / "damaged.mcap"), str(rec / "damaged.mcap"), *args, cwd=tmp_path)
        assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
        if not args:
            last = r.stdout.strip().splitlines()[-1]
            assert "nothing after the damage was compared" in last and "damaged.mcap" in last, last
        else:
            assert "damaged.mcap: recording is damaged" in r.stderr.strip().splitlines()[-1], r.stderr
    r = gflow("diff", str(rec / "demo.mcap"), str(rec / "demo.mcap"), cwd=tmp_path)  # an intact one still is
    assert r.returncode == 0 and r.stdout.strip().endswith("identical"), r.stdout


@pytest.mark.parametrize("args, status", [
    (["boxes", "{r}", "--out", "OUT"], 3),
    (["render", "{r}", "OUT", "-q"], 1),
    (["plot", "{r}", "OUT"], 1),
    (["foxglove", "{r}", "OUT"], 1),
])
def test_an_output_of_a_damaged_recording_is_not_reported_as_whole(rec: Path, tmp_path: Path, args: list[str],
                                                                   status: int) -> None:
    """boxes, render, plot and foxglove wrote what could be read before the damage and exited 0, as if the run had
    ended there, though the recording goes on after it; the output is kept, the exit status says it is partial."""
    out = {"boxes": "b.csv", "render": "v.mp4", "plot": "p.png", "foxglove": "f.mcap"}[args[0]]
    r = gflow(*[a.replace("{r}", str(rec / "damaged.mcap")).replace("OUT", out) for a in args], cwd=tmp_path)
    # one line, naming the damage, which was said twice by some of them (a warning, then their own words)
    line = one_line_error(r, f"{out} holds only what was read before the damage: ", "damaged.mcap: recording is "
                          "damaged at byte", rc=status)
    assert line.startswith(f"gflow {args[0]}: ") and (tmp_path / out).is_file()
    assert sum("recording is damaged" in ln for ln in r.stdout.splitlines() + r.stderr.splitlines()) == 1, r
    whole = gflow(*[a.replace("{r}", str(rec / "demo.mcap")).replace("OUT", "whole-" + out) for a in args], cwd=tmp_path)
    assert whole.returncode == 0 and not whole.stderr.strip(), whole.stderr  # an intact one still is whole


@pytest.mark.parametrize("args", [["info", "{r}"], ["boxes", "{r}", "--out", "b.csv"], ["render", "{r}", "v.mp4"],
                                  ["plot", "{r}", "p.png"], ["foxglove", "{r}", "f.mcap"], ["replay", "{r}", "--max"],
                                  ["rerun", "{r}", "--stage", "filter"], ["frame", "{r}", "0", "f.png"]])
def test_a_recording_damaged_in_its_only_chunk_is_said_in_one_line(rec: Path, tmp_path: Path, args: list[str]) -> None:
    """Every message in one chunk, the chunk damaged: most commands said the damage twice, a warning and then their
    error repeating it (render and replay: a warning, then "no frame" / "nothing to replay" without it)."""
    data = bytearray((rec / "demo.mcap").read_bytes())
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(b ^ 0xFF for b in data[mid:mid + 64])
    (tmp_path / "one.mcap").write_bytes(bytes(data))
    r = gflow(*[a.replace("{r}", "one.mcap") for a in args], cwd=tmp_path)
    assert r.returncode != 0 and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]  # (info's report on stdout says where, as it did)
    assert len(lines) == 1 and "one.mcap" in lines[0] and "damaged" in lines[0], r.stderr


def test_a_replay_of_a_damaged_recording_is_not_reported_as_whole(rec: Path, tmp_path: Path) -> None:
    """It said "replayed N messages" and exited 0, what came after the damage never sent."""
    r = gflow("replay", str(rec / "damaged.mcap"), "--max", cwd=tmp_path)
    error_line(r, "the replay holds only what was read before the damage: ", "damaged.mcap: recording is damaged", rc=1)
    whole = gflow("replay", str(rec / "demo.mcap"), "--max", cwd=tmp_path)
    assert whole.returncode == 0 and "replayed" in whole.stderr, whole.stderr


# -- gflow rerun -------------------------------------------------------------------------------------------


def test_rerun_graph_with_topics_matching_nothing_is_refused_before_it_runs(rec: Path, tmp_path: Path) -> None:
    """The whole graph was re-run and its recording written beside the input, then --topics refused."""
    (tmp_path / "demo.mcap").write_bytes((rec / "demo.mcap").read_bytes())
    r = gflow("rerun", "demo.mcap", "--graph", "--topics", "nosuch", cwd=tmp_path)
    one_line_error(r, "--topics nosuch: ", "estimate", rc=2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.mcap"], "no re-run recording"


@pytest.mark.parametrize("args,where", [
    (["replay", "{r}", "--max"], "{r}"),
    (["foxglove", "{r}", "f.mcap"], "{r}"),
    (["diff", "{r}", "{r}"], "{r} or {r}"),
    (["rerun", "{r}", "--stage", "filter"], "the re-run's outputs"),
    (["step", "{r}", "--stage", "filter"], "stage filter's outputs"),
])
def test_topics_matching_nothing_names_the_option_and_the_part(rec: Path, tmp_path: Path, args: list[str],
                                                              where: str) -> None:
    """"no topic of demo.mcap matches 'nosuch'; it holds: ..." named no option: ``--topics estimate nosuch`` did not
    say which option the word that matched nothing was given to."""
    (tmp_path / "demo.mcap").write_bytes((rec / "demo.mcap").read_bytes())
    r = gflow(*[a.replace("{r}", "demo.mcap") for a in args], "--topics", "estimate", "nosuch", cwd=tmp_path)
    line = one_line_error(r, f"--topics nosuch: no topic of {where.replace('{r}', 'demo.mcap')} matches it; it holds: ",
                          rc=2)
    assert "estimate" in line.split("it holds: ")[1], line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.mcap"], "nothing written"


def test_rerun_of_a_damaged_recording_is_not_a_check(rec: Path, tmp_path: Path) -> None:
    """'all identical bit for bit' and exit 0 with --check, though nothing after the damage was re-run."""
    r = gflow("rerun", str(rec / "damaged.mcap"), "--stage", "filter", "--check", cwd=tmp_path)
    assert r.returncode == 1 and "Traceback" not in r.stderr, (r.stdout, r.stderr)
    last = r.stdout.strip().splitlines()[-1]
    assert "not a check of the whole run" in last and "damaged.mcap: recording is damaged" in last, last


def test_rerun_of_a_recording_damaged_before_its_stage_inputs_names_the_damage(rec: Path, tmp_path: Path) -> None:
    """It re-ran '0 steps' and reported '2 of 0 outputs differ'; a header damaged was 'not written by
    gflow's recorder'."""
    cut = tmp_path / "early.mcap"  # its only data chunk damaged: the metadata after it is still read
    data = bytearray((rec / "demo.mcap").read_bytes())
    data[len(data) // 10:len(data) // 10 + 16] = bytes(b ^ 0xFF for b in data[len(data) // 10:len(data) // 10 + 16])
    cut.write_bytes(bytes(data))
    r = gflow("rerun", str(cut), "--stage", "filter", cwd=tmp_path)
    error_line(r, "holds no input of stage filter", "early.mcap: recording is damaged", rc=2)
    for cmd in ("rerun", "step"):
        r = gflow(cmd, str(rec / "head.mcap"), "--stage", "filter", cwd=tmp_path)
        one_line_error(r, "head.mcap: recording is damaged", rc=2)
        assert "not written by gflow" not in r.stderr


@pytest.mark.parametrize("args", [["track", "demo.mcap", "--init", "10,10,20,20", "--out", "b.csv", "--start", "100",
                                   "--inline"], ["frame", "demo.mcap", "100", "f.png"]])
def test_a_frame_past_a_recordings_frames_says_which_it_holds(rec: Path, tmp_path: Path, args: list[str]) -> None:
    """'demo.mcap: no frame at or after --start 100' (and gflow frame's 'at or after frame 100') did not say what the
    recording holds, where an image folder's said its frames (replay, rerun, step and render say them too)."""
    (tmp_path / "demo.mcap").write_bytes((rec / "demo.mcap").read_bytes())
    r = gflow(*args, cwd=tmp_path)
    one_line_error(r, "demo.mcap: no frame at or after ", " 100 (it holds frames 0..7)", rc=2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.mcap"], "nothing written"


# -- gflow step, fed by a script ---------------------------------------------------------------------------


@pytest.mark.parametrize("script,line,words", [
    ("n\nj abc\nn\n", 2, ["usage: j SEQ"]),
    ("j 9999\nn\n", 1, ["no frame 9999", "frames 0..7"]),  # demo.mcap's 8 frames, not the proposals' 8
])
def test_step_stops_at_a_jump_its_script_cannot_make(rec: Path, tmp_path: Path, script: str, line: int,
                                               words: list[str]) -> None:
    """Commands piped in: a jump that could not be made was answered on stdout and the script went on
    (exit 0) from where it was, the frames after it shown as if they were the ones asked for."""
    r = gflow("step", str(rec / "demo.mcap"), "--stage", "filter", cwd=tmp_path, stdin=script)
    one_line_error(r, f"standard input line {line}:", *words, rc=2)
    assert r.stdout.count("--- frame ") == script[:line * 2].count("n\n"), r.stdout


def test_step_script_without_mistakes_still_runs_to_its_end(rec: Path, tmp_path: Path) -> None:
    r = gflow("step", str(rec / "demo.mcap"), "--stage", "filter", cwd=tmp_path, stdin="n\nj 3\ns\nq\n")
    assert r.returncode == 0 and r.stderr == "" and "--- frame 3 " in r.stdout, (r.stdout, r.stderr)


# -- gflow plot, gflow frame: sizes and ground truth -------------------------------------------------------


@pytest.mark.parametrize("value,words", [("0", ["--dpi", "1-1000", "got 0"]), ("100000", ["--dpi", "1-1000"])])
def test_plot_dpi_out_of_range_names_the_option_before_any_work(rec: Path, tmp_path: Path, value: str,
                                                                words: list[str]) -> None:
    """0 was refused after the recording was read as 'dpi must be positive', naming no option; 100000
    ended in 'internal error: MemoryError'."""
    r = gflow("plot", str(rec / "demo.mcap"), "p.png", "--dpi", value, cwd=tmp_path)
    one_line_error(r, *words, rc=2)
    assert not (tmp_path / "p.png").exists()


def test_plot_ground_truth_of_other_frames_is_refused(rec: Path, tmp_path: Path) -> None:
    """A plot was written with an empty error panel, exit 0, as of a run with no ground truth given."""
    (tmp_path / "far.csv").write_text("frame,x,y,w,h\n5000,10,10,20,20\n5001,10,10,20,20\n")
    r = gflow("plot", str(rec / "demo.mcap"), "p.png", "--gt", "far.csv", cwd=tmp_path)
    one_line_error(r, "--gt far.csv", "5000..5001", "demo.mcap", rc=2)
    assert not (tmp_path / "p.png").exists()


def test_plot_of_a_rerun_recording_prints_no_numpy_warnings(rec: Path, tmp_path: Path) -> None:
    """A re-run's recording has outputs with no input published before them: each such stage's empty
    latency series printed numpy's 'Mean of empty slice' RuntimeWarnings (four lines) before 'wrote'."""
    r = gflow("rerun", str(rec / "demo.mcap"), "--stage", "filter", "--out", "r.mcap", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = gflow("plot", "r.mcap", "p.png", cwd=tmp_path)
    assert r.returncode == 0 and r.stderr == "" and (tmp_path / "p.png").is_file(), r.stderr


def test_frame_scaled_past_any_picture_is_refused(rec: Path, tmp_path: Path) -> None:
    """--scale 1000 ended in an out-of-memory 'internal error' from OpenCV."""
    r = gflow("frame", str(rec / "demo.mcap"), "2", "f.png", "--scale", "1000", cwd=tmp_path)
    one_line_error(r, "--scale 1000", "320x240", "at most 102", rc=2)
    assert not (tmp_path / "f.png").exists()


@pytest.mark.parametrize("out", ["v.mp4", "pictures"])
def test_render_scaled_past_any_picture_is_refused(rec: Path, tmp_path: Path, out: str) -> None:
    """gflow render --scale 1000 ended in an out-of-memory 'internal error' from OpenCV, as gflow frame's did."""
    r = gflow("render", str(rec / "demo.mcap"), out, "--scale", "1000", cwd=tmp_path)
    one_line_error(r, "--scale 1000", "320x240", "at most 102", rc=2)
    assert not list(tmp_path.iterdir())


# -- ranges partly past the input ---------------------------------------------------------------------------


def _boxes_and_points(d: Path) -> None:
    """gt.csv (boxes of frames 0..7, as demo.mcap's) and ref.npz / pts.csv (face points of frames 0..4)."""
    (d / "gt.csv").write_text("frame,x,y,w,h\n" + "".join(f"{f},{10 + f},10,20,20\n" for f in range(8)))
    rng = np.random.default_rng(0)
    np.savez(d / "ref.npz", landmarks=rng.uniform(0, 100, (5, 468, 2)))
    (d / "pts.csv").write_text("frame,landmark,x,y\n" + "".join(f"{f},{i},1,2\n" for f in range(5)
                                                                 for i in (33, 133, 263, 362, 61, 291)))


@pytest.mark.parametrize("args,said", [
    (["render", "demo.mcap", "v.mp4", "-q", "--frames", "5:12"], "--frames 5:12: demo.mcap holds frames 0..7; drawing 5..7"),
    (["replay", "demo.mcap", "--max", "--to-seq", "12"], "--to-seq 12: demo.mcap holds frames 0..7; replaying 0..7"),
    (["replay", "demo.mcap", "--max", "--from-seq", "5", "--to-seq", "12"],
     "--from-seq 5 --to-seq 12: demo.mcap holds frames 0..7; replaying 5..7"),
    (["replay", "demo.mcap", "--max", "--end", "1000"], "--end 1000: demo.mcap holds 0."),
    (["eval", "--gt", "gt.csv", "--pred", "gt.csv", "--frames", "5:12"], "--frames 5:12: gt.csv holds frames 0..7; "
                                                                        "scoring 5..7"),
    (["eval", "--landmarks", "ref.npz", "--points", "pts.csv", "--frames", "3:9"],
     "--frames 3:9: ref.npz holds frames 0..4; scoring 3..4"),
])
def test_a_range_partly_past_the_input_says_what_it_took(rec: Path, tmp_path: Path, args: list[str], said: str) -> None:
    """A range running past the last frame was clipped without a word (exit 0): `gflow render --frames 5:12` of 8
    frames drew 3 and said "drew 3 frames", as if the rest were not asked for; replay --to-seq and --end, and eval
    --frames, likewise. A note now names the option, what the input holds and what was taken; the exit is still 0,
    and a range within the input says nothing."""
    (tmp_path / "demo.mcap").write_bytes((rec / "demo.mcap").read_bytes())
    _boxes_and_points(tmp_path)
    r = gflow(*args, cwd=tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    notes = [ln for ln in r.stderr.splitlines() if ln.startswith("note: ")]
    assert len(notes) == 1 and notes[0].startswith(f"note: {said}"), r.stderr
    if "--end" in args:  # the recording's length, and the part replayed: all of it
        assert re.fullmatch(r"note: --end 1000: demo\.mcap holds (\d+\.\d{3}) s; replaying 0\.000\.\.\1 s", notes[0]), notes
    inside = [a.replace("12", "8").replace("1000", "0.01").replace("3:9", "3:5") for a in args]
    inside = [a.replace("v.mp4", "w.mp4") for a in inside]
    r = gflow(*inside, cwd=tmp_path)
    assert r.returncode == 0 and "note: " not in r.stderr, r.stderr


# -- gflow eval --------------------------------------------------------------------------------------------


def test_eval_of_points_on_none_of_the_reference_frames_is_refused(tmp_path: Path) -> None:
    """Scored 'NME nan', 'error nan px' with exit 0; boxes on no ground-truth frame were already refused."""
    rng = np.random.default_rng(0)
    np.savez(tmp_path / "ref.npz", landmarks=rng.uniform(0, 100, (5, 468, 2)))
    (tmp_path / "far.csv").write_text("frame,landmark,x,y\n" + "".join(f"900,{i},1,2\n" for i in (33, 133, 263)))
    r = gflow("eval", "--landmarks", "ref.npz", "--points", "far.csv", cwd=tmp_path)
    one_line_error(r, "no frame has both", "ref.npz: frames 0..4", "far.csv: frames 900..900", rc=2)
    assert r.stdout == ""


# -- gflow export vot --------------------------------------------------------------------------------------


@pytest.fixture()
def two_sequences(tmp_path: Path) -> Path:
    """data/good (3 frames and their boxes) and data/bad (a groundtruth.csv with a row of words)."""
    import cv2

    rng = np.random.default_rng(0)
    for name in ("good", "bad"):
        (tmp_path / "data" / name / "frames").mkdir(parents=True)
        for i in range(3):
            cv2.imwrite(str(tmp_path / "data" / name / "frames" / f"{i:04d}.png"),
                        rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    (tmp_path / "data" / "good" / "groundtruth.csv").write_text("frame,x,y,w,h\n0,10,10,20,20\n1,11,10,20,20\n")
    (tmp_path / "data" / "bad" / "groundtruth.csv").write_text("frame,x,y,w,h\n0,10,10,20,20\n1,abc,10,20,20\n")
    return tmp_path


def test_export_vot_of_chosen_sequences_reads_only_those(two_sequences: Path) -> None:
    """A sequence left out by --sequences, with a bad groundtruth.csv, refused the whole export (and a
    mistyped name in --sequences was hidden behind it)."""
    r = gflow("export", "vot", "data", "ws", "--sequences", "good", cwd=two_sequences)
    assert r.returncode == 0 and (two_sequences / "ws" / "sequences" / "good" / "groundtruth.txt").is_file(), r.stderr
    assert not (two_sequences / "ws" / "sequences" / "bad").exists()
    for chosen, words in (("nosuch", ["unknown sequence nosuch", "known: bad, good"]),
                          ("", ["argument --sequences: empty"]),
                          ("bad", ["bad/groundtruth.csv:3", "not numbers"])):
        r = gflow("export", "vot", "data", "ws2", "--sequences", chosen, cwd=two_sequences)
        one_line_error(r, *words, rc=2)
        assert not (two_sequences / "ws2").exists()


# -- gflow clean -------------------------------------------------------------------------------------------


def test_clean_leaves_alone_a_file_named_mcap_that_is_not_a_recording(rec: Path, tmp_path: Path) -> None:
    """Every *.mcap was removed as a recording, whatever it held (notes, another program's data)."""
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "old.mcap").write_bytes((rec / "torn.mcap").read_bytes())
    os.utime(runs / "old.mcap", (1, 1))
    (runs / "notes.mcap").write_text("not a recording\n")
    os.utime(runs / "notes.mcap", (2, 2))  # older than old.mcap: it would be the first to go
    (runs / "new.mcap").write_bytes((rec / "torn.mcap").read_bytes())
    r = gflow("clean", "runs", "--keep", "1", cwd=tmp_path)
    assert r.returncode == 0 and "removed 1 recording(s)" in r.stdout, (r.stdout, r.stderr)
    assert sorted(p.name for p in runs.iterdir()) == ["new.mcap", "notes.mcap"]
    assert "notes.mcap" in r.stderr and "not MCAP" in r.stderr, r.stderr


def test_a_recording_with_bytes_after_its_end_is_called_damaged(rec: Path, tmp_path: Path) -> None:
    """A second copy appended (two writers on one file) was not read, and `gflow info` said nothing of
    it (exit 0) though `gflow verify` calls the file damaged."""
    data = (rec / "demo.mcap").read_bytes()
    (tmp_path / "twice.mcap").write_bytes(data + data)
    r = gflow("info", "twice.mcap", cwd=tmp_path)
    assert r.returncode == 1 and f"{len(data)} bytes after its closing magic bytes" in r.stdout, r.stdout
    assert "the recording is damaged" in r.stderr, r.stderr


# -- gflow foxglove ----------------------------------------------------------------------------------------


def test_foxglove_of_topics_it_cannot_show_names_the_option(rec: Path, tmp_path: Path) -> None:
    """'no message of demo.mcap could be copied' (exit 1), as of a damaged recording, when --topics chose
    only features and particles, which a Foxglove copy leaves out."""
    r = gflow("foxglove", str(rec / "demo.mcap"), "f.mcap", "--topics", "features", "particles", cwd=tmp_path)
    one_line_error(r, "--topics features particles", "Foxglove cannot show", "features, particles", rc=2)
    assert not (tmp_path / "f.mcap").exists()


@pytest.mark.parametrize("size,words", [(0, ["is empty (0 bytes)"]), (4, ["ends after 4 bytes", "torn"])])
@pytest.mark.parametrize("cmd", [["info"], ["diff", "{rec}/demo.mcap"], ["replay"]])
def test_an_empty_or_barely_begun_recording_is_called_so(rec: Path, tmp_path: Path, size: int, words: list[str],
                                                         cmd: list[str]) -> None:
    """Both were 'not an MCAP file (bad magic bytes ...)', b'' for an empty one."""
    (tmp_path / "r.mcap").write_bytes((rec / "demo.mcap").read_bytes()[:size])
    r = gflow(*[c.replace("{rec}", str(rec)) for c in cmd], "r.mcap", cwd=tmp_path)
    one_line_error(r, "r.mcap", *words, rc=2)
    assert "bad magic" not in r.stderr


def test_frame_of_a_recording_kept_without_frames_says_so(tmp_path: Path) -> None:
    """'no frame at or after frame 0', as if frame 0 were missing, of a run recorded with --record-topics
    estimate (which keeps no frame at all)."""
    r = gflow("demo", "--frames", "3", "--inline", "--record", "est.mcap", "--record-topics", "estimate",
              cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = gflow("frame", "est.mcap", "0", "f.png", cwd=tmp_path)
    one_line_error(r, "est.mcap holds no frames", "estimate", rc=2)
    assert not (tmp_path / "f.png").exists()


# -- gflow replay ------------------------------------------------------------------------------------------


def test_replay_speed_too_slow_for_the_clock_is_refused_as_parsed(rec: Path, tmp_path: Path) -> None:
    """--speed 1e-308 passed (it is > 0), joined the network and ended in 'internal error: OverflowError'
    at its first wait."""
    r = gflow("replay", str(rec / "demo.mcap"), "--speed", "1e-308", cwd=tmp_path)
    one_line_error(r, "--speed", ">= 0.001", "1e-308", rc=2)
    assert "replaying" not in r.stderr


def test_a_whole_number_past_64_bits_is_read_as_one(tmp_path: Path) -> None:
    """``--keep 99999999999999999999999999`` said "invalid nonnegative_int value" (numpy's isfinite overflows on an
    int past 64 bits, and argparse reported the type); it is a whole number, read as such, and a negative one is
    refused by its rule."""
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "a.mcap").write_bytes(b"\x89MCAP0\r\n" + b"x" * 100)  # the beginning of a recording
    r = gflow("clean", "runs", "--keep", "9" * 26, "--dry-run", cwd=tmp_path)
    assert r.returncode == 0 and "would remove 0 recording(s)" in r.stdout and "kept the newest 1" in r.stdout, \
        (r.stdout, r.stderr)
    r = gflow("clean", "runs", "--keep", "-" + "9" * 26, cwd=tmp_path)
    assert r.returncode == 2 and "must be >= 0" in r.stderr and "invalid" not in r.stderr, r.stderr
