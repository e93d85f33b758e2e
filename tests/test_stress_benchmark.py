"""``gflow benchmark --stress``, the confidence,state columns and ``gflow eval --visibility``: the real
CLI on two short synthetic sequence folders (a few seconds per run)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.recording.results import read_boxes, read_track, read_visibility, write_boxes
import cli_fork
from conftest import synthetic_sequence
from gflow_msgs.messages import Estimate, Frame, Header, NDArray
from gflow_msgs.annotations import MAGENTA, ORANGE, annotations_for

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]
FRAMES = 60
STRESS = ["--stress", "--cases", "none,occlude-10,fast-2", "--lead", "8", "--tail", "20", "--trackers", "appearance",
          "--inline", "-q"]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Two sequence folders (each the other's donor of image patches)."""
    root = tmp_path_factory.mktemp("stressdata")
    for name, seed in (("synth", 3), ("other", 5)):
        synthetic_sequence(root / name, seed, FRAMES)
    return root


def _gflow(*args: str, env: dict | None = None, timeout: float = 240) -> subprocess.CompletedProcess:
    return cli_fork.run_command([*GFLOW, *args], capture_output=True, text=True, timeout=timeout,
                          env=None if env is None else dict(os.environ, **env))


@pytest.fixture(scope="module")
def first_run(data, tmp_path_factory) -> tuple[dict, Path, Path, str]:
    out = tmp_path_factory.mktemp("stressrun")
    cache, runs = out / "cache", out / "runs"
    r = _gflow("benchmark", str(data), *STRESS, "--json", "--stress-cache", str(cache), "--out-dir", str(runs))
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return json.loads(r.stdout), cache, runs, r.stderr


def _derived(cache: Path, seq: str, case: str, seed: int = 1) -> Path:
    """The cached folder of a derived sequence (``CACHE/SEQ/CASE-KEY``) made with ``seed``."""
    found = [d for d in (cache / seq).glob(f"{case}-*") if json.loads((d / "stress.json").read_text())["seed"] == seed]
    assert len(found) == 1, found
    return found[0]


def _rows(res: dict, **kw) -> list[dict]:
    return [r for r in res["rows"] if all(r[k] == v for k, v in kw.items())]


def test_every_case_of_every_sequence_has_its_rows(first_run):
    res, _, _, err = first_run
    assert res["sequences"] == ["other", "synth"] and res["mode"] == "inline" and res["lead"] == 8
    assert [c["name"] for c in res["cases"]] == ["none", "occlude-10", "fast-2"]
    for seq in ("other", "synth"):
        for case in ("occlude-10", "fast-2"):
            mine = _rows(res, sequence=seq, case=case)
            kinds = {"tracker", "baseline"} | (set() if res["opencv_missing"] else {"opencv"})
            assert {r["kind"] for r in mine} == kinds, mine
            app = _rows(res, sequence=seq, case=case, tracker="appearance")[0]
            assert app["frames"] == (38 if case == "occlude-10" else 58)  # fast-2: 60 frames in the window, 30 kept
            assert app["window"] == ([8, 18] if case == "occlude-10" else [8, 38])
            assert 0 <= app["success"] <= 1 and app["fps"] > 0 and "state" in app
            if not res["opencv_missing"]:
                assert _rows(res, sequence=seq, case=case, tracker="opencv csrt")[0]["cle_px"] is not None
    assert "[1/6] other / none" in err and "[6/6] synth / fast-2" in err
    assert set(res["summary"]) == {"appearance"} | (set() if res["opencv_missing"] else {"opencv csrt"})
    if res["opencv_missing"]:
        assert "unavailable" in res["opencv_missing"]["csrt"] and "opencv csrt not measured" in err


def test_derived_folder_truth_visibility_and_untouched_frames(first_run, data):
    _, cache, _, _ = first_run
    d = _derived(cache, "synth", "occlude-10")
    meta = json.loads((d / "stress.json").read_text())
    assert meta["window"] == [8, 18] and meta["patch_from"].startswith("other frame ")
    gt = read_boxes(d / "groundtruth.csv")
    vis, pert = read_visibility(d / "visibility.csv")
    assert sorted(gt) == sorted(vis) == list(range(38))
    assert all(vis[f] == 0 for f in range(8, 18)) and all(vis[f] > 0.99 for f in range(8))
    assert [f for f in pert if pert[f]] == list(range(8, 18))
    # the truth is the original's, frame for frame
    src = {int(r.split(",")[0]): int(r.split(",")[3]) for r in (d / "visibility.csv").read_text().split()[1:]}
    orig = read_boxes(data / "synth" / "groundtruth.csv")
    assert all(np.allclose(gt[f], orig[src[f]], atol=0.01) for f in gt)
    # frames outside the window are the original files, byte for byte
    frames = sorted((d / "frames").iterdir())
    assert len(frames) == 38
    assert frames[0].read_bytes() == (data / "synth" / "frames" / f"{src[0]:06d}.png").read_bytes()
    assert frames[10].suffix == ".jpg"


