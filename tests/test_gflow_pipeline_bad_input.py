"""Bad input to the G-flow tracker: each gives a clear error, the pipeline goes on, and no NaN
ever leaves the filter."""

from __future__ import annotations


import cv2
import numpy as np
import pytest

from gflow_core.gflow import EllipsoidHead
from gflow_scenes import SYNTH, Cycle, errors, features_msg, plan_for, pose_estimates, render_folder
from pipeline.runtime.graph import GraphError
from pipeline.runtime.inline import run_inline
from pipeline.io.mcap_io import iter_records
from pipeline.io.modelfile import save_model
from gflow_msgs.messages import decode
import cli_fork

FRAMES = 10


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("head") / "frames"
    seq, _ = render_folder(folder, FRAMES)
    return folder, seq


def _finite_outputs(path) -> bool:
    """Every PoseEstimate and ExpertStates array and number in a recording is finite."""
    for r in iter_records(path):
        if r.type == "PoseEstimate":
            m = decode(r.data)
            arrs = [m.expert_points.array(), m.mean_points.array(), m.log_credibility.array(),
                    np.array(m.box + m.pose + m.pose_std + m.rotation + (m.spread_px, m.ess))]
        elif r.type == "ExpertStates":
            m = decode(r.data)
            arrs = [m.poses.array(), m.tex_mean.array(), m.tex_var.array(), m.log_credibility.array()]
        else:
            continue
        if not all(np.isfinite(a).all() for a in arrs):
            return False
    return True


def test_initial_box_outside_the_image(scene, tmp_path) -> None:
    folder, _ = scene
    rec = tmp_path / "run.mcap"
    r = run_inline(plan_for(folder, (500, 400, 40, 50), **SYNTH), recording=str(rec))
    assert r.frames == FRAMES and r.steps["preprocess"] == FRAMES  # the stream went on
    errs = [(e.stage, e.kind, e.message) for e in errors(rec)]
    filt = [e for e in errs if e[0] == "filter"]
    assert len(filt) == 1 and filt[0][1] == "init_failed", errs  # said once, not on every frame
    assert "lies outside the 160x120 frame" in filt[0][2]
    assert not pose_estimates(rec)


def test_initial_box_partly_outside_is_clipped(scene, tmp_path) -> None:
    folder, seq = scene
    x, y, w, h = seq.box
    rec = tmp_path / "run.mcap"
    run_inline(plan_for(folder, (x, y - 70, w, h + 70), **SYNTH), recording=str(rec))
    kinds = [(e.stage, e.kind) for e in errors(rec)]
    assert ("filter", "init_box_clipped") in kinds
    est = pose_estimates(rec)
    assert sorted(est) == list(range(FRAMES)) and est[0].box[1] == pytest.approx(-0.5)
    assert _finite_outputs(rec)


