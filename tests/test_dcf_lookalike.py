"""dcf with a look-alike beside the target (``lookalike_doubt``, :mod:`gflow_core.dcf.lookalike`): the unit
rule, and caviar1's stress case ``distract-40`` on the real frames, where a mirrored copy of the standing
woman walks across her and the default leaves with it."""

from __future__ import annotations

import json
import subprocess

import pytest

from gflow_core.dcf.lookalike import beside
from gflow_core.visibility import ChiSquare


def _dist(mean: float, std: float, n: int = 20) -> ChiSquare:
    d = ChiSquare()
    for k in range(n):  # samples at mean +- std: running moments of that mean and spread
        d = d.update(mean + (std if k % 2 else -std), 1.0 / (k + 1))
    return d


def test_a_runner_up_that_scores_as_the_target_is_a_look_alike():
    target, clutter = _dist(0.6, 0.05), _dist(0.85, 0.04)
    assert beside(target, clutter, (0.38, 100.0), 0.02)  # rho 0.62: the target's
    assert not beside(target, clutter, (0.14, 100.0), 0.02)  # rho 0.86: the clutter's
    assert not beside(target, clutter, None, 0.02)  # no place away from the estimate
    assert not beside(ChiSquare(), clutter, (0.38, 100.0), 0.02)  # nothing learnt of the target yet


def _distract(flag: str, tmp_path, gflow_cmd) -> dict:
    from tests.conftest import data_dir

    data = data_dir("caviar1").parent
    r = subprocess.run([*gflow_cmd, "benchmark", str(data), "--stress", "--sequences", "caviar1", "--cases",
                        "distract-40", "--trackers", "dcf", "--opencv", "none", "--inline", "-q", "--json", "--seed",
                        "1", "--stress-cache", str(tmp_path / "cache"), "--set", f"tracker.lookalike_doubt={flag}"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return next(x for x in json.loads(r.stdout)["rows"] if x["kind"] == "tracker")


def test_caviar1_standing_woman_is_kept_when_her_copy_walks_across(tmp_path, gflow_cmd):
    """Without the rule the estimate takes up the copy's pace when it covers her and leaves with it
    (reported tracked); with it the frames the copy is beside her are in doubt, the box holds, and she is
    tracked again after the window."""
    off, on = _distract("false", tmp_path, gflow_cmd), _distract("true", tmp_path, gflow_cmd)
    print({"off": (off["back"], off["after"]), "on": (on["back"], on["after"])})
    assert not off["back"], "the default kept her: the case no longer tests the rule"
    assert on["back"] and on["after"] >= 0.8