def test_scores_equal_gflow_eval_and_the_csv_has_the_state(first_run):
    res, cache, runs, _ = first_run
    app = _rows(res, sequence="synth", case="occlude-10", tracker="appearance")[0]
    csv = runs / "synth" / "occlude-10" / "appearance.csv"
    d = _derived(cache, "synth", "occlude-10")
    assert csv.read_text().splitlines()[0] == "frame,x,y,w,h,confidence,state"
    track = read_track(csv)
    assert track.states is not None and set(track.states.values()) <= {"tracked", "occluded", "lost"}
    r = _gflow("eval", "--gt", str(d / "groundtruth.csv"), "--pred", str(csv), "--visibility",
               str(d / "visibility.csv"), "--json")
    assert r.returncode == 0, r.stderr
    ev = json.loads(r.stdout)
    assert ev["cle_px"] == pytest.approx(app["cle_px"], abs=1e-3)
    assert ev["success_rate_0.5"] == pytest.approx(app["success"], abs=1e-4)
    assert ev["state"] == app["state"]
    assert ev["state"]["hidden_frames"] == 5  # 10 hidden frames, the first 5 not scored
    # the after score: success from 10 frames after the window on, as eval computes it on those frames
    r = _gflow("eval", "--gt", str(d / "groundtruth.csv"), "--pred", str(csv), "--frames", "28:", "--json")
    assert json.loads(r.stdout)["success_rate_0.5"] == pytest.approx(app["after"], abs=1e-4)


def test_undisturbed_frames_split_by_the_box_count_again_from_the_files(first_run):
    res, cache, runs, _ = first_run
    pooled = np.zeros(4, dtype=np.int64)
    for row in _rows(res, tracker="appearance"):
        d = _derived(cache, row["sequence"], row["case"])
        gt = read_boxes(d / "groundtruth.csv")
        vis, pert = read_visibility(d / "visibility.csv")
        track = read_track(runs / row["sequence"] / row["case"] / "appearance.csv")
        assert pert is not None and track.states is not None
        frames = sorted(gt)
        # undisturbed: not perturbed and at least a tenth of the target in view; on the target: IoU > 0.5
        shown = np.array([not pert[f] and vis[f] >= 0.1 for f in frames])
        on = np.array([_iou(gt[f], track.boxes[f]) > 0.5 for f in frames])
        said = np.array([track.states[f] for f in frames])
        counts = [(shown & on).sum(), (shown & on & (said == "tracked")).sum(), (shown & ~on).sum(),
                  (shown & ~on & np.isin(said, ["occluded", "lost"])).sum()]
        st = row["state"]
        assert st["undisturbed_on_target_frames"] + st["undisturbed_off_target_frames"] == st["undisturbed_frames"]
        assert [st["undisturbed_on_target_frames"], st["undisturbed_off_target_frames"]] == [counts[0], counts[2]]
        pooled += counts
    s = res["summary"]["appearance"]
    assert s["undisturbed_on_target_reported_tracked"] == [pooled[1], pooled[0]]
    assert s["undisturbed_off_target_reported_occluded_or_lost"] == [pooled[3], pooled[2]]


def _iou(a: tuple, b: tuple) -> float:
    w = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    return w * h / (a[2] * a[3] + b[2] * b[3] - w * h)


@pytest.mark.parametrize("case, frames", [("occlude-10", "28:38"), ("fast-2", "78:88")])
def test_untouched_after_is_the_control_run_on_the_same_original_frames(first_run, case, frames):
    res, cache, runs, _ = first_run
    row = _rows(res, sequence="other", case=case, tracker="appearance")[0]
    control = _derived(cache, "other", "none")
    r = _gflow("eval", "--gt", str(control / "groundtruth.csv"), "--pred", str(runs / "other" / "none" /
               "appearance.csv"), "--frames", frames, "--json")
    assert json.loads(r.stdout)["success_rate_0.5"] == pytest.approx(row["untouched_after"], abs=1e-4)
    # the same original frames
    src = {c: [line.split(",")[3] for line in (_derived(cache, "other", c) / "visibility.csv").read_text().split()[1:]]
           for c in ("none", case)}
    a, b = (int(v) for v in frames.split(":"))
    assert src[case][28 if case == "occlude-10" else 48:] == src["none"][a:b]


