"""G-flow inside the pipeline (inline): it is exactly the core algorithm, shards change nothing,
snapshots resume bit for bit, and it tracks a rendered head with known 3-D pose."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from gflow_core.gflow import fit_head_model_to_box, init_state, step
from gflow_core.gflow.geometry import TRANS, project, rotation_angle_deg
from gflow_core.gflow.head_model import bounding_box
from gflow_scenes import SYNTH, Cycle, features_msg, payloads, plan_for, pose_estimates, render_folder
from pipeline.runtime.inline import run_inline
from gflow_core.gflow import GFlowParams
from stages.gflow_filter import GFlowFilterParams
from stages.tracker_params import tracker_params
from stages.rng import stream_hash

FRAMES = 16


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("head") / "frames"
    seq, frames = render_folder(folder, FRAMES)
    return folder, seq, frames


def test_inline_pipeline_is_the_core_filter_bit_for_bit(scene, tmp_path) -> None:
    """Backgrounds replicated in the proposal stage, states over messages: the same numbers as
    gflow_core.gflow.step in a loop (which keeps the backgrounds in its own state)."""
    folder, seq, frames = scene
    params = dict(SYNTH, background=True, seed=5)
    plan = plan_for(folder, seq.box, **params)
    run_inline(plan, recording=str(tmp_path / "run.mcap"))
    est = pose_estimates(tmp_path / "run.mcap")
    assert sorted(est) == list(range(FRAMES))
    params_ = tracker_params(msgspec.convert(plan.stages["filter"].params, GFlowFilterParams), GFlowParams)
    model, pose0 = fit_head_model_to_box(seq.box, frames.shape[1:])
    cfg = params_.config(model, pose0)
    state = init_state(model, pose0, frames[0], cfg)
    assert est[0].state == "init" and np.allclose(est[0].box, bounding_box(project(model.bases, pose0)))
    for t in range(1, FRAMES):
        state, e = step(state, frames[t], model, cfg, seed=5, t=t, stream_hash=stream_hash(plan.stream))
        assert est[t].state == "track"
        assert est[t].pose == tuple(e.pose) and est[t].box == tuple(e.bbox), f"frame {t} differs"
        assert np.array_equal(est[t].expert_points.array(), e.expert_points.astype(np.float32))


def test_two_shards_equal_one_bit_for_bit(scene, tmp_path) -> None:
    folder, seq, _ = scene
    params = dict(SYNTH, background=True, seed=2)
    one, two = tmp_path / "one.mcap", tmp_path / "two.mcap"
    run_inline(plan_for(folder, seq.box, shards=1, **params), recording=str(one))
    plan2 = plan_for(folder, seq.box, shards=2, **params)
    assert {"proposal0", "proposal1"} <= set(plan2.stages) and "proposal" not in plan2.stages
    run_inline(plan2, recording=str(two))
    a, b = payloads(one), payloads(two)
    assert len(a) == 2 * FRAMES and a == b


def test_snapshot_restore_then_continue_equals_a_straight_run(scene) -> None:
    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    params = dict(SYNTH, background=True, seed=4, init=[float(v) for v in seq.box])
    jitter = {"init_jitter": (0.02, 1.0, 0.01)}
    straight = Cycle(params, filter_extra=jitter)
    want = [straight.step(t, features_msg(grey[t], t)) for t in range(FRAMES)]
    resumed = Cycle(params, filter_extra=jitter)
    got = []
    for t in range(FRAMES):
        if t in (1, 7):  # just after the first frame, and mid-stream with a replica of the backgrounds
            resumed.restart_from_snapshots()
        got.append(resumed.step(t, features_msg(grey[t], t)))
    assert got == want
    # a snapshot is msgpack of a struct, not pickle, and says what it is when it is not one
    with pytest.raises(ValueError, match="not a gflow.filter snapshot"):
        Cycle(params).filter.restore(b"\x80\x04garbage")


def test_tracks_a_rendered_head_with_known_pose(tmp_path) -> None:
    """30 frames of 160x120: a textured head turning by up to (10, 20, 8) degrees and moving
    (15, 8) px, its texture drifting, with noise, then quantised to 8 bits by the PNG files."""
    seq, _ = render_folder(tmp_path / "frames", 30)
    plan = plan_for(tmp_path / "frames", seq.box, **dict(SYNTH, seed=3))
    run_inline(plan, recording=str(tmp_path / "run.mcap"))
    est = pose_estimates(tmp_path / "run.mcap")
    assert sorted(est) == list(range(30))
    rot = np.array([rotation_angle_deg(np.array(est[t].pose), seq.poses[t]) for t in range(1, 30)])
    px = np.array([np.linalg.norm(np.array(est[t].pose)[TRANS] - seq.poses[t][TRANS]) for t in range(1, 30)])
    still_rot = np.array([rotation_angle_deg(seq.poses[0], seq.poses[t]) for t in range(1, 30)])
    still_px = np.array([np.linalg.norm(seq.poses[0][TRANS] - seq.poses[t][TRANS]) for t in range(1, 30)])
    print(f"\nG-flow pipeline, 10 experts: rotation error mean {rot.mean():.2f} max {rot.max():.2f} deg; "
          f"translation error mean {px.mean():.2f} max {px.max():.2f} px "
          f"(standing still: {still_rot.mean():.1f} deg, {still_px.mean():.1f} px)")
    assert rot.mean() < 6.0 and rot.max() < 12.0 and px.mean() < 1.5 and px.max() < 3.0
    assert still_rot.mean() > 2 * 6.0 and still_px.mean() > 4 * 1.5  # the bounds do reject a tracker that sits still


def test_the_proposal_snapshot_holds_its_background_replica_compactly(scene) -> None:
    """The proposal stage snapshots after every frame (for a restart); its background replica is
    stored as distinct tiles, a fraction of the dense (E, H, W) float64 arrays, and a snapshot
    whose tile table is damaged is refused with a one-line reason."""
    from stages import gflow_proposal

    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    params = dict(SYNTH, n_experts=24, background=True, seed=4, init=[float(v) for v in seq.box])
    cyc = Cycle(params)
    for t in range(8):
        cyc.step(t, features_msg(grey[t], t))
    snap = cyc.proposal.snapshot()
    dense = 2 * 24 * grey[0].size * 8
    assert len(snap) < dense / 4, (len(snap), dense)
    s = msgspec.msgpack.decode(snap, type=gflow_proposal._Snapshot)
    bad = msgspec.structs.replace(s, bg_table=type(s.bg_table).of(np.full((24, 80), 10**6, np.int32)))
    with pytest.raises(ValueError, match="tile ids|do not fit"):
        Cycle(params).proposal.restore(msgspec.msgpack.encode(bad))
