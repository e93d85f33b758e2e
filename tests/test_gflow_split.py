"""G-flow split across processes (gflow_core.gflow.split): the proposal stage's background replica
advances, restarts and predicts as the one-process tracker's backgrounds do, survives its snapshot
form, and the stages' snapshots of another version are refused in one line naming it."""

from __future__ import annotations

import dataclasses

import msgspec
import numpy as np
import pytest

from gflow_core.gflow import GFlowParams, model_setup
from gflow_core.gflow.filter import advance_background, initial_background
from gflow_core.gflow.split import (LATER_FIELDS, BackgroundReplica, ProposalShard, check_experts, check_shard,
                                    config_digest, placed, restored_setup, restored_state, shard_indices,
                                    start_filter)
from gflow_core.gflow.state_fields import state_fields, state_of_fields
from gflow_core.gflow.tracker import TRACKER
from gflow_core.tracker import FrameRng
from gflow_core.gflow.synthetic_head import synthetic_sequence
from gflow_scenes import SYNTH, Cycle, features_msg


@pytest.fixture(scope="module")
def head():
    seq = synthetic_sequence(np.random.default_rng(3), n_frames=5, image_shape=(60, 80))
    grey = np.rint(seq.frames * 255).astype(np.uint8)
    params = GFlowParams(**dict(SYNTH, n_experts=6, background=True))
    setup = model_setup(params, seq.box, grey.shape[1:])
    poses = np.repeat(setup.pose0[None], 6, axis=0)
    return setup, grey, poses


def test_the_replica_starts_advances_restarts_and_predicts_as_the_tracker(head) -> None:
    setup, grey, poses = head
    parents = np.array([0, 0, 1, 2, 2, 5], np.int64)
    r, problem = BackgroundReplica().advance(setup, 1, poses, parents, first=True)
    assert r.bg is None and problem is not None and problem[0] == "no_background"  # frame 0 never seen
    r, problem = BackgroundReplica().seen(0, grey[0]).advance(setup, 1, poses, parents, first=True)
    y0, y1 = setup.observation(grey[0]), setup.observation(grey[1])
    want = initial_background(setup.model, poses, y0, setup.cfg)
    assert problem is None and r.seq == 0 and np.array_equal(np.asarray(r.bg[0]), np.asarray(want[0]))
    # the state of frame 1 with frame 1 seen: each child from its parent, updated with y_1 (eq. 7-10)
    r2, problem = r.seen(1, grey[1]).advance(setup, 2, poses, parents, first=False)
    want = advance_background(want[0], want[1], poses, parents, y1, setup.model, setup.cfg)
    assert problem is None and r2.seq == 1
    assert np.array_equal(np.asarray(r2.bg[0]), np.asarray(want[0]))
    assert np.array_equal(np.asarray(r2.bg[1]), np.asarray(want[1]))
    # frame 2 not seen here: prediction only (means of the parents, variances + psi_b)
    r3, problem = r2.advance(setup, 3, poses, parents, first=False)
    assert problem is None and r3.seq == 2
    assert np.array_equal(np.asarray(r3.bg[0]), np.asarray(r2.bg[0])[parents])
    assert np.allclose(np.asarray(r3.bg[1]), np.asarray(r2.bg[1])[parents] + setup.cfg.psi_b)
    # a lost state message (the replica is at frame 0 when the state of frame 3 arrives): restarted
    r4, problem = r.seen(3, grey[3]).advance(setup, 4, poses, parents, first=False)
    assert problem is not None and problem[0] == "background_reset" and r4.seq == 3 and r4.bg is not None
    assert r4.ready(setup) and not BackgroundReplica().ready(setup)
    # without the background terms there is nothing to keep, and proposals need none
    off = dataclasses.replace(setup, cfg=dataclasses.replace(setup.cfg, background=False))
    r5, problem = r.advance(off, 2, poses, parents, first=False)
    assert r5 is r and problem is None and BackgroundReplica().ready(off)


def test_the_replica_survives_its_snapshot_fields_and_refuses_fields_that_do_not_fit(head) -> None:
    setup, grey, poses = head
    r, _ = BackgroundReplica().seen(0, grey[0]).advance(setup, 1, poses, np.arange(6), first=True)
    fields = r.fields()
    assert fields["bg_seq"] == 0 and fields["bg_table"].shape[0] == 6
    assert fields["bg_mean"].nbytes < np.asarray(r.bg[0]).nbytes / 2  # distinct tiles, not (E, H, W)
    back = BackgroundReplica.of_fields(setup, **fields)
    assert np.array_equal(np.asarray(back.bg[0]), np.asarray(r.bg[0])) and back.fields()["prev_seq"] == 0
    assert BackgroundReplica.of_fields(None, **BackgroundReplica().fields()) == BackgroundReplica()
    other = dataclasses.replace(setup, cfg=dataclasses.replace(setup.cfg, n_experts=7))
    with pytest.raises(ValueError, match="6 experts, this stage has 7"):
        BackgroundReplica.of_fields(other, **fields)
    with pytest.raises(ValueError, match="without a frame size"):
        BackgroundReplica.of_fields(None, **fields)


