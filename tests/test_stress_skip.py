"""`gflow benchmark --stress`: a ``distract`` case that cannot be made on a sequence (nothing of the target in the
image at the window's start, so no look of it to copy) is skipped, said in one line on stderr naming the sequence
and the case, and counted in the tables and the JSON; the other cases and sequences run. It stopped the whole run
(exit 1, "the target's box ... is not in the ... image")."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import synthetic_sequence
import cli_fork

FRAMES = 60
STRESS = ["--stress", "--cases", "none,distract", "--lead", "8", "--tail", "20", "--trackers", "appearance",
          "--inline", "-q"]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """``synth``, and ``odd``, whose target is in the image on its first frames only (leaves it at frame 5)."""
    root = tmp_path_factory.mktemp("stressskip")
    synthetic_sequence(root / "synth", 3, FRAMES)
    synthetic_sequence(root / "odd", 5, FRAMES, move=lambda t, b: (b[0] + (5000 if t >= 5 else 0), *b[1:]))
    return root


def _gflow(*args: str) -> subprocess.CompletedProcess:
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args], capture_output=True, text=True,
                                timeout=240, stdin=subprocess.DEVNULL)


def test_a_distract_case_that_cannot_be_made_is_skipped_not_the_end_of_the_run(data: Path, tmp_path: Path) -> None:
    r = _gflow("benchmark", str(data), *STRESS, "--json", "--out-dir", str(tmp_path / "runs"))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    said = [ln for ln in r.stderr.splitlines() if "skipped" in ln]
    assert len(said) == 1 and "odd / distract-40: skipped:" in said[0] and "not in the 320x240 image" in said[0], said
    res = json.loads(r.stdout)
    odd = [x for x in res["rows"] if x["sequence"] == "odd" and x["case"] == "distract-40"]
    assert {x["tracker"] for x in odd} >= {"appearance", "still box"}, odd
    assert all(x["case_skipped"] and x["note"].startswith("skipped: ") and x["success"] is None for x in odd), odd
    synth = [x for x in res["rows"] if x["sequence"] == "synth" and x["case"] == "distract-40"]
    assert synth and all(x["success"] is not None and "case_skipped" not in x for x in synth), synth
    s = res["summary"]["appearance"]
    assert s["skipped_cases"] == ["odd/distract-40"] and s["back"]["every case"][1] == 1, s
    assert s["families"]["distract"]["back"][1] == 1  # the case run on synth only


def test_the_tables_say_which_case_was_skipped(data: Path, tmp_path: Path) -> None:
    r = _gflow("benchmark", str(data), *STRESS, "--opencv", "none", "--stress-cache", str(tmp_path / "cache"))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "- skipped, the case could not be made on the sequence (not in the counts above): 1 case(s): " \
           "odd/distract-40" in r.stdout, r.stdout
    row = next(ln for ln in r.stdout.splitlines() if ln.startswith("odd ") and "distract-40" in ln)
    assert "skipped: on frame 8, the window's start, the target's box" in row, row
    assert any(ln.startswith("cases skipped (could not be made)") and ln.split()[-1] == "1"
               for ln in r.stdout.splitlines()), r.stdout
