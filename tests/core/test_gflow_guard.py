"""G-flow's lost guard (gflow_core.gflow.guard): re-seating the experts on a re-detected box at the
pose where the first look fits it, the first-look fit that confirms it, and the experts kept near
the held box while the target is held (tests/test_real_tracking.py has it on caviar1's real frames)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gflow_core.gflow import GFlowParams, fit_head_model_to_box, init_state
from gflow_core.gflow import guard
from gflow_core.gflow.geometry import rotation_angle_deg
from gflow_core.gflow.image import frame_pyramid, prepare_frame
from gflow_core.gflow.tracker import TRACKER, GFlowState, model_setup
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


def test_a_plain_patch_has_no_fit_to_the_first_look(head) -> None:
    """The fit is a correlation: a flat wall explains the texels of a contrast-normalised face within
    their spread, and still does not fit them."""
    seq, model, pose0 = head
    cfg = GFlowParams(model="", n_experts=4, texture_decay=0.9).config(model, pose0)
    st = init_state(model, pose0, seq.frames[0], cfg)
    flat = np.full_like(seq.frames[0], 0.5)
    flat[:, :3] = 0.2  # not uniform (a uniform frame is unusable), but flat under the head
    assert guard.first_look_fit(st, flat, model, cfg)(pose0) == 0.0
    far = pose0.copy()
    far[3] += 1e4  # every vertex outside the image
    assert guard.first_look_fit(st, seq.frames[0], model, cfg)(far) == 0.0


def test_settle_puts_a_box_sized_guess_back_on_the_face(head) -> None:
    """A re-detection gives a box; the first frame's pose placed in a box a few pixels off and tilted
    settles where the first look fits the frame: back on the head's true pose."""
    seq, model, pose0 = head
    cfg = GFlowParams(model="", n_experts=4, texture_decay=0.9).config(model, pose0)
    st = init_state(model, pose0, seq.frames[0], cfg)
    guess = pose0.copy()
    guess[3:5] += (7.0, -5.0)
    guess[:3] = (0.0, 0.0, np.radians(12.0))
    pyramid = frame_pyramid(prepare_frame(seq.frames[0]), cfg.pyramid_levels)
    u = guard.settle(guess, pyramid, st, model, cfg)
    err = lambda v: np.abs(project(model.bases, v) - project(model.bases, pose0)).max()  # noqa: E731
    assert err(guess) > 6.0 and err(u) < 1.0
    assert rotation_angle_deg(guess, pose0) == pytest.approx(12.0) and rotation_angle_deg(u, pose0) < 4.0


def test_the_experts_are_kept_near_the_held_box_while_the_target_is_held(head) -> None:
    seq, model, pose0 = head
    params = GFlowParams(model="", n_experts=3, lost_hold=1.0)
    setup = model_setup(params, seq.box, seq.frames.shape[1:])
    st = init_state(setup.model, setup.pose0, seq.frames[0], setup.cfg)
    poses = np.array(st.poses)
    poses[:, 3] += (0.0, 30.0, 500.0)  # on the box, near it, far away
    poses.setflags(write=False)
    st = dataclasses.replace(st, poses=poses)
    held = tuple(float(v) for v in bounding_box(project(setup.model.bases, setup.pose0)))
    kept = TRACKER._hold(setup, st, held, params.lost_hold)
    centres = np.array([bounding_box(p)[:2] + 0.5 * bounding_box(p)[2:] for p in project(setup.model.bases, kept.poses)])
    hc = np.array(held[:2]) + 0.5 * np.array(held[2:])
    assert np.array_equal(kept.poses[:2], st.poses[:2])  # within reach: unchanged
    assert centres[2, 0] == pytest.approx(hc[0] + held[2], abs=1e-9)  # the far one at the edge of reach
    assert np.array_equal(kept.poses[2, 5:], st.poses[2, 5:]) and np.array_equal(kept.tex_mean, st.tex_mean)
    with pytest.raises(ValueError, match="lost_hold"):
        GFlowParams(lost_hold=-1.0)
