"""``gflow benchmark --variant none,grey,...``: several kinds of footage in one run, each reported as its own run
would be, and a summary of where each tracker is behind; the real CLI on ../shared/data/crossing and made-up rows."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gflow_core.evaluation.metrics import TrackScore
from gflow_core.synthetic import SyntheticScene
from gflow_core.evaluation.variants import SUITE, VARIANTS
from pipeline.evaluation.kinds_summary import behind, format_kinds_summary, kinds_json
from pipeline.evaluation.sequence_benchmark import PRECISION_THRESHOLDS, Row
from pipeline.io.datasets import write_frames
from pipeline.recording.results import write_boxes

import cli_fork
from conftest import data_dir, interrupt_after

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


def _bench(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return cli_fork.run_command([*GFLOW, "benchmark", *args], capture_output=True, text=True, timeout=timeout)


def _row(seq: str, tracker: str, kind: str, auc: float | None) -> Row:
    """A scored row whose success curve is flat at ``auc`` (so its AUC is ``auc``); None: a run not scored."""
    if auc is None:
        return Row(seq, tracker, kind, note="failed")
    return Row(seq, tracker, kind, score=TrackScore(frames=10, cle=1.0, mean_overlap=auc, success=auc, missing=0),
               curve=np.full(21, auc), precision=np.ones(len(PRECISION_THRESHOLDS)))


def test_behind_names_the_comparison_a_tracker_is_below():
    rows = [_row("a", "dcf", "tracker", 0.70), _row("a", "opencv csrt", "opencv", 0.77),
            _row("a", "opencv kcf", "opencv", 0.60), _row("a", "static box", "baseline", 0.30),
            _row("b", "dcf", "tracker", 0.40), _row("b", "opencv csrt", "opencv", 0.30),
            _row("b", "static box", "baseline", 0.40),
            _row("c", "dcf", "tracker", 0.90), _row("c", "opencv csrt", "opencv", 0.80),
            _row("c", "static box", "baseline", 0.20),
            _row("d", "dcf", "tracker", None), _row("d", "static box", "baseline", 0.20)]
    got = behind(rows, "dcf")
    assert [(seq, what) for seq, _, what, _ in got] == [("a", "CSRT"), ("b", "still box"), ("d", "not scored")]
    assert got[0][1] == pytest.approx(0.70) and got[0][3] == pytest.approx(0.77) and got[2][1] is None
    # an OpenCV tracker this OpenCV lacks (never scored) is no comparison
    assert behind([_row("a", "dcf", "tracker", 0.5), _row("a", "opencv csrt", "opencv", None),
                   _row("a", "static box", "baseline", 0.1)], "dcf") == []


def test_summary_sums_every_kind_and_seed():
    def run(auc_a: float, auc_b: float) -> list[Row]:
        return [_row("a", "dcf", "tracker", auc_a), _row("a", "static box", "baseline", 0.5),
                _row("b", "dcf", "tracker", auc_b), _row("b", "static box", "baseline", 0.5)]

    kinds = [("none", [run(0.8, 0.6), run(0.8, 0.4)]), ("fast", [run(0.5, 0.7), run(0.6, 0.6)])]
    js = kinds_json(kinds, [1, 2])["dcf"]
    assert [k["kind"] for k in js] == ["none", "fast"]
    assert js[0]["auc_per_seed"] == [0.7, 0.6] and js[0]["auc"] == 0.65
    assert [(b["sequence"], b["seed"], b["behind"]) for b in js[0]["behind"]] == [("b", 2, "still box")]
    assert [(b["sequence"], b["seed"]) for b in js[1]["behind"]] == [("a", 1)]
    text = format_kinds_summary(kinds, [1, 2], markdown=True)
    assert "| as they are | 0.650 | 0.700 | 0.600 | 1 of 4 | b seed 2 (0.400; still box 0.500) |" in text
    assert "| every kind (2) | 0.625 |  |  | 2 of 8 |  |" in text
    assert "behind: at or below the box that never moves (no OpenCV tracker ran" in text


def test_all_is_every_variant_and_the_sequences_as_they_are():
    assert SUITE[0] == "none" and set(VARIANTS) <= set(SUITE) and "fast+blur" in SUITE


@pytest.mark.parametrize("variant, says", [
    ("none,gray", "unknown variant 'gray' in --variant"),
    ("grey,none,grey", "--variant grey,none,grey: a kind of footage is named twice"),
])
def test_a_mistyped_or_repeated_kind_is_a_one_line_error(variant, says):
    r = _bench("no/such/folder", "--variant", variant, timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], r.stderr


def test_a_plot_of_several_kinds_is_refused_before_any_work(tmp_path):
    crossing = data_dir("crossing")
    r = _bench(str(crossing), "--variant", "none,grey", "--trackers", "dcf", "--opencv", "none", "--inline",
               "--plot", str(tmp_path / "s.png"), timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["gflow benchmark: error: --plot and --precision-plot draw one kind of "
                                             "footage: give one --variant"]
    assert not (tmp_path / "s.png").exists()


def test_several_kinds_run_as_their_own_runs_and_are_summed_up(tmp_path):
    """Each kind of a run of several gives the AUC a run of that kind alone gives; the summary's means and cells
    behind are those of the kinds' own rows; the boxes are kept under DIR/KIND and never written over."""
    crossing = data_dir("crossing")
    common = ["--trackers", "dcf", "--opencv", "none", "--frames", "0:12", "--inline", "--json", "--no-fps", "-q"]
    out = tmp_path / "runs"
    r = _bench(str(crossing), "--variant", "none,grey,fast", "--seeds", "1,2", "--out-dir", str(out), *common)
    assert r.returncode == 0, r.stderr
    js = json.loads(r.stdout)
    assert [k["kind"] for k in js["kinds"]] == ["none", "grey", "fast"]
    for kind in ("none", "grey", "fast"):
        assert (out / kind / "seed-2" / "crossing" / "dcf.csv").is_file()
    # the grey kind, seed 2, as a run of its own: the same AUC
    alone = _bench(str(crossing), "--variant", "grey", "--seed", "2", *common)
    assert alone.returncode == 0, alone.stderr
    one = {(q["sequence"], q["tracker"]): q for q in json.loads(alone.stdout)["rows"]}
    grey = js["kinds"][1]
    seed2 = {(q["sequence"], q["tracker"]): q for q in grey["runs"][1]["rows"]}
    assert seed2["crossing", "dcf"]["auc"] == one["crossing", "dcf"]["auc"]
    # the summary, recomputed from the kinds' rows
    summary = js["summary"]["dcf"]
    for k, s in zip(js["kinds"], summary):
        per_seed = [{q["tracker"]: q["auc"] for q in run["rows"] if q["sequence"] == "crossing"} for run in k["runs"]]
        assert s["auc_per_seed"] == pytest.approx([p["dcf"] for p in per_seed], abs=1e-4)
        assert [b["seed"] for b in s["behind"]] == [seed for seed, p in zip((1, 2), per_seed)
                                                    if p["dcf"] <= p["static box"]]
    # the same folder again: refused before any work, nothing written over
    before = (out / "fast" / "seed-1" / "crossing" / "dcf.csv").read_bytes()
    again = _bench(str(crossing), "--variant", "none,grey,fast", "--seeds", "1,2", "--out-dir", str(out), *common)
    assert again.returncode == 2 and "exists (an earlier run's)" in again.stderr
    assert (out / "fast" / "seed-1" / "crossing" / "dcf.csv").read_bytes() == before


