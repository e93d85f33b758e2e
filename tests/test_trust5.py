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
    ("frame,x,y,w,h\n0,1,2,3,4\n1,1,2,3,4\n2,1,2,3,4,0.9,tracked\n", 4, "7 columns, but the rows before have 5"),
    ("0,1,2,3,4,0.5,tracked\n1,1,2,3,4\n", 2, "5 columns, but the rows before have 7 (frame,x,y,w,h,confidence,state)"),
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
    assert rc == 2 and f"gt.csv:3: 6 columns, but the rows before have 5" in one_line(err), err
