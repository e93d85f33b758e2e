"""`gflow eval` and `gflow plot --gt` score boxes of no size as OTB does: a ground-truth row with w or h 0 (or NaN)
marks the target absent and is left out; a predicted one is a failure (overlap 0, a miss); a negative width or
height in either file is damage, refused naming the file and line before any scoring."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

import cli_fork
ROOT = Path(__file__).resolve().parents[1]

GT = "frame,x,y,w,h\n0,10,10,20,20\n1,10,10,20,20\n2,10,10,20,20\n3,10,10,20,20\n"


def gflow(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``gflow ARGS`` in a process of its own, forked from one that has imported the command line (:mod:`cli_fork`)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return cli_fork.run(list(args), cwd=cwd, env=env, timeout=120)


def one_line_error(r: subprocess.CompletedProcess, *words: str, rc: int) -> None:
    assert r.returncode == rc, (r.returncode, r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert all(w in lines[0] for w in words), (words, lines[0])


def write(tmp_path: Path, name: str, text: str) -> str:
    (tmp_path / name).write_text(text)
    return name


def test_ground_truth_of_no_size_marks_the_target_absent_and_is_left_out(tmp_path: Path) -> None:
    """A row of 0 width or height, or NaN, was scored as a box: overlap 0 on a frame the target is not in
    (a NaN row refused the whole file)."""
    gt = write(tmp_path, "gt.csv", GT.replace("1,10,10,20,20", "1,10,10,0,20").replace("2,10,10,20,20", "2,nan,nan,nan,nan"))
    pred = write(tmp_path, "pred.csv", GT)
    r = gflow("eval", "--gt", gt, "--pred", pred, "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["frames"] == 2 and s["absent_frames"] == 2 and s["mean_overlap"] == 1.0 and s["success_rate_0.5"] == 1.0
    r = gflow("eval", "--gt", gt, "--pred", pred, cwd=tmp_path)
    assert r.returncode == 0 and "frames left out, the target absent: 2" in r.stdout, (r.stdout, r.stderr)


def test_prediction_of_no_size_is_a_failure_not_a_hit(tmp_path: Path) -> None:
    """A box of 0 size at the true centre (20, 20) counted as a centre error of 0 px; a NaN row refused the file."""
    gt = write(tmp_path, "gt.csv", GT)
    pred = write(tmp_path, "pred.csv", GT.replace("1,10,10,20,20", "1,20,20,0,0").replace("2,10,10,20,20", "2,nan,0,0,0"))
    r = gflow("eval", "--gt", gt, "--pred", pred, "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["frames"] == 4 and s["missing_predictions"] == 2 and s["empty_predictions"] == 2, s
    assert s["mean_overlap"] == 0.5 and s["success_rate_0.5"] == 0.5 and s["absent_frames"] == 0, s
    r = gflow("eval", "--gt", gt, "--pred", pred, cwd=tmp_path)
    assert "(missing predictions: 2, 2 of them a box of no size)" in r.stdout, r.stdout


def test_a_tracker_with_no_box_on_any_frame_scores_zero(tmp_path: Path) -> None:
    gt = write(tmp_path, "gt.csv", GT)
    pred = write(tmp_path, "pred.csv", "frame,x,y,w,h\n0,1,1,0,0\n1,1,1,0,0\n2,1,1,0,0\n3,1,1,0,0\n")
    r = gflow("eval", "--gt", gt, "--pred", pred, "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["cle_px"] is None and s["mean_overlap"] == 0.0 and s["success_rate_0.5"] == 0.0 and s["missing_predictions"] == 4


def test_ground_truth_absent_on_every_frame_is_nothing_to_score(tmp_path: Path) -> None:
    gt = write(tmp_path, "gt.csv", "frame,x,y,w,h\n0,0,0,0,0\n1,0,0,0,0\n")
    r = gflow("eval", "--gt", gt, "--pred", write(tmp_path, "pred.csv", GT), cwd=tmp_path)
    one_line_error(r, "gt.csv", "absent", "every ground-truth frame", rc=2)


@pytest.mark.parametrize("which", ["gt", "pred"])
def test_negative_width_or_height_is_damage_named_by_line(tmp_path: Path, which: str) -> None:
    """A box reaching back from its corner was scored: its centre on the other side of the corner (a box
    30,30,-20,-20 had the true centre 20,20, a centre error of 0 px)."""
    bad = write(tmp_path, "bad.csv", GT.replace("2,10,10,20,20", "2,30,30,-20,-20"))
    good = write(tmp_path, "good.csv", GT)
    args = ["--gt", bad, "--pred", good] if which == "gt" else ["--gt", good, "--pred", bad]
    r = gflow("eval", *args, cwd=tmp_path)
    one_line_error(r, "bad.csv:4", "negative width or height", rc=2)
    assert r.stdout == ""


@pytest.fixture
def demo(demo8: Path) -> Path:
    return demo8


def test_plot_refuses_ground_truth_with_a_negative_size(demo: Path, tmp_path: Path) -> None:
    gt = write(tmp_path, "gt.csv", "".join(f"{f},150,115,{-30 if f == 5 else 30},30\n" for f in range(8)))
    r = gflow("plot", str(demo), "p.png", "--gt", gt, cwd=tmp_path)
    one_line_error(r, "gt.csv:6", "negative width or height", rc=2)
    assert not (tmp_path / "p.png").exists()


def test_plot_leaves_out_frames_with_the_target_absent(demo: Path, tmp_path: Path) -> None:
    """Rows of no size, even on every frame of the run, are the target absent: a plot, not a refusal."""
    for rows in (lambda f: 0 if f < 3 else 30, lambda f: 0):
        gt = write(tmp_path, "gt.csv", "".join(f"{f},150,115,{rows(f)},30\n" for f in range(8)))
        r = gflow("plot", str(demo), "p.png", "--gt", gt, cwd=tmp_path)
        assert r.returncode == 0 and (tmp_path / "p.png").is_file(), r.stderr
        (tmp_path / "p.png").unlink()


def test_benchmark_scores_boxes_of_no_size_as_eval_does(tmp_path: Path) -> None:
    """`gflow benchmark` read a dataset's truth and a published tracker's boxes as boxes whatever their size: a
    frame the target is absent on was scored (overlap 0), and a published failure written 0,0,0,0 counted in the
    centre error as a box at the corner. It now reads them as `gflow eval` does, and its rows equal eval's."""
    from gflow_core.synthetic import SyntheticScene
    from pipeline.io.datasets import write_frames
    from pipeline.recording.results import write_boxes

    root = tmp_path / "synth"
    scene = SyntheticScene(n_frames=12, seed=3, period=60)
    write_frames(root / "frames", [scene.render(t) for t in range(12)])
    truth = {t: scene.truth_box(t) for t in range(12)}
    write_boxes(root / "groundtruth.csv", {**truth, 5: (0.0, 0.0, 0.0, 0.0)})  # the target absent on frame 5
    write_boxes(root / "results" / "other.csv", {**truth, 3: (0.0, 0.0, 0.0, 0.0)})  # a failure on frame 3
    r = gflow("benchmark", str(root), "--trackers", "chamfer", "--opencv", "none", "--inline", "--json", "-q",
              "--out-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    rows = {x["tracker"]: x for x in json.loads(r.stdout)["rows"]}
    other = rows["other"]
    assert other["frames"] == 11 and other["missing_predictions"] == 1 and other["cle_px"] == 0.0, other
    for name in ("other", "chamfer", "static box"):
        ev = json.loads(gflow("eval", "--gt", str(root / "groundtruth.csv"), "--pred", rows[name]["boxes"], "--json",
                              cwd=tmp_path).stdout)
        assert ev.pop("absent_frames") == 1 and ev.pop("empty_predictions") == (name == "other")
        ev.pop("auc_size_right"), ev.pop("auc_place_right")  # eval's own split of the AUC, not in a benchmark's row
        assert {k: rows[name][k] for k in ev} == ev, name


def test_eval_says_whether_the_place_or_the_size_costs_the_overlap(tmp_path: Path) -> None:
    """Boxes on the true centres at 1.5 times the true size: the AUC with the true size at each centre is the truth's
    own (20 / 21: no overlap is above the last threshold, 1), with
    each box's size at the true centre it is the AUC itself; the text and --json say the same."""
    gt = write(tmp_path, "gt.csv", GT)
    pred = write(tmp_path, "pred.csv", "frame,x,y,w,h\n" + "".join(f"{t},5,5,30,30\n" for t in range(4)))
    r = gflow("eval", "--gt", gt, "--pred", pred, "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["auc_size_right"] == round(20 / 21, 4) and out["auc_place_right"] == out["auc"] < 0.9, out
    text = gflow("eval", "--gt", gt, "--pred", pred, cwd=tmp_path).stdout
    assert f"success-plot AUC:            {out['auc']:.3f} (with the true size at each centre 0.952; with the true " \
           f"centre, each box's size {out['auc']:.3f})" in text, text