def test_a_proposal_shard_places_proposes_and_survives_its_snapshot_fields(head) -> None:
    """What a proposal process keeps (split.ProposalShard): the model placed on the first usable frame
    as the filter places it, proposals of any partition of the experts concatenating to one shard's bit
    for bit, the replica brought to the experts' frame, and its snapshot fields restoring it."""
    setup, grey, _ = head
    params = GFlowParams(**dict(SYNTH, n_experts=6, background=True))
    box = tuple(float(v) for v in setup.box)
    state, _, digest = start_filter(params, TRACKER.observe_grey(params, grey[0]), box, 1, FrameRng(1, 0, 0))
    experts = {k: getattr(state.experts, k) for k in ("poses", "tex_mean", "tex_var", "log_credibility", "tex_anchor")}
    experts["parents"] = np.arange(6, dtype=np.int64)
    obs, outs = TRACKER.observe_grey(params, grey[1]), []
    for idx in (np.arange(6), np.arange(4), np.arange(4, 6)):
        shard = ProposalShard().started(params, box, 1, 0, grey[0])
        assert shard.digest == digest and shard.init_seq == 0
        shard, props, problems = shard.propose(params, 1, experts, True, obs, FrameRng(1, 0, 1), 1.0, idx)
        assert problems == [] and props is not None and shard.replica.seq == 0
        outs.append(props)
    assert np.array_equal(outs[0].u_hat, np.concatenate([outs[1].u_hat, outs[2].u_hat]))
    assert np.array_equal(outs[0].log_evidence, np.concatenate([outs[1].log_evidence, outs[2].log_evidence]))
    # without the frame: the replica still advances, and there are no proposals
    idle, none, _ = ProposalShard().started(params, box, 1, 0, grey[0]).propose(
        params, 1, experts, True, None, FrameRng(1, 0, 1), 1.0, np.arange(6))
    assert none is None and idle.replica.seq == 0
    fields = shard.fields()
    assert fields["image_shape"] == (60, 80) and fields["digest"] == digest and fields["init_seq"] == 0
    replica = {k: v for k, v in fields.items() if k not in ("image_shape", "digest", "init_seq")}
    back = ProposalShard.of_fields(shard.setup, 0, digest, replica).fields()
    assert back.keys() == fields.keys() and all(
        np.array_equal(v, fields[k]) if isinstance(v, np.ndarray) else v == fields[k] for k, v in back.items())
    assert ProposalShard.of_fields(None, -1, digest, BackgroundReplica().fields()) == ProposalShard()


def test_the_digest_names_the_configuration_and_the_shards_cover_the_experts(head) -> None:
    setup = head[0]
    assert config_digest(setup, 1) == config_digest(setup, 1) != config_digest(setup, 2)
    assert config_digest(dataclasses.replace(setup, contrast_sigma=5.0), 1) != config_digest(setup, 1)
    parts = [shard_indices(10, k, 3) for k in range(3)]
    assert np.array_equal(np.concatenate(parts), np.arange(10)) and [len(p) for p in parts] == [4, 3, 3]
    check_shard(10, 9, 10)
    for shard, shards, why in ((0, 11, "shards must be in \\[1, n_experts=10\\], got 11"), (0, 0, "got 0"),
                               (3, 3, "shard must be in \\[0, shards=3\\), got 3"), (-1, 3, "got -1")):
        with pytest.raises(ValueError, match=why):
            check_shard(10, shard, shards)


def test_every_process_places_the_model_alike_and_refuses_what_is_not_its_own(head) -> None:
    setup, grey, _ = head
    params = GFlowParams(**dict(SYNTH, n_experts=6, background=True))
    box = tuple(float(v) for v in setup.box)
    again, digest = placed(params, box, 1, grey.shape[1:])
    assert np.array_equal(again.pose0, setup.pose0) and digest == config_digest(setup, 1)
    assert restored_setup(params, box, 1, grey.shape[1:], None, digest)[1] == digest
    with pytest.raises(ValueError, match="another G-flow configuration, model or seed"):
        restored_setup(params, box, 2, grey.shape[1:], None, digest)
    with pytest.raises(ValueError, match="lies outside the 80x60 frame"):
        placed(params, (500.0, 500.0, 10.0, 10.0), 1, grey.shape[1:])
    obs = TRACKER.observe_grey(params, grey[0])
    state, est, started = start_filter(params, obs, box, 1, FrameRng(1, 0, 0))
    # the filter process's start: the same placement and digest, and no backgrounds (its proposals keep them)
    assert started == digest and est.phase == "init" and state.experts.bg_mean is None
    with pytest.raises(ValueError, match="another G-flow configuration, model or seed"):
        restored_state(params, box, 2, grey.shape[1:], None, digest, lambda s: {}, {})
    parents = np.arange(6)
    check_experts(setup, (60, 80), parents, setup.cfg.texture_decay != 1.0)
    for shape, par, anchor, why in (((61, 80), parents, False, "for \\(61, 80\\) frames"),
                                    ((60, 80), parents + 1, False, "parents must lie in \\[0, 6\\)"),
                                    ((60, 80), parents, True, "texture anchor is unexpected")):
        with pytest.raises(ValueError, match=why):
            check_experts(setup, shape, par, anchor)


