"""G-flow's lost guard (gflow_core.gflow.guard): re-seating the experts on a re-detected box, the
first-look fit that confirms it (tests/test_real_tracking.py has it on caviar1's real frames)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.gflow import GFlowParams, fit_head_model_to_box, init_state
from gflow_core.gflow import guard
from gflow_core.gflow.face_pose import following_box
from gflow_core.gflow.geometry import project
from gflow_core.gflow.head_model import bounding_box
from gflow_core.gflow.synthetic_head import synthetic_sequence


@pytest.fixture(scope="module")
def head():
    seq = synthetic_sequence(np.random.default_rng(3), 3, (120, 160))
    model, pose0 = fit_head_model_to_box(seq.box, seq.frames.shape[1:])
    return seq, model, pose0


def test_reseat_pose_puts_both_boxes_of_gflow_on_the_target_box(head) -> None:
    _, model, pose0 = head
    held = bounding_box(project(model.bases, pose0))
    target = (37.0, 21.5, held[2] * 1.3, held[3] * 1.3)
    u = guard.reseat_pose(pose0, tuple(held), target)
    # the projected vertices' box
    assert np.allclose(bounding_box(project(model.bases, u)), target, atol=1e-9)
    # a learned face's following box (the user's box moved and scaled with the face)
    box0 = np.array([10.0, 12.0, 40.0, 50.0])
    fb = following_box(pose0, pose0, box0)
    u2 = guard.reseat_pose(pose0, tuple(fb), target)
    assert np.allclose(following_box(u2, pose0, box0), target, atol=1e-9)


def test_reseat_reads_the_texels_at_the_new_pose_and_evens_the_credibilities(head) -> None:
    seq, model, pose0 = head
    cfg = GFlowParams(model="", n_experts=4, texture_decay=0.9).config(model, pose0)
    st = init_state(model, pose0, seq.frames[0], cfg)
    moved = pose0.copy()
    moved[3] += 6.0
    new = guard.reseat(st, moved, seq.frames[1], model, cfg)
    assert np.allclose(new.poses, moved[None])
    fresh = init_state(model, moved, seq.frames[1], cfg)
    assert np.array_equal(new.tex_mean, fresh.tex_mean) and np.array_equal(new.tex_var, fresh.tex_var)
    assert np.allclose(np.exp(new.log_credibility), 0.25)
    # the first look is kept: texels still revert toward the first frame's
    assert np.array_equal(new.tex_anchor, st.tex_anchor)


def test_the_first_look_fits_the_target_better_than_a_place_beside_it(head) -> None:
    seq, model, pose0 = head
    cfg = GFlowParams(model="", n_experts=4, texture_decay=0.9).config(model, pose0)
    st = init_state(model, pose0, seq.frames[0], cfg)
    fit = guard.first_look_fit(st, seq.frames[0], model, cfg)
    beside = pose0.copy()
    beside[3] += 40.0
    assert fit(pose0) > 0.95 and fit(beside) < fit(pose0) - 0.03