def test_gflow_boxes_writes_the_same_columns_from_the_recording(first_run, tmp_path):
    _, _, runs, _ = first_run
    run = runs / "synth" / "fast-2"
    r = _gflow("boxes", str(run / "appearance.mcap"), "--out", str(tmp_path / "b.csv"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "b.csv").read_text() == (run / "appearance.csv").read_text()


def test_second_run_reuses_the_cache_and_gives_the_same_scores(first_run, data):
    res, cache, _, _ = first_run
    args = [a if a != "none,occlude-10,fast-2" else "occlude-10" for a in STRESS]
    r = _gflow("benchmark", str(data), *args, "--sequences", "synth", "--json", "--stress-cache", str(cache))
    assert r.returncode == 0, r.stderr
    assert "synth / occlude-10: 38 frames, window 8:18 (cached)" in r.stderr
    keys = ("tracker", "cle_px", "success", "after", "back_in", "state")
    again = [{k: row.get(k) for k in keys} for row in json.loads(r.stdout)["rows"]]
    assert again == [{k: row.get(k) for k in keys} for row in _rows(res, sequence="synth", case="occlude-10")]


def test_runs_of_other_seeds_keep_their_own_derived_frames_in_a_shared_cache(first_run, data):
    # a run with another seed writes its own folder; the first seed's frames stay cached
    _, cache, _, _ = first_run
    args = [a if a != "none,occlude-10,fast-2" else "occlude-10" for a in STRESS]
    other = _gflow("benchmark", str(data), *args, "--sequences", "synth", "--seed", "2", "--json", "--stress-cache",
                   str(cache))
    assert other.returncode == 0, other.stderr
    assert "(cached)" not in other.stderr
    again = _gflow("benchmark", str(data), *args, "--sequences", "synth", "--json", "--stress-cache", str(cache))
    assert again.returncode == 0, again.stderr
    assert "synth / occlude-10: 38 frames, window 8:18 (cached)" in again.stderr
    assert len(list((cache / "synth").glob("occlude-10-*"))) == 2


def test_two_runs_deriving_one_sequence_at_once_both_read_complete_frames(data, tmp_path):
    # each run writes the derived sequence under a name of its own and renames it when complete:
    # both get a complete folder, one folder is kept, nothing half-written is left
    from concurrent.futures import ThreadPoolExecutor

    from gflow_core.evaluation.stress import CASES
    from pipeline.evaluation.sequence_benchmark import find_sequences
    from pipeline.evaluation.stress_benchmark import derive

    seqs, _ = find_sequences([str(data)])
    synth, other = sorted(seqs, key=lambda q: q.name != "synth")
    case = next(c for c in CASES if c.name == "occlude-10")
    cache = tmp_path / "cache"
    with ThreadPoolExecutor(2) as pool:
        runs = [pool.submit(derive, synth, case, other, cache, 1, 8, 20) for _ in range(2)]
        got = [r.result() for r in runs]
    assert got[0].seq.path == got[1].seq.path
    assert len(list((got[0].seq.path / "frames").glob("*"))) == 38
    assert [p.name for p in (cache / "synth").iterdir()] == [got[0].seq.path.name]


def test_sparse_ground_truth_is_scored_on_the_labelled_frames_only(data, tmp_path):
    """A sequence labelled every 5th frame (as the MIL dataset): the derived truth and visibility hold
    the frames that show a labelled one, the scores are `gflow eval`'s on those, and the summary
    reports per family and per sequence."""
    sparse = tmp_path / "sparse"
    sparse.mkdir()
    (sparse / "frames").symlink_to(data / "synth" / "frames", target_is_directory=True)
    truth = read_boxes(data / "synth" / "groundtruth.csv")
    write_boxes(sparse / "groundtruth.csv", {f: b for f, b in truth.items() if f % 5 == 0})
    cache, runs = tmp_path / "cache", tmp_path / "runs"
    r = _gflow("benchmark", str(sparse), str(data / "other"), "--sequences", "sparse", *STRESS, "--opencv", "none",
               "--json", "--stress-cache", str(cache), "--out-dir", str(runs))
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    d = _derived(cache, "sparse", "occlude-10")
    src = {int(ln.split(",")[0]): int(ln.split(",")[3]) for ln in (d / "visibility.csv").read_text().split()[1:]}
    gt = read_boxes(d / "groundtruth.csv")
    assert sorted(gt) == sorted(src) and all(f % 5 == 0 for f in src.values()) and 0 in gt
    assert all(np.allclose(gt[f], truth[src[f]], atol=0.01) for f in gt)
    assert len(list((d / "frames").iterdir())) == 38 > len(gt)  # every frame is shown, the labelled ones scored
    app = _rows(res, sequence="sparse", case="occlude-10", tracker="appearance")[0]
    assert app["frames"] == len(gt)
    csv = runs / "sparse" / "occlude-10" / "appearance.csv"
    ev = json.loads(_gflow("eval", "--gt", str(d / "groundtruth.csv"), "--pred", str(csv), "--visibility",
                           str(d / "visibility.csv"), "--json").stdout)
    assert ev["success_rate_0.5"] == pytest.approx(app["success"], abs=1e-4) and ev["state"] == app["state"]
    after = [f for f in gt if f >= 18 + 10]
    ev_after = json.loads(_gflow("eval", "--gt", str(d / "groundtruth.csv"), "--pred", str(csv), "--frames",
                                 f"{min(after)}:", "--json").stdout)
    assert ev_after["success_rate_0.5"] == pytest.approx(app["after"], abs=1e-4)
    summary = res["summary"]["appearance"]
    assert set(summary["families"]) == {"occlude", "fast"} and list(summary["sequences"]) == ["sparse"]
    assert summary["sequences"]["sparse"]["back"][1] == 2 == summary["back"]["every case"][1]


def test_markdown_table_and_nothing_left_behind(data, tmp_path):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    r = _gflow("benchmark", str(data), "--stress", "--cases", "fast-2", "--sequences", "synth", "--lead", "8",
               "--tail", "20", "--trackers", "appearance", "--inline", "-q", "--opencv", "none", "--markdown",
               env={"TMPDIR": str(tmp)})
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "### appearance"
    assert any(line.startswith("| synth | fast-2 |") for line in lines)
    assert any(line.startswith("- back after fast motion") for line in lines)
    family = lines.index("**appearance per family**")
    assert lines[family + 2] == "| family | got back | mean success | mean after |"
    assert lines[family + 4].startswith("| fast | 0/1 |") or lines[family + 4].startswith("| fast | 1/1 |")
    assert "**appearance per sequence**" in lines and any(ln.startswith("| synth | ") for ln in lines)
    assert "csrt" not in r.stdout.lower()
    assert list(tmp.iterdir()) == []  # the derived sequences and runs were removed


@pytest.mark.parametrize("args, msg", [
    (["--cases", "wobble"], "unknown stress case 'wobble'"),
    (["--sequences", "nope"], "unknown sequence 'nope'"),
    (["--plot", "x.png"], "--plot is not used with --stress"),
    (["--tail", "3"], "--tail at least 15"),
])
def test_mistakes_are_one_line_errors(data, args, msg):
    r = _gflow("benchmark", str(data), "--stress", "--trackers", "appearance", *args)
    assert r.returncode == 2
    assert msg in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) <= 2