def test_several_kinds_print_each_kinds_tables_then_the_summary():
    crossing = data_dir("crossing")
    r = _bench(str(crossing), "--variant", "none,small", "--trackers", "dcf", "--opencv", "none", "--frames", "0:8",
               "--inline", "--markdown", "--no-fps", "-q")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    heads = [out.index("## the sequences as they are"), out.index("## the small variant of every sequence"),
             out.index("## every kind of footage")]
    assert heads == sorted(heads)
    assert out.count("**dcf** (") >= 3  # each kind's table, then the summary's
    assert "| every kind (2) |" in out
    assert "footage: the small variant of every sequence" in r.stderr


def test_a_kind_interrupted_midway_is_left_out_of_the_summary(tmp_path):
    """SIGINT during the second kind: exit 130; the first kind whole, the second marked interrupted, the summary
    over the first alone."""
    seq = tmp_path / "synth"
    scene = SyntheticScene(n_frames=30, seed=3, period=60)
    write_frames(seq / "frames", [scene.render(t) for t in range(30)])
    write_boxes(seq / "groundtruth.csv", {t: scene.truth_box(t) for t in range(30)})
    # frames paced at 10 fps, so the second kind's run is still going when the signal comes
    rc, out, seen = interrupt_after([*GFLOW, "benchmark", str(seq), "--variant", "none,grey", "--trackers", "chamfer",
                                     "--opencv", "none", "--json", "--set", "source.realtime=true", "--set",
                                     "source.fps=10"], "footage: the grey variant")
    assert rc == 130, "".join(seen)
    res = json.loads(out)
    assert [k["kind"] for k in res["kinds"]] == ["none", "grey"]
    assert [k["interrupted"] for k in res["kinds"]] == [False, True]
    first = {q["tracker"]: q for q in res["kinds"][0]["rows"]}
    assert first["chamfer"]["frames"] == 30  # the first kind's run, whole
    assert [k["kind"] for k in res["summary"]["chamfer"]] == ["none"]
