"""``gflow benchmark --seeds``: the real CLI run once per seed on a short synthetic sequence folder, each
seed's rows equal to a run with ``--seed`` alone, and the means over the seeds."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gflow_core.evaluation.metrics import TrackScore
from gflow_core.synthetic import SyntheticScene
from pipeline.cli.main import main
from pipeline.evaluation.seed_means import format_seed_tables, mean_rows, parse_seeds
from pipeline.evaluation.stress_seeds import format_stress_seeds
from pipeline.evaluation.sequence_benchmark import Row
from pipeline.io.datasets import write_frames
from pipeline.recording.results import write_boxes

from conftest import interrupt_after
import cli_fork

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]
FRAMES = 30
#: chamfer draws its particles from the seed: the seeds' boxes differ
RUN = ["--trackers", "chamfer", "--inline", "--opencv", "none", "-q", "--json"]


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    """A sequence folder: 30 synthetic frames and their ground truth."""
    root = tmp_path_factory.mktemp("seeds") / "synth"
    scene = SyntheticScene(n_frames=FRAMES, seed=3, period=60)
    write_frames(root / "frames", [scene.render(t) for t in range(FRAMES)])
    write_boxes(root / "groundtruth.csv", {t: scene.truth_box(t) for t in range(FRAMES)})
    return root


def _bench(*args: str) -> dict:
    r = cli_fork.run_command([*GFLOW, "benchmark", *args], capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return json.loads(r.stdout)


def _row(res: dict, tracker: str) -> dict:
    (row,) = [r for r in res["rows"] if r["tracker"] == tracker]
    return row


def test_each_seed_is_the_run_of_that_seed_and_the_mean_is_theirs(seq, tmp_path):
    both = _bench(str(seq), *RUN, "--seeds", "2,5", "--out-dir", str(tmp_path / "runs"))
    assert both["seeds"] == [2, 5] and "seed" not in both
    assert [r["seed"] for r in both["runs"]] == [2, 5]
    for run, seed in zip(both["runs"], (2, 5)):
        alone = _bench(str(seq), *RUN, "--seed", str(seed))
        for name in ("chamfer", "static box"):
            mine, theirs = _row(run, name), _row(alone, name)
            assert mine["success_curve"] == theirs["success_curve"], (name, seed)
            assert mine["cle_px"] == theirs["cle_px"], (name, seed)
        # each seed's boxes kept apart under --out-dir
        assert Path(_row(run, "chamfer")["boxes"]) == tmp_path / "runs" / f"seed-{seed}" / "synth" / "chamfer.csv"
    aucs = [_row(r, "chamfer")["auc"] for r in both["runs"]]
    mean = _row(both["mean"], "chamfer")
    assert mean["auc"] == pytest.approx(np.mean(aucs), abs=2e-4)
    assert mean["cle_px"] == pytest.approx(np.mean([_row(r, "chamfer")["cle_px"] for r in both["runs"]]), abs=2e-3)
    assert both["mean"]["means"]["chamfer"]["auc"] == pytest.approx(mean["auc"], abs=1e-4)


def test_the_text_shows_every_seed_then_the_means(seq):
    r = cli_fork.run_command([*GFLOW, "benchmark", str(seq), *RUN[:-1], "--seeds", "1-3", "--markdown", "--no-fps"],
                             capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "**chamfer** (AUC with each seed: 1, 2, 3)"
    assert lines[2] == "| sequence | seed 1 | seed 2 | seed 3 | mean | lowest | highest |"
    cells = lines[4].split(" | ")
    assert cells[0] == "| synth"
    a = [float(c) for c in cells[1:4]]
    assert float(cells[4]) == pytest.approx(np.mean(a), abs=1e-3)
    assert float(cells[5]) == min(a) and float(cells[6].rstrip(" |")) == max(a)
    assert any(ln.startswith("**chamfer** (tracker") for ln in lines)  # the usual tables, of the means
    assert "seeds 1, 2, 3" in lines[-1]


def test_parse_seeds():
    assert parse_seeds("1,2,3") == [1, 2, 3]
    assert parse_seeds("1-5") == [1, 2, 3, 4, 5]
    assert parse_seeds("0, 4-6") == [0, 4, 5, 6]
    for bad, why in (("1,1", "given twice"), ("2,1-3", "given twice"), ("a", "not a seed"), ("3-1", "A <= B"),
                     ("-1", "not a seed"), ("1,", "not a seed"), ("0-1000", "more than")):
        with pytest.raises(ValueError, match=why):
            parse_seeds(bad)


@pytest.mark.parametrize("argv, want", [
    (["--seed", "1", "--seeds", "1,2"], "give --seed or --seeds, not both"),
    (["--seeds", "1,x"], "'x' is not a seed"),
    (["--seeds", "2,2"], "seed 2 is given twice"),
])
def test_bad_seeds_are_one_line(seq, argv, want, capsys):
    assert main(["benchmark", str(seq), "--trackers", "chamfer", "--inline", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gflow benchmark: error:") and want in err[0], err


def _scored(seq: str, auc: float, cle: float) -> Row:
    curve = np.full(21, auc)
    return Row(seq, "dcf", "tracker", score=TrackScore(frames=10, cle=cle, mean_overlap=auc, success=auc, missing=0),
               curve=curve, precision=np.linspace(0.0, 1.0, 51))


def test_a_row_not_scored_on_one_seed_is_not_averaged():
    runs = [[_scored("a", 0.8, 2.0), _scored("b", 0.6, 4.0)],
            [_scored("a", 0.4, 6.0), Row("b", "dcf", "tracker", note="failed: boom")]]
    a, b = mean_rows(runs, [1, 2])
    assert a.auc == pytest.approx(0.6) and a.score is not None and a.score.cle == pytest.approx(4.0)
    assert b.score is None and b.auc is None and b.note == "not scored with seed 2 (failed: boom)"
    text = format_seed_tables(runs, [1, 2])
    # the mean over the sequences counts only those scored with every seed, and says so
    assert "mean of 1 (of 2)" in text and "0.800" in text and "0.400" in text


def test_stress_runs_each_seed(seq, tmp_path):
    stress = ["--stress", "--cases", "fast-2", "--lead", "8", "--tail", "20", "--trackers", "chamfer", "--inline",
              "--opencv", "none", "-q", "--json"]
    both = _bench(str(seq), *stress, "--seeds", "1,2", "--out-dir", str(tmp_path / "runs"))
    assert both["seeds"] == [1, 2] and [r["seed"] for r in both["runs"]] == [1, 2]
    alone = _bench(str(seq), *stress, "--seed", "2")
    timeless = [{k: v for k, v in r.items() if k not in ("fps", "seconds", "seconds_total", "boxes")}
                for r in alone["rows"]]
    assert [{k: v for k, v in r.items() if k not in ("fps", "seconds", "seconds_total", "boxes")}
            for r in both["runs"][1]["rows"]] == timeless
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["seed-1", "seed-2"]
    # as text: each seed's tables, then the summaries side by side, each figure the seed's JSON's
    r = cli_fork.run_command([*GFLOW, "benchmark", str(seq), *stress[:-1], "--seeds", "1,2", "--markdown"],
                             capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "## seed 1" in lines and "## seed 2" in lines and "## every seed" in lines
    assert "|  | seed 1 | seed 2 |" in lines
    back = [ln for ln in lines if ln.startswith("| got back, every case |")]
    want = [f"{a} / {b}" for a, b in (run["summary"]["chamfer"]["back"]["every case"] for run in both["runs"])]
    assert back == [f"| got back, every case | {want[0]} | {want[1]} |"]


def test_stress_seeds_table_marks_what_a_seed_lacks():
    summary = {"back": {"every case": [3, 4], "fast motion": [1, 2]}, "mean_success": 0.5,
               "hidden_reported_occluded_or_lost": [9, 10]}
    text = format_stress_seeds([{"dcf": summary}, {}], [1, 2])
    assert "got back, every case" in text and "3 / 4" in text and "9 / 10 (0.900)" in text and "0.500" in text
    rows = {ln.split("  ")[0]: ln for ln in text.splitlines()}
    assert rows["got back, rolls <= 35 degrees"].split()[-2:] == ["-", "-"]  # no such group: not a zero
    assert rows["mean success"].split()[-1] == "-"  # the second seed has no dcf at all


def test_a_seed_interrupted_midway_is_left_out(seq):
    """SIGINT during the second seed: exit 130, and the tables hold the first seed, which finished."""
    # frames paced at 10 fps, so the second seed's run is still going when the signal comes
    rc, out, seen = interrupt_after([*GFLOW, "benchmark", str(seq), "--trackers", "chamfer", "--opencv", "none", "--json",
                                     "--seeds", "1,2", "--set", "source.realtime=true", "--set", "source.fps=10"],
                                    "seed 2")
    assert rc == 130, "".join(seen)
    res = json.loads(out)
    assert res["seed"] == 1 and res["interrupted"] is True and "seeds" not in res
    assert _row(res, "chamfer")["frames"] == FRAMES  # seed 1's run, whole
    assert any("seed 2 was interrupted: the tables hold seeds 1" in ln for ln in seen), "".join(seen)