def test_an_out_dir_of_an_earlier_stress_run_is_refused_before_any_case_is_derived(first_run, data, tmp_path):
    """It was refused only once the first case had been derived and its progress said (and not at all with no
    tracker recording there: the OpenCV and still box CSVs were written over)."""
    _, _, runs, _ = first_run
    before = {p: p.stat().st_mtime_ns for p in runs.rglob("*") if p.is_file()}
    r = _gflow("benchmark", str(data), *STRESS, "--stress-cache", str(tmp_path / "cache"), "--out-dir", str(runs))
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "exists (an earlier run's)" in lines[0], r.stderr
    assert not (tmp_path / "cache").exists()  # nothing derived
    assert {p: p.stat().st_mtime_ns for p in runs.rglob("*") if p.is_file()} == before


def test_eval_reads_old_five_column_files_and_new_seven_column_ones(tmp_path):
    gt = {f: (10.0 + f, 20.0, 30.0, 40.0) for f in range(10)}
    write_boxes(tmp_path / "gt.csv", gt)
    pred = {f: (12.0 + f, 20.0, 30.0, 40.0) for f in range(10)}
    write_boxes(tmp_path / "old.csv", pred)
    write_boxes(tmp_path / "new.csv", pred, {f: 0.5 for f in pred}, {f: "tracked" for f in pred})
    assert (tmp_path / "old.csv").read_text().splitlines()[0] == "frame,x,y,w,h"
    out = [_gflow("eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / n), "--json") for n in
           ("old.csv", "new.csv")]
    assert all(r.returncode == 0 for r in out), [r.stderr for r in out]
    assert json.loads(out[0].stdout) == json.loads(out[1].stdout)
    assert json.loads(out[0].stdout)["cle_px"] == pytest.approx(2.0)
    # the state needs the state column: a five-column file says so in one line
    (tmp_path / "vis.csv").write_text("frame,visible\n" + "".join(f"{f},1\n" for f in range(10)))
    r = _gflow("eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / "old.csv"), "--visibility",
               str(tmp_path / "vis.csv"))
    assert r.returncode == 2 and "has no state column" in r.stderr and "Traceback" not in r.stderr
    r = _gflow("eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / "new.csv"), "--visibility",
               str(tmp_path / "vis.csv"))
    assert r.returncode == 0 and "state right when undisturbed: 1.000 (tracked on 10 of 10 frames)" in r.stdout
    assert "off the target, said tracked: - (tracked on 0 of 0 frames" in r.stdout
    # boxes that leave the target on frames 6-9, said tracked on 6-7 and lost on 8-9
    off = {**pred, **{f: (200.0, 200.0, 30.0, 40.0) for f in range(6, 10)}}
    write_boxes(tmp_path / "off.csv", off, {f: 0.5 for f in off},
                {f: "lost" if f >= 8 else "tracked" for f in off})
    r = _gflow("eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / "off.csv"), "--visibility",
               str(tmp_path / "vis.csv"), "--json")
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)["state"]
    assert st["off_target_frames"] == 4 and st["off_target_reported_tracked"] == pytest.approx(0.5)
    assert [b["frames"] for b in st["confidence_bands"]] == [0, 0, 10, 0, 0]  # every confidence 0.5
    assert st["confidence_bands"][2]["on_target"] == pytest.approx(0.6)
    # the text says the same split: 6 on target all tracked; 4 off, 2 of them said lost
    r = _gflow("eval", "--gt", str(tmp_path / "gt.csv"), "--pred", str(tmp_path / "off.csv"), "--visibility",
               str(tmp_path / "vis.csv"))
    assert "box on target:  1.000 (tracked on 6 of 6" in r.stdout, r.stdout
    assert "box off target: 0.500 (occluded or lost on 2 of 4" in r.stdout, r.stdout


