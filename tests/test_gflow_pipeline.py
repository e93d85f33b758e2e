"""G-flow inside the pipeline (inline): it is exactly the core algorithm, shards change nothing,
snapshots resume bit for bit, and it tracks a rendered head with known 3-D pose."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from gflow_core import colour
from gflow_core.gflow import fit_head_model_to_box, init_state, step
from gflow_core.gflow.geometry import TRANS, project, rotation_angle_deg
from gflow_core.gflow.head_model import bounding_box
from gflow_scenes import SYNTH, Cycle, features_msg, payloads, plan_for, pose_estimates, render_folder
from pipeline.runtime.inline import run_inline
from gflow_core.gflow import GFlowParams
from stages.base import StageContext
from stages.gflow_filter import GFlowFilterParams, GFlowFilterStage
from stages.gflow_proposal import GFlowProposalParams, GFlowProposalStage
from gflow_msgs.messages import ColourFeatures, NDArray
from gflow_msgs.snapshots import GFlowProposalSnapshot
from gflow_msgs.params import tracker_params
from gflow_core.tracker import stream_hash

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
    params_ = tracker_params(msgspec.convert(plan.stage_params("filter"), GFlowFilterParams), GFlowParams)
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


def test_a_restart_mid_stream_with_the_online_guard_continues_as_the_straight_run(scene) -> None:
    """The online guard's model of the face travels in the filter's snapshot: restored mid-stream, the run
    goes on bit for bit (its cue weighs the experts' samples, so a model started afresh would not), and a
    version-2 snapshot, made before the model was kept, restores with the model started afresh."""
    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    params = dict(SYNTH, seed=4, init=[float(v) for v in seq.box], online_guard=True, online_cue=30.0)
    straight = Cycle(params)
    want = [straight.step(t, features_msg(grey[t], t)) for t in range(FRAMES)]
    resumed = Cycle(params)
    got = []
    for t in range(FRAMES):
        if t in (2, 9):
            before = resumed.filter.state.online
            resumed.restart_from_snapshots()
            after = resumed.filter.state.online
            assert after is not None and after.learnt == before.learnt and after.centre == before.centre
            assert np.array_equal(after.model.det, before.model.det)
        got.append(resumed.step(t, features_msg(grey[t], t)))
    assert got == want
    # a version-2 snapshot has no online model: restored, it starts afresh on the next frame
    old = msgspec.msgpack.decode(resumed.filter.snapshot())
    assert old["online"] is not None and old["version"] == 3
    old = {k: v for k, v in old.items() if not k.startswith("online")}
    resumed.filter.restore(msgspec.msgpack.encode(dict(old, version=2)))
    assert resumed.filter.state.online is None and resumed.filter.state.anchor is not None
    resumed.step(FRAMES - 1, features_msg(grey[FRAMES - 1], FRAMES - 1))
    assert resumed.filter.state.online is not None
    # a damaged model is refused in one line
    bad = msgspec.msgpack.decode(straight.filter.snapshot())
    bad["online_values"]["parts"][0][1] = [3, 3, 3]
    with pytest.raises(ValueError, match="bad gflow.filter snapshot: online model") as e:
        Cycle(params).filter.restore(msgspec.msgpack.encode(bad))
    assert "\n" not in str(e.value)


def test_the_mixture_proposal_acts_and_a_restart_continues_as_the_straight_run(scene) -> None:
    """With ``online_mix`` the filter draws a share of the samples about the online model's place of the face
    (its own random stream): the run differs from the one without, and restored mid-stream from the
    snapshots it goes on bit for bit (the filter's draws depend on the frame alone)."""
    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    base = dict(SYNTH, seed=4, init=[float(v) for v in seq.box], online_guard=True)
    plain = Cycle(base)
    without = [plain.step(t, features_msg(grey[t], t)) for t in range(FRAMES)]
    params = dict(base, online_mix=0.25)
    straight = Cycle(params)
    want = [straight.step(t, features_msg(grey[t], t)) for t in range(FRAMES)]
    assert want[0] == without[0] and want[1:] != without[1:]
    resumed = Cycle(params)
    got = []
    for t in range(FRAMES):
        if t in (3, 10):
            resumed.restart_from_snapshots()
        got.append(resumed.step(t, features_msg(grey[t], t)))
    assert got == want


def test_without_the_online_guard_the_snapshot_is_version_2_as_before(scene) -> None:
    """Without the online guard's model the filter writes the version-2 snapshot, without version 3's two
    fields, so the snapshots of a run recorded before version 3 are re-made byte for byte by a re-run
    (``gflow rerun --check`` compares them); it restores and the run goes on as the straight one."""
    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    params = dict(SYNTH, seed=4, init=[float(v) for v in seq.box])
    straight = Cycle(params)
    want = [straight.step(t, features_msg(grey[t], t)) for t in range(FRAMES)]
    snap = msgspec.msgpack.decode(straight.filter.snapshot())
    assert snap["version"] == 2 and not any(k.startswith("online") for k in snap)
    resumed = Cycle(params)
    got = []
    for t in range(FRAMES):
        if t == 5:
            resumed.restart_from_snapshots()
        got.append(resumed.step(t, features_msg(grey[t], t)))
    assert got == want


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

    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    params = dict(SYNTH, n_experts=24, background=True, seed=4, init=[float(v) for v in seq.box])
    cyc = Cycle(params)
    for t in range(8):
        cyc.step(t, features_msg(grey[t], t))
    snap = cyc.proposal.snapshot()
    dense = 2 * 24 * grey[0].size * 8
    assert len(snap) < dense / 4, (len(snap), dense)
    s = msgspec.msgpack.decode(snap, type=GFlowProposalSnapshot)
    bad = msgspec.structs.replace(s, bg_table=type(s.bg_table).of(np.full((24, 80), 10**6, np.int32)))
    with pytest.raises(ValueError, match="tile ids|do not fit"):
        Cycle(params).proposal.restore(msgspec.msgpack.encode(bad))


def _colour_features(grey: np.ndarray, seq: int, bins: np.ndarray | None = None) -> ColourFeatures:
    """Features of a colour frame made from ``grey`` (H, W), with its bins (or ``bins``)."""
    if bins is None:
        bins = colour.bins(np.dstack([grey, np.roll(grey, 7, axis=1), 255 - grey]))
    f = features_msg(grey, seq)
    return ColourFeatures(f.header, f.grey, f.edges, f.chamfer, f.profile, f.g0, bins=NDArray.of(bins))


def test_the_lost_guard_reads_colour_bins_survives_a_restart_and_reports_bad_bins(scene) -> None:
    """The filter's lost guard takes the colour bins of ColourFeatures (the preprocess stage's
    ``colour``): its anchor keeps the first box's histogram across a snapshot, a version-1 snapshot
    (before the guard) restores with the guard off, and bins of the wrong size are reported while
    tracking goes on."""
    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    params = dict(SYNTH, seed=4, init=[float(v) for v in seq.box])
    cyc = Cycle(params)
    for t in range(4):
        cyc.step(t, _colour_features(grey[t], t))
    st = cyc.filter.state
    assert st.anchor is not None and st.anchor.colour is not None and st.lost.ctarget.n == 3
    snap = cyc.filter.snapshot()
    cyc.restart_from_snapshots()
    again = cyc.filter.state
    assert np.array_equal(again.anchor.colour, st.anchor.colour) and again.lost == st.lost
    assert again.fit_level == st.fit_level and again.look_clutter == st.look_clutter
    # a version-1 snapshot has no guard fields: restored, the guard is off for the rest of the run
    old = msgspec.msgpack.decode(snap)
    old = {k: v for k, v in old.items() if not k.startswith(("anchor", "lost_", "held", "fit_"))}
    old["version"] = 1
    cyc.filter.restore(msgspec.msgpack.encode(old))
    assert cyc.filter.state.anchor is None
    out = cyc.step(4, _colour_features(grey[4], 4))
    assert msgspec.msgpack.decode(out["estimate"])["target_state"] == "tracked"
    # bins of another size than the grey image: reported, the frame is tracked on the edges alone
    fresh = Cycle(params)
    fresh.step(0, _colour_features(grey[0], 0))
    fresh.step(1, _colour_features(grey[1], 1, np.zeros((5, 5), np.uint8)))
    kinds = [k for k, _, _ in fresh.filter.drain_reports()]
    assert kinds == ["bad_features"] and fresh.filter.state.lost.found == 1


def test_a_live_step_of_several_periods_travels_with_the_proposals(scene) -> None:
    """With host stamps (a live source) the proposal stage measures the time since the experts' frame
    in nominal periods and the proposals carry it to the filter, which predicts the texels over the
    same periods; proposals claiming a step shorter than a period are refused and the filter coasts."""
    _, seq, frames = scene
    grey = np.rint(frames * 255).astype(np.uint8)
    params = dict(SYNTH, seed=4, init=[float(v) for v in seq.box])
    live = {"frame_period_ns": 40e6}  # 25 frames/s
    prop = GFlowProposalStage(msgspec.convert(params, GFlowProposalParams), StageContext("proposal", "t", **live))
    filt = GFlowFilterStage(msgspec.convert(params, GFlowFilterParams), StageContext("filter", "t", **live))
    t0 = 1_700_000_000_000_000_000
    stamps = [t0, t0 + 40_000_000, t0 + 160_000_000]  # frame 2 was taken 3 periods after frame 1
    state, steps = None, []
    for t, stamp in enumerate(stamps):
        f = features_msg(grey[t], t)
        feat = msgspec.structs.replace(f, header=msgspec.structs.replace(f.header, stamp_ns=stamp))
        props = dict(prop.step(t, {"features": feat, "state": state})).get("proposals")
        if props is not None:
            steps.append(props.dt)
        out = dict(filt.step(t, {"features": feat, "proposals0": props}))
        state = out["state"]
        assert out["estimate"].state in ("init", "track")
    assert steps == [1.0, 3.0]
    bad = msgspec.structs.replace(props, dt=0.5)
    out = dict(filt.step(3, {"features": features_msg(grey[3], 3), "proposals0": bad}))
    assert out["estimate"].state == "coast"
    assert [k for k, _, _ in filt.drain_reports()] == ["bad_proposals"]
