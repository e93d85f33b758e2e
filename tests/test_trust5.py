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