def test_read_track_refuses_bad_states_and_mixed_rows(tmp_path):
    p = tmp_path / "b.csv"
    p.write_text("frame,x,y,w,h,confidence,state\n0,1,2,3,4,0.5,tracked\n1,1,2,3,4,0.5,hidden\n")
    with pytest.raises(ValueError, match=r"b.csv:3: unknown state 'hidden'"):
        read_track(p)
    p.write_text("0,1,2,3,4,1.5,tracked\n")
    with pytest.raises(ValueError, match=r"outside \[0, 1\]"):
        read_track(p)
    p.write_text("0,1,2,3,4,0.5,tracked\n1,1,2,3,4\n")
    for read in (read_track, read_boxes):  # read_boxes took a row cut short after full ones
        with pytest.raises(ValueError, match=r"b.csv:2: 5 columns, but the rows before have 7 \(frame,x,y,w,h,"
                                             r"confidence,state\)"):
            read(p)


def test_overlay_colours_the_box_by_state_and_writes_the_confidence():
    img = np.zeros((40, 60, 3), np.uint8)
    frame = Frame(Header("s", 3, 0), NDArray.of(img))
    texts, colours = [], []
    for state, conf in (("tracked", 0.9), ("occluded", 0.4), ("lost", 0.05)):
        est = Estimate(Header("s", 3, 0), (5.0, 6.0, 10.0, 12.0), (0.0, 0.0, 0.0, 1.0), 0, (0.0, 0.0, 0.0, 1.0),
                       (0.0, 0.0, 0.0, 0.0), 1.0, 1, 0.0, NDArray.of(np.zeros((0, 2), np.float32)),
                       confidence=conf, target_state=state)
        ann = annotations_for(frame, est, None)
        texts.append(ann.texts[0].text)
        colours.append(ann.points[-1].outline_color)
    assert texts[0].endswith("target tracked 0.90") and texts[2].endswith("target lost 0.05")
    assert colours[1] == ORANGE and colours[2] == MAGENTA and colours[0] not in (ORANGE, MAGENTA)


