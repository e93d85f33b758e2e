"""`gflow eval --visibility` reads the same prediction files as plain `gflow eval`: a row of no box (NaN, or w or h
0) is a miss for the box metrics and its state column is still read; a really malformed row is still refused in one
line naming the file and the line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import cli_fork

ROOT = Path(__file__).resolve().parents[1]

GT = "frame,x,y,w,h\n0,10,10,20,20\n1,10,10,20,20\n2,10,10,20,20\n3,10,10,20,20\n"
# frame 1: no box (NaN), said tracked; frame 2: a box of no size, said lost
PRED = ("frame,x,y,w,h,confidence,state\n0,10,10,20,20,0.9,tracked\n1,nan,nan,nan,nan,0.0,tracked\n"
        "2,20,20,0,0,0.1,lost\n3,10,10,20,20,0.9,tracked\n")
VIS = "frame,visible\n0,1\n1,1\n2,1\n3,1\n"


def gflow(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args], cwd=cwd, env=env, capture_output=True,
                                text=True, timeout=120, stdin=subprocess.DEVNULL)


def one_line_error(r: subprocess.CompletedProcess, *words: str, rc: int = 2) -> None:
    assert r.returncode == rc, (r.returncode, r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert all(w in lines[0] for w in words), (words, lines[0])


def files(tmp_path: Path, pred: str = PRED) -> list[str]:
    for name, text in (("gt.csv", GT), ("pred.csv", pred), ("vis.csv", VIS)):
        (tmp_path / name).write_text(text)
    return ["--gt", "gt.csv", "--pred", "pred.csv", "--visibility", "vis.csv"]


def test_visibility_accepts_the_rows_of_no_box_plain_eval_scores(tmp_path: Path) -> None:
    """A NaN row refused the whole file with --visibility ("box has NaN") though plain eval scores it as a miss."""
    args = files(tmp_path)
    plain = gflow("eval", *args[:4], "--json", cwd=tmp_path)
    r = gflow("eval", *args, "--json", cwd=tmp_path)
    assert plain.returncode == 0 and r.returncode == 0, (plain.stderr, r.stderr)
    s, p = json.loads(r.stdout), json.loads(plain.stdout)
    assert {k: v for k, v in s.items() if k != "state"} == p  # the box metrics do not change with --visibility
    assert s["missing_predictions"] == 2 and s["empty_predictions"] == 2 and s["mean_overlap"] == 0.5, s
    st = s["state"]
    # both rows of no box are off the target; the NaN one's state (tracked) was read, and so was the empty one's (lost)
    assert st["undisturbed_frames"] == 4 and st["off_target_frames"] == 2, st
    assert st["off_target_reported_tracked"] == 0.5 and st["undisturbed_off_target_reported_occluded_or_lost"] == 0.5
    assert st["undisturbed_reported_tracked"] == 0.75, st
    r = gflow("eval", *args, cwd=tmp_path)
    assert r.returncode == 0 and "off the target, said tracked: 0.500" in r.stdout, (r.stdout, r.stderr)


@pytest.mark.parametrize("row, words", [
    ("1,nan,nan,nan,nan,0.0,gone", ["pred.csv:3", "unknown state 'gone'"]),
    ("1,nan,nan,nan,nan,2,lost", ["pred.csv:3", "confidence 2 is outside [0, 1]"]),
    ("1,nan,nan,nan,nan,x,lost", ["pred.csv:3", "confidence is not a number"]),
    ("1,nan,nan,nan,nan", ["pred.csv:3", "column"]),
    ("1,nan,nan,nan,inf,0.0,lost", ["pred.csv:3", "inf"]),
    ("1,a,b,c,d,0.0,lost", ["pred.csv:3", "not numbers"]),
    ("1,10,10,-5,20,0.0,lost", ["pred.csv:3", "negative width or height"]),
])
def test_visibility_still_refuses_a_malformed_row_by_file_and_line(tmp_path: Path, row: str, words: list) -> None:
    args = files(tmp_path, PRED.replace("1,nan,nan,nan,nan,0.0,tracked", row))
    one_line_error(gflow("eval", *args, cwd=tmp_path), *words)


def test_visibility_accepts_a_nan_confidence_on_a_row_of_no_box(tmp_path: Path) -> None:
    """A row of no box has no confidence to give: NaN there was refused ("confidence nan is outside [0, 1]") though
    the row is a miss whatever its confidence; its state is still read."""
    args = files(tmp_path, PRED.replace("1,nan,nan,nan,nan,0.0,tracked", "1,nan,nan,nan,nan,nan,tracked")
                 .replace("2,20,20,0,0,0.1,lost", "2,20,20,0,0,nan,lost"))
    r = gflow("eval", *args, "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)["state"]
    assert st["off_target_frames"] == 2 and st["off_target_reported_tracked"] == 0.5, st


def test_visibility_refuses_a_nan_confidence_on_a_row_with_a_box(tmp_path: Path) -> None:
    args = files(tmp_path, PRED.replace("3,10,10,20,20,0.9,tracked", "3,10,10,20,20,nan,tracked"))
    one_line_error(gflow("eval", *args, cwd=tmp_path), "pred.csv:5", "confidence nan", "column 6", "no box")
