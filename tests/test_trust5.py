"""Answers a user can trust (round 5): a command's errors all start with its own name, argparse's and
the command's alike; a boxes CSV whose rows have different numbers of columns is refused; a name
listed twice in a comma list is refused; a bad ``--set`` of ``gflow benchmark`` is said before any
note.

The runs are real (``main([...])`` in this process) on tiny files written into tmp folders.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import cli


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> Path:
    """Six 64x48 textured frames in a folder."""
    d = tmp_path_factory.mktemp("trust5") / "frames"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(6):
        cv2.imwrite(str(d / f"{i:04d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    return d


def one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("argv,prefix", [
    (["learn", "m2", "{d}/nonexist", "--out", "m.npz"], "gflow learn m2: error: training source not found"),
    (["learn", "m2", "{d}", "--out", "m.npz", "-K", "abc"], "gflow learn m2: error: argument -K"),
    (["learn", "gflow", "{d}/nonexist.npz", "--out", "m.npz"], "gflow learn gflow: error: landmark file not found"),
    (["learn", "gflow", "{d}", "--out", "m.npz", "-k", "abc"], "gflow learn gflow: error: argument -k"),
    (["export", "vot", "{d}/nonexist", "ws"], "gflow export vot: error: dataset folder not found"),
    (["export", "vot", "{d}"], "gflow export vot: error: the following arguments are required"),
])
def test_a_command_of_a_command_says_its_errors_under_its_own_name(frames: Path, tmp_path: Path, monkeypatch,
                                                                   capsys, argv: list[str], prefix: str) -> None:
    """``gflow learn m2`` said argparse's mistakes as ``gflow learn m2: error:`` and its own as ``gflow learn:
    error:`` (``gflow export vot`` alike): one command, two names. Every error now starts with the command's full
    name, as argparse's do."""
    monkeypatch.chdir(tmp_path)
    rc, err = cli([a.replace("{d}", str(frames)) for a in argv], capsys)
    assert rc == 2 and one_line(err).startswith(prefix), err


@pytest.mark.parametrize("text,line,words", [
    ("0,1,2,3,4\n1,1,2,3,4,0.5\n", 2, "6 columns, but the rows before have 5 (frame,x,y,w,h) (from line 1)"),
    ("frame,x,y,w,h\n0,1,2,3,4\n1,1,2,3,4\n2,1,2,3,4,0.9,tracked\n", 4,
     "7 columns, but the rows before have 5"),
    ("0,1,2,3,4,0.5,tracked\n1,1,2,3,4\n", 2,
     "5 columns, but the rows before have 7 (frame,x,y,w,h,confidence,state)"),
    ("0,1,2,3,4,\n1,1,2,3,4\n", 2, "5 columns, but the rows before have 6"),  # a trailing comma on the first row
])
def test_read_boxes_refuses_rows_of_different_widths(tmp_path: Path, text: str, line: int, words: str) -> None:
    """``read_boxes`` read a boxes CSV whose rows had different numbers of columns (a row run on, or cut
    short), each as it came; it now names the file and the first line that differs, as its other errors do."""
    from pipeline.recording.results import read_boxes

    p = tmp_path / "b.csv"
    p.write_text(text)
    with pytest.raises(ValueError) as e:
        read_boxes(p)
    assert str(e.value).startswith(f"{p}:{line}: {words}"), str(e.value)


@pytest.mark.parametrize("text", [
    "\ufeffframe,x,y,w,h\n0,1,2,3,4\n1,1,2,3,4\n",  # a byte-order mark
    "frame,x,y,w,h,confidence,state\n0,1,2,3,4,0.5,tracked\n1,1,2,3,4,0.5,lost\n",  # extra columns on every row
])
def test_read_boxes_still_reads_even_rows(tmp_path: Path, text: str) -> None:
    from pipeline.recording.results import read_boxes

    p = tmp_path / "b.csv"
    p.write_text(text, encoding="utf-8")
    assert read_boxes(p) == {0: (1.0, 2.0, 3.0, 4.0), 1: (1.0, 2.0, 3.0, 4.0)}


@pytest.mark.parametrize("sep", ["\t", ";"])
def test_read_boxes_still_refuses_other_separators(tmp_path: Path, sep: str) -> None:
    from pipeline.recording.results import read_boxes

    p = tmp_path / "b.csv"
    p.write_text(sep.join("01234") + "\n")
    with pytest.raises(ValueError, match="separated by tabs, semicolons or spaces"):
        read_boxes(p)