def test_each_case_s_runs_are_removed_once_scored_without_out_dir(data, tmp_path, monkeypatch):
    """Without --out-dir a case's recordings and boxes go as soon as it is scored (a whole stress
    run keeps gigabytes otherwise, until its end), so the next case never finds the last one's."""
    import argparse

    from pipeline.evaluation.sequence_benchmark import find_sequences
    from pipeline.evaluation.stress_benchmark import run_stress

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    seqs, _ = find_sequences([str(data / "synth")])
    seen: list[list[str]] = []

    def plan_of(seq, name, folder):  # the still box still writes its boxes into the case's folder
        seen.append(sorted(p.name for p in folder.parent.iterdir()) if folder.parent.is_dir() else [])
        return "not run in this test"

    args = argparse.Namespace(cases="none,fast-2", stress_cache=None, out_dir=None, seed=1, lead=8, tail=20)
    rows, interrupted, _ = run_stress(args, seqs, ["appearance"], [], plan_of, donors=find_sequences([str(data)])[0])
    assert not interrupted and [r.case for r in rows if r.kind == "baseline"] == ["none", "fast-2"]
    assert seen == [[], []]  # case "none"'s folder was gone when "fast-2" was planned


def test_list_cases_lists_every_case_or_those_cases_names():
    """--list-cases printed every case whatever --cases said; it lists the ones --cases names, and a name
    it does not know is a one-line error."""
    from gflow_core.evaluation.stress import CASES

    every = _gflow("benchmark", "--list-cases")
    assert every.returncode == 0 and len(every.stdout.splitlines()) == len(CASES)
    some = _gflow("benchmark", "--list-cases", "--cases", "roll-camera,distract")
    assert some.returncode == 0, some.stderr
    assert [ln.split()[0] for ln in some.stdout.splitlines()] == ["roll-camera-20", "roll-camera-35", "roll-camera-45",
                                                                  "distract-40"]
    bad = _gflow("benchmark", "--list-cases", "--cases", "nope")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "unknown stress case 'nope'" in bad.stderr


def test_a_damaged_cached_opencv_result_is_named_and_run_again(data, tmp_path):
    """The cached OpenCV result (``opencv_NAME_seedS_cvV.json`` beside its boxes) was read unguarded: a truncated one
    ended the benchmark on 'error: Expecting value: line 1 column 9 (char 8)', naming no file, a list an internal
    error. Each damage, of the .json or of its boxes, is one line naming the file, and OpenCV runs again."""
    args = ["--stress", "--cases", "occlude-10", "--lead", "8", "--tail", "20", "--trackers", "appearance", "--inline",
            "-q", "--opencv", "mil", "--sequences", "synth", "--json", "--stress-cache", str(tmp_path / "cache")]
    r = _gflow("benchmark", str(data), *args)
    assert r.returncode == 0, r.stderr
    if json.loads(r.stdout)["opencv_missing"]:
        pytest.skip("this OpenCV has no MIL tracker")
    info = next((tmp_path / "cache" / "synth").glob("occlude-10-*/opencv_mil_seed1_cv*.json"))
    boxes = info.with_suffix(".csv")
    for damaged, text, said in ((info, '{"fps": ', "not a cached OpenCV result (Expecting value"),
                                (info, "[1, 2]", 'not a cached OpenCV result (expected {"fps": frames/s or null}, got '
                                                 '[1, 2])'),
                                (info, '{"fps": "x"}', "not a cached OpenCV result"),
                                (boxes, "frame,x\n1,2,3\n", "expected frame,x,y,w,h, got 3 column(s)")):
        good = damaged.read_text()
        damaged.write_text(text)
        r = _gflow("benchmark", str(data), *args)
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
        assert f"benchmark: {damaged}{'' if damaged == info else ':2'}: " in r.stderr and said in r.stderr and \
            "; running opencv mil again" in r.stderr, r.stderr
        row = next(x for x in json.loads(r.stdout)["rows"] if x["tracker"] == "opencv mil")
        assert row["cle_px"] is not None and row["fps"] > 0, row
        assert damaged.read_text() != text and json.loads(info.read_text())["fps"] > 0  # written again
        assert damaged.read_text().startswith(good[:5])