def test_zero_size_box_is_refused_before_anything_runs(scene, tmp_path, gflow_cmd) -> None:
    folder, _ = scene
    with pytest.raises(GraphError, match="positive width and height"):
        plan_for(folder, (10, 10, 0, 20), **SYNTH)
    out = cli_fork.run_command([*gflow_cmd, "track", str(folder), "--tracker", "gflow", "--init", "10,10,0,5", "--out",
                                str(tmp_path / "b.csv")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "width and height must be positive" in out.stderr


def test_frames_changing_size_and_missing_frames(scene, tmp_path) -> None:
    folder, seq = scene
    frames = tmp_path / "frames"
    frames.mkdir()
    for t in range(FRAMES):
        img = cv2.imread(str(folder / f"{t:06d}.png"))
        if t in (4, 5):
            img = cv2.resize(img, (200, 150))
        if t != 7:  # frame 7 is missing from the folder
            cv2.imwrite(str(frames / f"{t:06d}.png"), img)
    rec = tmp_path / "run.mcap"
    run_inline(plan_for(frames, seq.box, background=True, **SYNTH), recording=str(rec))
    errs = errors(rec)
    assert any(e.kind == "frame_size_changed" and "frame 4" in e.message for e in errs)
    est = pose_estimates(rec)
    # every frame has an estimate; the filter coasted over those it could not see
    assert sorted(est) == list(range(FRAMES))
    assert [est[t].state for t in range(FRAMES)] == ["init", "track", "track", "track", "coast", "coast", "track",
                                                     "coast", "track", "track"]
    assert {(e.stage, e.kind) for e in errs if e.header.seq == 7} >= {("filter", "missing_features")}
    assert _finite_outputs(rec)


def test_features_of_another_size_reach_the_stages(scene) -> None:
    """When the frame size changes behind the source (e.g. features from a recording), both stages
    say so and the filter coasts."""
    folder, seq = scene
    cyc = Cycle(dict(SYNTH, init=[float(v) for v in seq.box]))
    grey = [cv2.imread(str(folder / f"{t:06d}.png"), cv2.IMREAD_GRAYSCALE) for t in range(4)]
    cyc.step(0, features_msg(grey[0], 0))
    cyc.step(1, features_msg(grey[1], 1))
    out = cyc.step(2, features_msg(cv2.resize(grey[2], (80, 60)), 2))
    assert decode(out["estimate"]).state == "coast"
    reports = cyc.proposal.drain_reports() + cyc.filter.drain_reports()
    assert any(k == "bad_features" and "differs from the 160x120 frames" in m for k, m, _ in reports), reports
    assert decode(cyc.step(3, features_msg(grey[3], 3))["estimate"]).state == "track"


def test_black_and_saturated_frames_give_no_nan(scene, tmp_path) -> None:
    folder, seq = scene
    frames = tmp_path / "frames"
    frames.mkdir()
    for t in range(FRAMES):
        img = cv2.imread(str(folder / f"{t:06d}.png"))
        if t in (3, 4):
            img[:] = 0
        elif t in (5, 6):
            img[:] = 255
        cv2.imwrite(str(frames / f"{t:06d}.png"), img)
    for bg in (False, True):
        rec = tmp_path / f"run{bg}.mcap"
        run_inline(plan_for(frames, seq.box, background=bg, **SYNTH), recording=str(rec))
        est = pose_estimates(rec)
        assert sorted(est) == list(range(FRAMES)) and _finite_outputs(rec)
        # a uniform frame says nothing about the pose: the filter coasts over it and says why
        assert [est[t].state for t in range(3, 8)] == ["coast"] * 4 + ["track"]
        msgs = [e.message for e in errors(rec) if e.stage == "filter"]
        assert any("every pixel is 0" in m for m in msgs) and any("every pixel is 255" in m for m in msgs)
        assert not [e for e in errors(rec) if e.kind == "stage_exception"]


def test_model_files(scene, tmp_path, gflow_cmd) -> None:
    folder, seq = scene
    init = ",".join(f"{v:.2f}" for v in seq.box)
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(b"PK\x03\x04 this is not a model")
    out = cli_fork.run_command([*gflow_cmd, "track", str(folder), "--tracker", "gflow", "--init", init, "--model",
                                str(bad), "--out", str(tmp_path / "b.csv")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert str(bad) in out.stderr and "not a readable model file" in out.stderr, out.stderr
    # a good user model file (here: the generic head, 7 x 5 vertices) is placed in the box and tracked
    good = save_model(tmp_path / "head.npz", EllipsoidHead(n_lon=7, n_lat=5).model())
    rec = tmp_path / "run.mcap"
    run_inline(plan_for(folder, seq.box, **dict(SYNTH, model=str(good))), recording=str(rec))
    est = pose_estimates(rec)
    assert sorted(est) == list(range(FRAMES)) and est[FRAMES - 1].mean_points.array().shape == (35, 2)
    assert est[FRAMES - 1].state == "track" and _finite_outputs(rec)


def test_proposal_and_filter_with_different_parameters(scene, tmp_path) -> None:
    """The graph's tracker block gives every stage the same parameters, so a G-flow parameter given to
    one stage is refused; a graph that names them per stage (written before the block) can still make
    them differ, and the digest the messages carry catches it."""
    from pipeline.runtime.graph import GRAPHS_DIR, parse_graph

    folder, seq = scene
    with pytest.raises(GraphError, match="set tracker.psi_v"):
        plan_for(folder, seq.box, filter_extra={"psi_v": 1e-3}, **dict(SYNTH, psi_v=1e-5))
    shared = dict(SYNTH, psi_v=1e-5, init=[float(v) for v in seq.box])
    text = (GRAPHS_DIR / "gflow.yaml").read_text().replace("\ntracker: gflow", "\n#")
    plan = parse_graph(text, "per-stage.yaml", overrides={"source": {"kind": "folder", "path": str(folder)},
                                                          "proposal": shared, "filter": dict(shared, psi_v=1e-3)})
    assert plan.tracker is None
    rec = tmp_path / "run.mcap"
    run_inline(plan, recording=str(rec))
    msgs = [e.message for e in errors(rec) if e.stage == "filter"]
    assert msgs and all("another G-flow configuration" in m for m in msgs)
    est = pose_estimates(rec)
    assert sorted(est) == list(range(FRAMES)) and {est[t].state for t in range(1, FRAMES)} == {"coast"}