def test_eval_refuses_truth_of_mixed_widths_in_one_line(tmp_path: Path, capsys) -> None:
    """The same through ``gflow eval`` (which reads the truth with the same rows)."""
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n0,1,2,3,4\n1,1,2,3,4,9\n")
    (tmp_path / "p.csv").write_text("frame,x,y,w,h\n0,1,2,3,4\n1,1,2,3,4\n")
    rc, err = cli(["eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / "p.csv")], capsys)
    assert rc == 2 and "gt.csv:3: 6 columns, but the rows before have 5" in one_line(err), err


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """A folder of two sequence folders (a and b: frames/ of four 64x48 frames and groundtruth.csv)."""
    d = tmp_path_factory.mktemp("trust5-data") / "data"
    rng = np.random.default_rng(1)
    for name in ("a", "b"):
        (d / name / "frames").mkdir(parents=True)
        for i in range(4):
            cv2.imwrite(str(d / name / "frames" / f"{i:06d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
        (d / name / "groundtruth.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(4)))
    return d


@pytest.mark.parametrize("argv,said", [
    (["benchmark", "{d}", "--trackers", "dcf,dcf"], "--trackers 'dcf,dcf': dcf is named twice"),
    (["benchmark", "{d}", "--trackers", "dcf, m2,dcf"], "--trackers 'dcf, m2,dcf': dcf is named twice"),
    (["benchmark", "{d}", "--trackers", "dcf,,chamfer"], "--trackers 'dcf,,chamfer': an empty name between commas"),
    (["benchmark", "{d}", "--trackers", "dcf,"], "--trackers 'dcf,': an empty name between commas"),
    (["benchmark", "{d}", "--sequences", "a,a"], "--sequences 'a,a': a is named twice"),
    (["benchmark", "{d}", "--opencv", "csrt,kcf,csrt"], "--opencv 'csrt,kcf,csrt': csrt is named twice"),
    (["benchmark", "{d}", "--stress", "--cases", "look,look"], "--cases 'look,look': look is named twice"),
    (["benchmark", "{d}", "--stress", "--cases", "occlude,occlude-25"],
     "--cases 'occlude,occlude-25': occlude-25 is named twice (by occlude and by occlude-25)"),
    (["benchmark", "{d}", "--stress", "--cases", "roll,roll-camera"], "roll-camera-20 is named twice"),
    (["benchmark", "--list-cases", "--cases", "dark,dark-40"], "dark-40 is named twice"),
    (["benchmark", "{d}", "--stress", "--sequences", "b,b"], "--sequences 'b,b': b is named twice"),
    (["export", "vot", "{d}", "{t}/ws", "--sequences", "a,b,a"], "--sequences 'a,b,a': a is named twice"),
    (["export", "vot", "{d}/a", "{t}/ws", "--sequences", "a,a"], "--sequences 'a,a': a is named twice"),
])
def test_a_name_listed_twice_is_refused(data: Path, tmp_path: Path, monkeypatch, capsys, argv: list[str],
                                        said: str) -> None:
    """``--trackers dcf,dcf`` ran dcf once without a word (``--sequences``, ``--opencv``, ``--cases``, and
    export vot's ``--sequences`` alike), and ``dcf,,chamfer`` dropped the empty name: the user may have meant
    another name there. Refused in one line naming the repeat, before any work."""
    monkeypatch.chdir(tmp_path)
    rc, err = cli([a.replace("{d}", str(data)).replace("{t}", str(tmp_path)) for a in argv], capsys)
    assert rc == 2 and said in one_line(err), err
    assert not list(tmp_path.iterdir()), "nothing may be written before the options are checked"


def test_distinct_names_are_still_taken(data: Path, capsys) -> None:
    """Names given once each, with spaces after the commas, are read as before."""
    capsys.readouterr()
    from pipeline.cli.main import main

    assert main(["benchmark", "--list-cases", "--cases", "occlude, look"]) == 0
    listed = [ln.split()[0] for ln in capsys.readouterr().out.splitlines()]
    assert listed == ["occlude-10", "occlude-25", "occlude-60", "occlude-150", "look"], listed


def _missing_opencv() -> str:
    """An OpenCV tracker this OpenCV does not have (CSRT in OpenCV 5 without contrib), or skip."""
    from pipeline.evaluation.sequence_benchmark import OPENCV_TRACKERS, opencv_tracker

    missing = [c for c in OPENCV_TRACKERS if opencv_tracker(c)[0] is None]
    if not missing:
        pytest.skip("this OpenCV has every OpenCV tracker gflow knows, so none is noted missing")
    return missing[0]


@pytest.mark.parametrize("extra", [["--stress", "--cases", "none"], ["--variant", "blur"], ["--opencv", "{cv}"],
                                   ["--stress", "--cases", "none", "--opencv", "{cv}"], ["--out-dir", "od"]])
@pytest.mark.parametrize("setting,said", [
    ("tracker.nonexist=3", "--set tracker.nonexist=3: DCFParams has no parameter 'nonexist'"),
    ("nonsense", "--set expects stage.param=value, got 'nonsense'"),
])
def test_a_bad_set_is_said_before_any_note_or_work(data: Path, tmp_path: Path, monkeypatch, capsys,
                                                   extra: list[str], setting: str, said: str) -> None:
    """``gflow benchmark --stress --set BAD`` said ``benchmark: opencv csrt not measured: ...`` before the --set's
    error, and ``--variant blur --set BAD`` said ``writing the blur variant`` and wrote it first: every option is
    now checked before any note or work, and the error is the one line; nor is ``--out-dir`` touched (a refused
    benchmark left DIR/SEQUENCE folders behind)."""
    monkeypatch.chdir(tmp_path)
    cv = _missing_opencv() if "{cv}" in extra else ""
    rc, err = cli(["benchmark", str(data / "a"), "--trackers", "dcf", "--inline", "--set", setting,
                   *[a.replace("{cv}", cv) for a in extra]], capsys)
    assert rc == 2 and said in one_line(err), err
    assert not list(tmp_path.iterdir())


def _bench_m2_transfer():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "bench" / "bench_m2_transfer.py"
    spec = importlib.util.spec_from_file_location("bench_m2_transfer", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bench_m2_transfer_rounds_each_figure_once() -> None:
    """The script took the benchmark JSON's figures, already rounded to 4 decimals, and printed their mean
    rounded again: an AUC of 0.73649 with every seed was printed 0.737 (its JSON 0.7365, rounded up)."""
    res = np.array([[2.0, 0.73649, 0.5], [2.0, 0.73649, 0.6]])
    assert _bench_m2_transfer().figures(res) == ["2.00 / 2.00", "2.00", "0.736 / 0.736", "0.736", "0.500-0.600"]


def test_bench_m2_transfer_scores_the_boxes_unrounded(data: Path, tmp_path: Path) -> None:
    """The figures come from the run's boxes, scored as the benchmark scores them, not from its rounded JSON; a
    JSON that disagrees beyond its rounding (other frames scored) stops the script rather than print either."""
    from pipeline.evaluation.sequence_benchmark import Row, find_sequences, score_row

    bench = _bench_m2_transfer()
    boxes = tmp_path / "m2.csv"
    boxes.write_text("frame,x,y,w,h\n0,10,10,20,20\n1,11.3,10,20,20\n2,13.7,12.1,19,21\n3,17,9,23,20\n")
    (seq,), _ = find_sequences([str(data / "a")])
    want = score_row(Row("a", "m2", "tracker"), seq.truth(0, None), boxes)
    assert round(want.auc, 4) != want.auc  # a figure the JSON rounds
    row = {"boxes": str(boxes), "cle_px": round(want.score.cle, 3), "auc": round(want.auc, 4),
           "success_rate_0.5": round(want.score.success, 4)}
    assert bench.score(row, data / "a", [None, None]) == (want.score.cle, want.auc, want.score.success)
    with pytest.raises(SystemExit, match="auc"):
        bench.score(dict(row, auc=row["auc"] + 0.01), data / "a", [None, None])


@pytest.fixture(scope="module")
def stripes(tmp_path_factory) -> Path:
    """Six 320x240 frames of one fine, low-contrast texture: vertical stripes 2 px wide, grey levels 100 and 130.
    Canny at 50/150 finds no edge in it; at thresholds chosen from its own gradients it has edges at full
    resolution, and none once resampled by 1/2 (each 2x2 block of pixels averages a stripe pair away)."""
    d = tmp_path_factory.mktemp("stripes") / "frames"
    d.mkdir()
    x = np.mgrid[0:240, 0:320][1]
    for i in range(6):
        cv2.imwrite(str(d / f"{i:04d}.png"), (100 + (x // 2) % 2 * 30).astype(np.uint8))
    return d


def _coast_lines(capsys, argv: list[str]) -> list[str]:
    from pipeline.cli.main import main

    capsys.readouterr()
    assert main(argv) == 0
    out = capsys.readouterr()
    return [ln for ln in (out.out + out.err).splitlines() if "coasted" in ln]


@pytest.mark.parametrize("match", [True, False])
def test_edgeless_reads_the_edges_at_the_resolution_the_tracker_read_them(caviar1_m2_model: Path, stripes: Path,
                                                                        tmp_path: Path, capsys, match: bool) -> None:
    """With ``preprocess.match_resolution=true`` the tracker reads the edges of the frame resampled to the model's
    resolution (here by 1/2, the box twice the model's reference size). The report looked for edges at the frame's
    own resolution: on a fine texture the tracker sees as uniform it said "not blank, but has no edges at the
    model's Canny thresholds 50/150 ... set others", and with the thresholds it suggested (null: each frame's
    own) the tracker coasted on every frame again. It now looks where the tracker looked: a blank frame; and the
    report's answer agrees with what the tracker does once the advice is followed."""
    from pipeline.io.modelfile import load_model

    rw, rh = load_model(caviar1_m2_model).ref_size
    box = f"100,40,{2 * rw:g},{2 * rh:g}"  # twice the model's reference size: resampled by 1/2
    argv = ["track", str(stripes), "--tracker", "m2", "--model", str(caviar1_m2_model), "--init", box, "--inline",
            "--no-record"] + (["--set", "preprocess.match_resolution=true"] if match else [])
    lines = _coast_lines(capsys, argv + ["--out", str(tmp_path / "fixed.csv")])
    assert len(lines) == 1, lines
    said_blank = "a blank frame" in lines[0]
    assert said_blank == match and ("is not blank" in lines[0]) == (not match), lines
    # the advice followed (thresholds chosen from each frame's gradients): a blank frame coasts again, a frame
    # that was not blank has edges now
    again = _coast_lines(capsys, argv + ["--set", "preprocess.canny_low=null", "--set", "preprocess.canny_high=null",
                                         "--out", str(tmp_path / "own.csv")])
    assert bool(again) == said_blank, (lines, again)


@pytest.mark.parametrize("argv,said", [
    (["learn", "m2", "{d}", "{d}", "--metric", "l2", "-K", "2"], "source {d} is given twice; give each source once"),
    (["learn", "m2", "{d}", "{t}/link", "--metric", "l2", "-K", "2"], "source {t}/link is given twice (as {d} and as"),
    (["learn", "gflow", "{t}/lm", "{t}/lm/landmarks.npz"],
     "landmark source {t}/lm/landmarks.npz is given twice (as {t}/lm and as {t}/lm/landmarks.npz)"),
])
def test_a_training_source_given_twice_is_refused(frames: Path, tmp_path: Path, monkeypatch, capsys,
                                                  argv: list[str], said: str) -> None:
    """``gflow learn m2 A A`` learned from every frame of A twice, as two sequences, without a word (and
    ``learn gflow`` alike, also with a folder and its landmarks.npz): refused naming the source, nothing written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "link").symlink_to(frames)
    (tmp_path / "lm").mkdir()
    np.savez(tmp_path / "lm" / "landmarks.npz", landmarks=np.zeros((4, 468, 3), np.float32))
    fill = (lambda a: a.replace("{d}", str(frames)).replace("{t}", str(tmp_path)))
    rc, err = cli([fill(a) for a in argv] + ["--out", str(tmp_path / "m.npz"), "-q"], capsys)
    assert rc == 2 and fill(said) in one_line(err), err
    assert not (tmp_path / "m.npz").exists()


@pytest.fixture(scope="module")
def demo_mcap(tmp_path_factory) -> Path:
    """A closed recording of 10 frames of the synthetic scene (``gflow demo --inline``)."""
    from pipeline.cli.main import main

    out = tmp_path_factory.mktemp("trust5-demo") / "demo.mcap"
    assert main(["demo", "--frames", "10", "--inline", "--record", str(out)]) == 0
    return out


@pytest.mark.parametrize("value,said", [
    (",", "--lockstep ',' names no stage"),
    ("filter,filter", "--lockstep 'filter,filter': filter is named twice"),
    ("filter,,proposal", "--lockstep 'filter,,proposal': an empty name between commas"),
])
def test_replay_lockstep_names_are_checked_before_replaying(demo_mcap: Path, capsys, value: str, said: str) -> None:
    """``gflow replay --lockstep ,`` replayed with no lockstep without a word, and ``filter,filter`` waited 10 s
    for heartbeats and then said "no heartbeat from filter, filter": refused at once, before any message is sent."""
    rc, err = cli(["replay", str(demo_mcap), "--max", f"--lockstep={value}"], capsys)
    assert rc == 2 and said in one_line(err), err


@pytest.mark.parametrize("extra", [[], ["--stress"]])
def test_a_model_for_a_tracker_not_run_is_refused(data: Path, tmp_path: Path, monkeypatch, capsys,
                                                  extra: list[str]) -> None:
    """``gflow benchmark --trackers dcf --m2-model M`` ran dcf alone, the model neither read nor used (here not even
    a model: a CSV), and nothing said so; refused naming the option, before any work."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n0,1,2,3,4\n")
    rc, err = cli(["benchmark", str(data), "--trackers", "dcf", "--m2-model", str(tmp_path / "gt.csv"), "--inline",
                   *extra], capsys)
    assert rc == 2 and "--m2-model gives --tracker m2 its model, but --trackers dcf does not run m2" in one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gt.csv"]


def test_eval_says_no_centre_error_rather_than_nan(tmp_path: Path, capsys) -> None:
    """A tracker with no box on any frame of truth scores overlap 0 (its JSON's cle_px is null), but the text said
    ``centre location error (CLE): nan px``; it now says there is none, and why."""
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n0,10,10,20,20\n1,10,10,20,20\n")
    (tmp_path / "p.csv").write_text("frame,x,y,w,h\n0,nan,nan,nan,nan\n1,1,1,0,0\n")
    from pipeline.cli.main import main

    capsys.readouterr()
    assert main(["eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / "p.csv")]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out.lower() and "CLE): none (no frame with ground truth has a predicted box)" in out, out


def test_learn_gflow_refuses_landmarks_of_another_layout(tmp_path: Path, capsys) -> None:
    """Ten landmarks a frame (not MediaPipe Face Mesh's 468) were learned from until the learning failed (exit 1)
    with "frontal landmarks (33, 263, 61, 291) must lie in [0, 10)"; a mistake in the input, said before learning."""
    rng = np.random.default_rng(0)
    np.savez(tmp_path / "lm.npz", landmarks=(rng.normal(size=(20, 10, 3)) * 50 + 200).astype(np.float32))
    rc, err = cli(["learn", "gflow", str(tmp_path / "lm.npz"), "--out", str(tmp_path / "m.npz"), "-q"], capsys)
    assert rc == 2 and f"{tmp_path / 'lm.npz'}: 10 landmarks a frame" in one_line(err), err
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("typ,fields,said", [
    ("Control", '{"comand": "stop"}', "FIELDS: Control has no field 'comand' (its fields: header, command)"),
    ("Control", '{"command": "stop", "header": {"sq": 3}}', "FIELDS: Control's header has no field 'sq'"),
    ("Control", '{"command": "halt"}', "FIELDS: no stage acts on Control command 'halt' (known: start, stop)"),
    ("Estimate", '{"box": [1, 2, 3, 4], "boxx": 1}', "FIELDS: Estimate has no field 'boxx'"),
])
def test_pub_refuses_a_field_the_message_does_not_have(tmp_path: Path, capsys, typ: str, fields: str,
                                                       said: str) -> None:
    """``gflow pub ... Control '{"command": "stop", "header": {"sq": 3}}'`` sent the message without the field
    mistyped (msgspec drops what it does not know), and ``{"command": "halt"}`` went to stages that log it and
    ignore it; refused before any session opens."""
    rc, err = cli(["pub", "gflow/cam0/_control" if typ == "Control" else "gflow/cam0/estimate", typ, fields,
                   "--wait", "0.2"], capsys)
    assert rc == 2 and said in one_line(err), err


@pytest.mark.parametrize("text,said", [
    ("frame,visible\n0,1\n1,0.5,1\n", "v.csv:3: 3 columns, but the rows before have 2 (frame,visible) (from line 2)"),
    ("frame,visible,perturbed\n0,1,1\n1,0.5\n",
     "v.csv:3: 2 columns, but the rows before have 3 (frame,visible,perturbed) (from line 2)"),
    ("frame,visible,perturbed\n0,1,0\n1,0.5,2\n", "v.csv:3: perturbed 2 is not 0 or 1 (column 3)"),
])
def test_a_visibility_file_of_uneven_rows_is_refused_by_line(tmp_path: Path, capsys, text: str, said: str) -> None:
    """A visibility file with the perturbed column on some rows only was refused as "the perturbed column is missing
    on some rows", naming no line, and a perturbed value of 2 was read as perturbed; both name the line now, as a
    boxes file's errors do."""
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n0,10,10,20,20\n1,10,10,20,20\n")
    (tmp_path / "p.csv").write_text("frame,x,y,w,h,confidence,state\n0,10,10,20,20,0.9,tracked\n"
                                    "1,10,10,20,20,0.9,tracked\n")
    (tmp_path / "v.csv").write_text(text)
    rc, err = cli(["eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / "p.csv"), "--visibility",
                   str(tmp_path / "v.csv")], capsys)
    assert rc == 2 and said in one_line(err), err


def test_a_points_file_of_uneven_rows_is_refused_by_line(tmp_path: Path) -> None:
    """A points file (frame,landmark,x,y) took a row run on (``0,61,5,6,7``: its last value dropped) as it came."""
    from pipeline.io.landmarks import read_points

    p = tmp_path / "pts.csv"
    p.write_text("frame,landmark,x,y\n0,33,1,2\n0,61,5,6,7\n")
    with pytest.raises(ValueError, match=r"pts.csv:3: 5 columns, but the rows before have 4 \(frame,landmark,x,y\) "
                                         r"\(from line 2\)"):
        read_points(p)


def test_step_refuses_a_recording_without_the_stage_inputs(tmp_path: Path, monkeypatch, capsys) -> None:
    """``gflow step`` of a recording made with ``--record-topics estimate,features`` (no proposals) said
    "stepping filter ... N input messages", and every step joined nothing: "end of the recording", exit 0. Refused
    naming the topics missing, as ``gflow rerun`` refuses it."""
    import io

    from pipeline.cli.main import main

    rec = tmp_path / "part.mcap"
    assert main(["demo", "--frames", "5", "--inline", "--record", str(rec), "--record-topics", "estimate,features"]) == 0
    monkeypatch.setattr("sys.stdin", io.StringIO("n\nn\nq\n"))
    rc, err = cli(["step", str(rec), "--stage", "filter"], capsys)
    assert rc == 2 and "cannot step stage filter: gflow/demo/proposals: it is not in" in \
        one_line(err), err
    assert "--record-topics estimate,features" in err


@pytest.mark.parametrize("option,value,said", [
    ("--reps", "1,1", "--reps '1,1': 1 is named twice"),
    ("--reps", "1,x", "--reps '1,x': 'x' is not a repetition number"),
    ("--reps", "1,,2", "--reps '1,,2': an empty name between commas"),
    ("--letters", "A-C,B", "--letters 'A-C,B': B is named twice"),
    ("--letters", "A,A", "A is named twice"),
    ("--letters", "Z-A", "--letters 'Z-A': Z-A runs backwards; write A-Z"),
])
def test_learn_m2_refuses_repeated_or_malformed_utterance_lists(frames: Path, tmp_path: Path, capsys, option: str,
                                                                value: str, said: str) -> None:
    """``--reps 1,1`` and ``--letters A-C,B`` learned each utterance once without a word, ``--reps 1,x`` said
    Python's "invalid literal for int() with base 10: 'x'", and ``--letters Z-A`` "no utterance with ... letters
    Z-A"; each is refused naming the option, before any source is read."""
    rc, err = cli(["learn", "m2", str(frames), "--metric", "shuffle", "-K", "2", "--out", str(tmp_path / "m.npz"),
                   "-q", f"{option}={value}"], capsys)
    assert rc == 2 and said in one_line(err), err
