"""``gflow benchmark``: the real CLI on a short synthetic sequence folder and on ../shared/data/crossing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from gflow_core.evaluation.metrics import score
from gflow_core.synthetic import SyntheticScene
from pipeline.cli.main import main
from pipeline.io.datasets import write_frames
from pipeline.recording.results import read_boxes, write_boxes

import cli_fork
from conftest import StderrLines, data_dir

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]
FRAMES = 30


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    """A sequence folder: 30 synthetic frames, their ground truth and a fake published tracker
    (the truth shifted by 6 px, one frame missing)."""
    root = tmp_path_factory.mktemp("bench") / "synth"
    scene = SyntheticScene(n_frames=FRAMES, seed=3, period=60)
    write_frames(root / "frames", [scene.render(t) for t in range(FRAMES)])
    truth = {t: scene.truth_box(t) for t in range(FRAMES)}
    write_boxes(root / "groundtruth.csv", truth)
    other = {t: (b[0] + 6.0, b[1], b[2], b[3]) for t, b in truth.items() if t != 7}
    write_boxes(root / "results" / "other.csv", other)
    return root


def _run(args: list[str], timeout: float = 120) -> subprocess.CompletedProcess:
    return cli_fork.run_command([*GFLOW, "benchmark", *args], capture_output=True, text=True, timeout=timeout)


def _eval(gt: Path, pred: str) -> dict:
    out = cli_fork.run_command([*GFLOW, "eval", "--gt", str(gt), "--pred", pred, "--json"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def _row(rows: list[dict], tracker: str) -> dict:
    found = [r for r in rows if r["tracker"] == tracker]
    assert len(found) == 1, f"expected one row {tracker!r} in {[r['tracker'] for r in rows]}"
    return found[0]


@pytest.fixture(scope="module")
def inline_run(seq, tmp_path_factory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("inline")
    r = _run([str(seq), "--trackers", "chamfer,m2", "--inline", "--json", "--out-dir", str(out / "runs"),
              "--plot", str(out / "success.png"), "--precision-plot", str(out / "precision.png"),
              "--opencv", "mil,csrt"])
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return json.loads(r.stdout), out


def test_inline_scores_equal_gflow_eval(seq, inline_run):
    res, out = inline_run
    rows = res["rows"]
    assert res["mode"] == "inline" and res["seed"] == 1 and res["sequences"] == ["synth"]
    chamfer = _row(rows, "chamfer")
    assert chamfer["kind"] == "tracker" and chamfer["frames"] == FRAMES and chamfer["fps"] > 0
    # every scored row (ours, published, baseline) equals `gflow eval` on the same CSV
    for name in ("chamfer", "other", "static box"):
        row = _row(rows, name)
        ev = _eval(seq / "groundtruth.csv", row["boxes"])
        assert ev.pop("absent_frames") == 0 and ev.pop("empty_predictions") == 0, name  # no box of no size here
        ev.pop("auc_size_right"), ev.pop("auc_place_right")  # eval's own split of the AUC, not in a benchmark's row
        assert {k: row[k] for k in ev} == ev, name
        assert row["auc"] == pytest.approx(np.mean(row["success_curve"]), abs=1e-4)
        assert row["success_curve"][10] == pytest.approx(row["success_rate_0.5"], abs=1e-4)  # threshold 0.5
    other = _row(rows, "other")
    assert other["kind"] == "published" and other["missing_predictions"] == 1
    assert other["boxes"] == str(seq / "results" / "other.csv")
    static = _row(rows, "static box")
    assert static["kind"] == "baseline"
    assert set(read_boxes(static["boxes"]).values()) == {read_boxes(seq / "groundtruth.csv")[0]}
    # the tracker's boxes were read back from its recording, kept with --out-dir
    assert Path(chamfer["boxes"]).with_suffix(".mcap").is_file()
    m2 = _row(rows, "m2")
    assert "cle_px" not in m2 and "--m2-model" in m2["note"]


def test_opencv_rows(inline_run):
    res, _ = inline_run
    for name in ("opencv mil", "opencv csrt"):
        row = _row(res["rows"], name)
        assert row["kind"] == "opencv"
        if "cle_px" in row:
            assert row["frames"] == FRAMES and row["fps"] > 0
        else:
            assert "unavailable" in row["note"]


def test_plots_are_images(inline_run):
    _, out = inline_run
    for name in ("success.png", "precision.png"):
        p = out / name
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = cv2.imread(str(p))
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100


def _tables(text: str) -> dict[str, list[dict[str, str]]]:
    """The plain-text tables of ``gflow benchmark``: {title's first word(s) before " (": [{column: cell}]}."""
    out: dict[str, list[dict[str, str]]] = {}
    for block in text.strip().split("\n\n"):
        lines = block.splitlines()
        if len(lines) == 1 and " (" in lines[0]:
            title = lines[0].split(" (")[0]
            continue
        if len(lines) >= 3 and set(lines[1]) <= {"-", " "}:
            # columns are separated by two spaces or more; the rule line gives their extents
            spans, x = [], 0
            for dashes in lines[1].split("  "):
                if dashes:
                    spans.append((x, x + len(dashes)))
                x += len(dashes) + 2

            def cells(line: str) -> list[str]:
                return [line[a:b + 1 if i < len(spans) - 1 else None].strip() if a < len(line) else ""
                        for i, (a, b) in enumerate(spans)]

            head = cells(lines[0])
            out[title] = [dict(zip(head, cells(ln))) for ln in lines[2:]]
    return out


def _close(cell: str, want: float, places: int) -> bool:
    """A printed figure equals the JSON's (rounded one place further) within half a printed unit
    plus the JSON's rounding (a value on a rounding boundary, AUC 0.68254 printed 0.683 and kept
    as 0.6825, must not fail)."""
    return abs(float(cell) - want) <= 0.5 * 10.0 ** -places + 0.5 * 10.0 ** -(places + 1) + 1e-12


def test_processes_tables_match_inline(seq, inline_run):
    """The default (multi-process) run prints one table per tracker whose scores equal the inline
    run's, the static box and the published tracker beside it, and the mean over the sequences."""
    res, _ = inline_run
    r = _run([str(seq), "--trackers", "chamfer"])
    assert r.returncode == 0, r.stderr
    assert "benchmark: [1/1] synth / chamfer" in r.stderr  # progress on stderr
    tables = _tables(r.stdout)
    assert list(tables) == ["chamfer", "static box", "published trackers", "means over the sequences"]
    chamfer = tables["chamfer"]
    assert list(chamfer[0])[:7] == ["sequence", "frames scored", "AUC", "prec@20", "CLE px", "success", "fps"]
    assert [c["sequence"] for c in chamfer] == ["synth", "mean of 1"]
    for name, cells in (("chamfer", chamfer[0]), ("static box", tables["static box"][0]),
                        ("other", tables["published trackers"][0])):
        row = _row(res["rows"], name)
        assert int(cells["frames scored"]) == row["frames"], name
        for col, key, places in (("AUC", "auc", 3), ("prec@20", "precision_20", 3), ("CLE px", "cle_px", 2),
                                 ("success", "success_rate_0.5", 3)):
            assert _close(cells[col], row[key], places), (name, col, cells[col], row[key])
    # beside the tracker: the static box's and the best published tracker's AUC on the same sequence
    assert _close(chamfer[0]["static box AUC"], _row(res["rows"], "static box")["auc"], 3)
    assert chamfer[0]["best published AUC"].startswith("other ")
    assert _close(chamfer[0]["best published AUC"].split()[1], _row(res["rows"], "other")["auc"], 3)
    assert float(chamfer[0]["fps"]) > 0 and tables["static box"][0]["fps"] == "-"
    # one sequence: the mean is its figures; the JSON has the means too
    assert {k: chamfer[1][k] for k in ("AUC", "CLE px")} == {k: chamfer[0][k] for k in ("AUC", "CLE px")}
    assert res["means"]["chamfer"]["sequences"] == 1
    assert res["means"]["chamfer"]["auc"] == _row(res["rows"], "chamfer")["auc"]
    means = {c["tracker"]: c for c in tables["means over the sequences"]}
    assert set(means) == {"chamfer", "static box"} and means["chamfer"]["AUC above static box"] in ("0 of 1", "1 of 1")
    assert "processes, seed 1; gflow " in r.stdout and "numpy " in r.stdout  # the versions it ran on


def test_means_over_sequences(tmp_path):
    """Two sequences: the mean row is the mean of the two rows, and a tracker skipped on none."""
    from gflow_core.evaluation.metrics import TrackScore
    from pipeline.evaluation.benchmark_tables import format_tables, means_json
    from pipeline.evaluation.sequence_benchmark import PRECISION_THRESHOLDS, Row

    def row(seq: str, tracker: str, kind: str, cle: float, auc: float, prec: float) -> Row:
        r = Row(seq, tracker, kind, score=TrackScore(10, cle, auc, auc, 0), fps=30.0 if kind != "baseline" else None)
        r.curve, r.precision = np.full(21, auc), np.full(PRECISION_THRESHOLDS.shape, prec)
        return r

    rows = [row("a", "t", "tracker", 2.0, 0.8, 1.0), row("a", "opencv csrt", "opencv", 4.0, 0.6, 0.9),
            row("a", "static box", "baseline", 30.0, 0.2, 0.1), row("b", "t", "tracker", 4.0, 0.4, 0.5),
            row("b", "opencv csrt", "opencv", 6.0, 0.5, 0.7), row("b", "static box", "baseline", 50.0, 0.5, 0.0)]
    text = format_tables(rows, fps=False)
    t = _tables(text)
    assert "fps" not in t["t"][0]
    mean = t["t"][-1]
    assert mean["sequence"] == "mean of 2" and mean["AUC"] == "0.600" and mean["CLE px"] == "3.00"
    assert mean["prec@20"] == "0.750" and mean["CSRT AUC"] == "0.550" and mean["static box AUC"] == "0.350"
    assert t["opencv csrt"][-1]["AUC"] == "0.550"
    means = {c["tracker"]: c for c in t["means over the sequences"]}
    assert means["t"]["AUC above static box"] == "1 of 2" and means["opencv csrt"]["AUC above static box"] == "1 of 2"
    assert means["t"]["AUC below CSRT on"] == "b" and means["t"]["AUC below static box on"] == "b"
    assert means["opencv csrt"]["AUC below CSRT on"] == "-"
    assert means_json(rows)["t"] == {"sequences": 2, "of": 2, "auc": 0.6, "precision_20": 0.75, "cle_px": 3.0,
                                     "success_rate_0.5": 0.6}
    md = format_tables(rows, markdown=True)
    assert "**t** (tracker; beside it the AUC of CSRT, static box)" in md
    assert "| mean of 2 |  | 0.600 | 0.750 | 3.00 | 0.600 | - | 0.550 | 0.350 |" in md


@pytest.mark.parametrize("case", ["missing", "no_frames", "no_truth", "tracker", "opencv", "model", "frames",
                                  "no_first_box", "plot_folder", "plot_format", "set_stage", "set_unknown",
                                  "set_unknown_every_tracker", "set_bad_value_every_tracker"])
def test_bad_input_is_one_line(case, seq, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    (tmp_path / "nogt" / "frames").mkdir(parents=True)
    (tmp_path / "noframes").mkdir()
    write_boxes(tmp_path / "noframes" / "groundtruth.csv", {0: (1, 2, 3, 4)})
    argv = {"missing": [str(tmp_path / "nope")],
            "no_frames": [str(tmp_path / "noframes")],
            "no_truth": [str(tmp_path / "nogt")],
            "tracker": [str(seq), "--trackers", "chamfer,nosuch"],
            "opencv": [str(seq), "--opencv", "nosuch"],
            "model": [str(seq), "--m2-model", str(tmp_path / "missing.npz")],
            "frames": [str(seq), "--frames", "20:10"],
            "no_first_box": [str(seq), "--frames", f"{FRAMES + 5}:{FRAMES + 9}"],
            "plot_folder": [str(seq), "--plot", str(tmp_path / "nodir" / "s.png")],
            "plot_format": [str(seq), "--plot", str(tmp_path / "s.xyz")],
            # a --set no selected tracker takes would skip every run: an error, not a table of skips
            "set_stage": [str(seq), "--trackers", "chamfer", "--set", "filter.particles=50"],
            "set_unknown": [str(seq), "--trackers", "chamfer", "--set", "tracker.nope=1"],
            # each tracker refusing it in words of its own (the default --trackers; m2 skipped for want of a
            # model) was a table of skips and exit 0
            "set_unknown_every_tracker": [str(seq), "--set", "tracker.nope=1"],
            "set_bad_value_every_tracker": [str(seq), "--trackers", "dcf,gflow", "--set", "tracker.particles=abc"]}[case]
    want = {"missing": "not found", "no_frames": "no frames/", "no_truth": "no groundtruth.csv", "tracker": "nosuch",
            "opencv": "unknown OpenCV tracker 'nosuch' in --opencv", "model": "missing.npz", "frames": "20:10", "no_first_box": f"frame {FRAMES + 5}",
            "plot_folder": "does not exist", "plot_format": ".png", "set_stage": "--set tracker.particles=VALUE",
            "set_unknown": "has no parameter 'nope'", "set_unknown_every_tracker": "has no parameter 'nope'",
            "set_bad_value_every_tracker": "particles must be a whole number, got 'abc'"}[case]
    assert main(["benchmark", *argv, "--inline"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gflow benchmark: error:") and want in err[0], err


def test_empty_parent_folder_is_an_error(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    assert main(["benchmark", str(tmp_path)]) == 2
    assert "holds none" in capsys.readouterr().err


def test_ctrl_c_stops_cleanly(seq, tmp_path):
    """SIGINT during a multi-process run: exit 130, the runs' temporary folder removed."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = dict(os.environ, TMPDIR=str(tmp))
    # frames paced at 5 fps, so the run is still going when the signal comes
    p = subprocess.Popen([*GFLOW, "benchmark", str(seq), "--trackers", "chamfer", "--set", "source.realtime=true",
                          "--set", "source.fps=5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    err = StderrLines(p)
    err.until(lambda seen: any(ln.startswith("source: ") and not ln.startswith("source: 0") for ln in seen), 90)
    p.send_signal(signal.SIGINT)
    p.wait(timeout=60)
    assert p.returncode == 130, "".join(err.rest())
    assert not list(tmp.glob("gflow-benchmark-*")), "the temporary folder was left behind"


def test_crossing_first_40_frames(tmp_path):
    """Real data: chamfer on crossing frames 0:40 (multi-process), its row scored like `gflow eval` over those frames."""
    crossing = data_dir("crossing")
    r = _run([str(crossing), "--trackers", "chamfer", "--frames", "0:40", "--json", "--out-dir", str(tmp_path)])
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["mode"] == "processes" and res["frames"] == [0, 40]
    gt = {f: b for f, b in read_boxes(crossing / "groundtruth.csv").items() if f < 40}
    chamfer, static = _row(res["rows"], "chamfer"), _row(res["rows"], "static box")
    assert chamfer["frames"] == 40 and chamfer["fps"] > 0
    for row, pred in ((chamfer, read_boxes(chamfer["boxes"])), (static, {f: gt[0] for f in gt})):
        want = score(gt, pred).to_json()
        assert {k: row[k] for k in want} == want, row["tracker"]


def test_folder_of_sequences(seq, tmp_path):
    """A parent folder runs each sequence in it, notes what it skips, and starts each sequence at its
    first ground-truth box (here frame 5)."""
    late = tmp_path / "late"
    late.mkdir()
    (late / "frames").symlink_to(seq / "frames", target_is_directory=True)
    gt = {f: b for f, b in read_boxes(seq / "groundtruth.csv").items() if f >= 5}
    write_boxes(late / "groundtruth.csv", gt)
    (tmp_path / "avletters").mkdir()
    (tmp_path / "avletters" / "anya.npz").write_bytes(b"")
    r = _run([str(tmp_path), "--trackers", "chamfer", "--inline", "--json", "--out-dir", str(tmp_path / "out")])
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["sequences"] == ["late"] and res["frames"] == [None, None]
    assert any("avletters" in s and "not a sequence folder" in s for s in res["skipped"])
    assert "avletters" in r.stderr
    chamfer = _row(res["rows"], "chamfer")
    assert chamfer["frames"] == FRAMES - 5 and chamfer["missing_predictions"] == 0
    assert min(read_boxes(chamfer["boxes"])) == 5
    assert read_boxes(chamfer["boxes"])[5] == pytest.approx(gt[5], abs=0.01)  # started from the first box


def test_rows_do_not_depend_on_order(seq, tmp_path):
    """Two copies of one sequence in one run score the same, OpenCV's MIL included (it draws from
    OpenCV's global RNG, which every OpenCV run reseeds)."""
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        for entry in ("frames", "groundtruth.csv"):
            (tmp_path / name / entry).symlink_to(seq / entry)
    r = _run([str(tmp_path), "--trackers", "chamfer", "--opencv", "mil", "--inline", "--json"])
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["rows"]
    for tracker in ("chamfer", "opencv mil", "static box"):
        a, b = ({k: v for k, v in row.items() if k not in ("sequence", "fps", "seconds", "seconds_total")}
                for row in rows if row["tracker"] == tracker)
        assert a == b, tracker


def test_each_temporary_recording_is_removed_once_its_run_is_scored(seq, monkeypatch, capsys):
    """Without --out-dir a run's recording goes as soon as its boxes are scored and timed (nine
    sequences and five trackers keep gigabytes otherwise, until the end), and the scores stand."""
    import pipeline.app

    made: list[tuple[Path, list[bool]]] = []
    real = pipeline.app.track

    def track(plan, *a, **kw):
        before = [p.exists() for p, _ in made]  # the earlier runs' recordings, as this run starts
        run = real(plan, *a, **kw)
        made.append((Path(run.recording), before))
        return run

    monkeypatch.setattr(pipeline.app, "track", track)
    assert main(["benchmark", str(seq), "--trackers", "dcf,appearance", "--frames", "0:8", "--inline",
                 "--opencv", "none", "--json", "-q"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert [r.get("auc") is not None for r in res["rows"] if r["kind"] == "tracker"] == [True, True], res["rows"]
    assert len(made) == 2 and made[0][0].suffix == ".mcap"
    assert made[1][1] == [False]  # the first run's recording was gone when the second started
