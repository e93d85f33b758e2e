"""The rules G-flow's pipeline stages take from the tracker rather than writing them: a failed update
coasts (``GFlowTracker.update_or_coast``), a frame's colour bins join its observation only when the
tracker reads colour (``with_bins``), the travelling arrays' dimensions (``split.message_dims``); and
the stages' own reports of a frame of another size, with what each does then."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gflow_core.gflow import GFlowParams
from gflow_core.gflow.split import message_dims
from gflow_core.gflow.synthetic_head import synthetic_sequence
from gflow_core.gflow.tracker import TRACKER, GFlowTracker
from gflow_core.tracker import FrameRng
from gflow_msgs.messages import decode
from gflow_scenes import SYNTH, Cycle, features_msg


@pytest.fixture(scope="module")
def head():
    seq = synthetic_sequence(np.random.default_rng(3), n_frames=3, image_shape=(60, 80))
    grey = np.rint(seq.frames * 255).astype(np.uint8)
    params = GFlowParams(**dict(SYNTH, n_experts=6))
    state, _ = TRACKER.init(params, TRACKER.observe_grey(params, grey[0]), tuple(float(v) for v in seq.box),
                            FrameRng(1, 0, 0), {})
    return params, grey, state, seq.box


def test_an_update_with_evidence_is_the_update_and_one_without_or_failing_coasts(head, monkeypatch) -> None:
    params, grey, state, _ = head
    obs = TRACKER.observe_grey(params, grey[1])
    props = TRACKER.propose(params, state, obs, FrameRng(1, 0, 1))
    new, est, failure = TRACKER.update_or_coast(params, state, props, obs, FrameRng(1, 0, 1))
    want, want_est = TRACKER.update(params, state, props, obs, FrameRng(1, 0, 1))
    assert failure is None and est.phase != "coast" and est.box == want_est.box
    assert np.array_equal(new.experts.poses, want.experts.poses)
    coasted, _ = TRACKER.coast(params, state, FrameRng(1, 0, 1), obs)
    for p, o in ((None, obs), (props, None)):  # no proposals, no frame: coasting, nothing failed
        new, est, failure = TRACKER.update_or_coast(params, state, p, o, FrameRng(1, 0, 1))
        want, _ = TRACKER.coast(params, state, FrameRng(1, 0, 1), o)
        assert failure is None and est.phase == "coast"
        assert np.array_equal(new.experts.tex_var, want.experts.tex_var)
        assert np.array_equal(new.experts.poses, state.experts.poses)

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(GFlowTracker, "update", singular)
    new, est, failure = TRACKER.update_or_coast(params, state, props, obs, FrameRng(1, 0, 1))
    assert failure == "LinAlgError: Singular matrix" and est.phase == "coast"
    assert np.array_equal(new.experts.tex_var, coasted.experts.tex_var)


def test_colour_bins_join_the_observation_only_when_the_tracker_reads_colour(head) -> None:
    params, grey, _, _ = head
    obs = TRACKER.observe_grey(params, grey[0])
    bins = np.ones(grey[0].shape, np.uint8)
    for guard, colour, joins in ((True, True, True), (True, False, False), (False, True, False)):
        p = dataclasses.replace(params, lost_guard=guard, lost_colour=colour)
        out = TRACKER.with_bins(p, obs, bins)
        assert (out.bins is bins) == joins and (out is obs) != joins
    assert TRACKER.with_bins(dataclasses.replace(params, lost_guard=True, lost_colour=True), obs, None) is obs


def test_the_travelling_arrays_dimensions_are_the_setups(head) -> None:
    params, _, state, _ = head
    s = state.setup
    assert message_dims(s) == {"E": 6, "P": s.model.pose_size, "n": s.model.n_vertices, "s": params.n_samples}


def test_a_frame_of_another_size_is_reported_and_each_stage_does_without_it(head) -> None:
    params, grey, _, box = head
    cyc = Cycle(dict(SYNTH, n_experts=6, seed=1, init=[float(v) for v in box]))
    cyc.step(0, features_msg(grey[0], 0))
    cyc.step(1, features_msg(grey[1], 1))
    cyc.proposal.drain_reports(), cyc.filter.drain_reports()
    out = cyc.step(2, features_msg(np.ascontiguousarray(grey[2][:, :70]), 2))
    said = "size 70x60 differs from the 80x60 frames the tracker started on; frame skipped"
    assert cyc.proposal.drain_reports() == [("bad_features", f"frame 2: {said}; no proposals for this frame", 2)]
    reports = cyc.filter.drain_reports()
    assert reports == [("bad_features", f"frame 2: {said}; coasting", 2)]
    assert decode(out["estimate"]).state == "coast" and cyc.filter.coasted == 1