def test_the_filters_posterior_survives_its_snapshot_fields(head) -> None:
    setup, grey, _ = head
    params = GFlowParams(**dict(SYNTH, n_experts=6))
    state, _ = TRACKER.init(params, TRACKER.observe_grey(params, grey[0]), tuple(float(v) for v in setup.box),
                            FrameRng(1, 0, 0), {})
    assert state_fields(None) == {"confidence": 1.0, "target_state": "tracked"}
    fields = state_fields(dataclasses.replace(state, confidence=0.25, target_state="occluded"))
    assert state.anchor is not None and fields["anchor"].shape[2] == 4
    back = state_of_fields(state.setup, state.experts, fields)
    assert (back.confidence, back.target_state) == (0.25, "occluded") and back.lost == state.lost
    assert np.array_equal(back.anchor.channels, state.anchor.channels)
    assert back.anchor.channels is not state.anchor.channels  # a copy: the guard updates its anchor in place
    again = state_fields(back)
    assert again.keys() == fields.keys() and all(
        np.array_equal(fields[k], v) if isinstance(v, np.ndarray) else fields[k] == v for k, v in again.items())
    no_guard = state_of_fields(state.setup, state.experts, {"confidence": 1.0, "target_state": "tracked"})
    assert no_guard.anchor is None  # a snapshot made before the guard: the guard is off
    with pytest.raises(ValueError, match="not \\(th, tw, 4\\)"):
        state_of_fields(state.setup, state.experts, dict(fields, anchor=fields["anchor"][..., :3]))


def test_snapshots_of_another_version_are_refused_in_one_line_naming_it(head) -> None:
    setup, grey, _ = head
    cyc = Cycle(dict(SYNTH, n_experts=6, seed=1, init=[float(v) for v in setup.box]))
    for t in range(2):
        cyc.step(t, features_msg(grey[t], t))
    for stage, old in ((cyc.proposal, 1), (cyc.filter, 4)):
        snap = msgspec.msgpack.decode(stage.snapshot())
        with pytest.raises(ValueError, match=f"snapshot version {old}, expected") as e:
            stage.restore(msgspec.msgpack.encode(dict(snap, version=old)))
        assert "\n" not in str(e.value)


#: the configuration fields every digest made so far covers (recordings carry those digests)
DIGESTED = ("n_experts", "n_samples", "alpha", "gn_iterations", "sigma_w", "psi_v", "psi_b", "v_init_var",
            "b_init_var", "unknown_var", "background", "gn_background", "object_mask", "object_mask_margin",
            "prior_std_rotation", "prior_std_translation", "prior_std_coefficients", "resample_ess_fraction",
            "prior_rotation_decay", "pyramid_levels", "search_radius", "search_step", "photometric",
            "photometric_gain_max", "max_rotation_deg", "search_stride", "outlier_sigmas", "max_scale_change",
            "scale_reference", "morph_prior_std", "texture_decay", "reset_rate", "reset_std_deg", "reset_min_deg",
            "data_temper", "generic_background")


def test_a_configuration_field_added_later_leaves_the_digest_of_older_recordings_alone(head) -> None:
    """A new G-flow configuration field must be one of LATER_FIELDS: at its default it stays out of
    the digest every message carries, so recordings made before it re-run bit for bit."""
    from gflow_core.gflow.filter import GFlowConfig

    new = [f.name for f in dataclasses.fields(GFlowConfig) if f.name not in DIGESTED]
    assert sorted(new) == sorted(LATER_FIELDS), f"register {set(new) - set(LATER_FIELDS)} in LATER_FIELDS"
    for name, default in LATER_FIELDS.items():
        # a recording from before the field: the field at the default it had then (today's may differ)
        setup = dataclasses.replace(head[0], cfg=dataclasses.replace(head[0].cfg, **{name: default}))
        away = (not default) if isinstance(default, bool) else default + 1
        moved = dataclasses.replace(setup, cfg=dataclasses.replace(setup.cfg, **{name: away}))
        assert config_digest(moved, 1) != config_digest(setup, 1)
