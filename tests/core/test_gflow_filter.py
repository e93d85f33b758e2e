"""The G-flow filter API: configuration, sharded proposals, determinism, bad input, NaN safety."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gflow_core.gflow import (
    paper_config,
    concatenate_proposals,
    expert_rngs,
    fit_head_model_to_box,
    init_state,
    propose,
    step,
    update,
)
from gflow_core.gflow.synthetic_head import synthetic_sequence


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(np.random.default_rng(5), 4, (60, 80), rot_amp_deg=(4, 6, 3), trans_amp_px=(4, 2))


@pytest.fixture(scope="module")
def model_pose(seq):
    return fit_head_model_to_box(seq.box, seq.frames.shape[1:])


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        (dict(n_experts=0), "n_experts"),
        (dict(n_samples=2.5), "n_samples"),
        (dict(gn_iterations=-1), "gn_iterations"),
        (dict(alpha=-0.1), "alpha"),
        (dict(sigma_w=0.0), "sigma_w"),
        (dict(psi_v=np.inf), "psi_v"),
        (dict(psi_b=-1.0), "psi_b"),
        (dict(v_init_var=np.nan), "v_init_var"),
        (dict(unknown_var=0.0), "unknown_var"),
        (dict(background="yes"), "background"),
        (dict(gn_background=1), "gn_background"),
        (dict(object_mask="box"), "object_mask"),
        (dict(object_mask_margin=-0.1), "object_mask_margin"),
        (dict(prior_std_rotation=(0.1, 0.1)), "prior_std_rotation"),
        (dict(prior_std_translation=0.0), "prior_std_translation"),
        (dict(prior_std_coefficients=np.nan), "prior_std_coefficients"),
        (dict(resample_ess_fraction=0.0), "resample_ess_fraction"),
    ],
)
def test_config_validation(kw, match) -> None:
    with pytest.raises(ValueError, match=match):
        paper_config(**kw)


def test_prior_std_follows_the_pose_layout() -> None:
    cfg = paper_config(prior_std_rotation=(0.1, 0.2, 0.3), prior_std_translation=4.0, prior_std_coefficients=(1.0, 2.0))
    np.testing.assert_array_equal(cfg.prior_std(2), [0.1, 0.2, 0.3, 4.0, 4.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="k=3"):
        cfg.prior_std(3)
    assert dataclasses.replace(cfg, n_experts=3).prior_std_rotation == (0.1, 0.2, 0.3)


@pytest.mark.parametrize("background", [False, True])
def test_sharded_proposals_equal_unsharded_bit_for_bit(seq, model_pose, background: bool) -> None:
    model, pose0 = model_pose
    cfg = paper_config(n_experts=7, n_samples=5, background=background)
    state = init_state(model, pose0, seq.frames[0], cfg, rng=np.random.default_rng(3), pose_jitter_std=0.05)
    full = propose(state, seq.frames[1], model, cfg, expert_rngs(11, 22, 1, range(7)))
    shards = ([4, 0, 6], [1], [2, 3, 5])
    parts = [propose(state, seq.frames[1], model, cfg, expert_rngs(11, 22, 1, s), expert_indices=s) for s in shards]
    joined = concatenate_proposals(parts)
    for f in dataclasses.fields(full):
        np.testing.assert_array_equal(getattr(joined, f.name), getattr(full, f.name), err_msg=f.name)
    s1, e1 = update(state, full, seq.frames[1], model, cfg, np.random.default_rng(9))
    s2, e2 = update(state, joined, seq.frames[1], model, cfg, np.random.default_rng(9))
    np.testing.assert_array_equal(s1.poses, s2.poses)
    np.testing.assert_array_equal(e1.pose, e2.pose)


def test_same_seed_same_result_and_inputs_are_not_modified(seq, model_pose) -> None:
    model, pose0 = model_pose
    cfg = paper_config(n_experts=5, n_samples=4, background=True)
    state = init_state(model, pose0, seq.frames[0], cfg)
    before = np.asarray(state.bg_mean), state.tex_mean.copy(), state.poses.copy()
    a = step(state, seq.frames[1], model, cfg, seed=1, t=1)
    b = step(state, seq.frames[1], model, cfg, seed=1, t=1)
    c = step(state, seq.frames[1], model, cfg, seed=2, t=1)
    np.testing.assert_array_equal(a[0].poses, b[0].poses)
    np.testing.assert_array_equal(a[0].bg_var, b[0].bg_var)
    assert not np.array_equal(a[0].poses, c[0].poses)
    np.testing.assert_array_equal(state.bg_mean, before[0])
    np.testing.assert_array_equal(state.tex_mean, before[1])
    np.testing.assert_array_equal(state.poses, before[2])
    assert not state.poses.flags.writeable and not a[0].bg_mean.pool.flags.writeable


@pytest.mark.parametrize("background", [False, True])
@pytest.mark.parametrize("value", [0.0, 1.0])
def test_black_and_saturated_frames_give_no_nans(seq, model_pose, background: bool, value: float) -> None:
    model, pose0 = model_pose
    cfg = paper_config(n_experts=4, n_samples=3, background=background)
    state = init_state(model, pose0, np.full(seq.frames.shape[1:], value), cfg)
    for t in range(1, 4):
        frame = np.full(seq.frames.shape[1:], value) if t != 2 else seq.frames[t]
        state, est = step(state, frame, model, cfg, seed=0, t=t)
        for f in dataclasses.fields(est):
            v = getattr(est, f.name)
            assert np.isfinite(np.asarray(v, dtype=float)).all(), f.name
        for arr in (state.poses, state.tex_mean, state.tex_var, state.log_credibility):
            assert np.isfinite(arr).all()
        if background:
            assert np.isfinite(np.asarray(state.bg_mean)).all() and np.isfinite(np.asarray(state.bg_var)).all()


def test_estimate_contents(seq, model_pose) -> None:
    model, pose0 = model_pose
    cfg = paper_config(n_experts=6, n_samples=4)
    state = init_state(model, pose0, seq.frames[0], cfg)
    state, est = step(state, seq.frames[1], model, cfg, seed=0, t=1)
    n = model.n_vertices
    assert est.expert_points.shape == (6, n, 2) and est.mean_points.shape == (n, 2)
    np.testing.assert_allclose(est.bbox[:2], est.mean_points.min(0))
    np.testing.assert_allclose(est.bbox[:2] + est.bbox[2:], est.mean_points.max(0))
    assert 1.0 <= est.ess <= 6.0 and est.resampled
    assert np.exp(est.log_credibility).sum() == pytest.approx(1.0)
    np.testing.assert_allclose(state.log_credibility, -np.log(6))
    assert est.rotation.shape == (3, 3) and est.pose_std.shape == (6,)


def test_no_resampling_above_the_ess_threshold_keeps_credibilities(seq, model_pose) -> None:
    model, pose0 = model_pose
    cfg = paper_config(n_experts=5, n_samples=4, resample_ess_fraction=1e-9)
    state = init_state(model, pose0, seq.frames[0], cfg)
    new, est = step(state, seq.frames[1], model, cfg, seed=0, t=1)
    assert not est.resampled
    np.testing.assert_array_equal(est.parents, np.arange(5))
    np.testing.assert_allclose(new.log_credibility, est.log_credibility)


def test_bad_input_raises_clear_errors(seq, model_pose) -> None:
    model, pose0 = model_pose
    cfg = paper_config(n_experts=3, n_samples=2)
    f0 = seq.frames[0]
    with pytest.raises(ValueError, match="pose0 must have last dimension"):
        init_state(model, pose0[:5], f0, cfg)
    with pytest.raises(ValueError, match="needs an rng"):
        init_state(model, pose0, f0, cfg, pose_jitter_std=0.1)
    with pytest.raises(ValueError, match="2-D grey"):
        init_state(model, pose0, np.stack([f0] * 3, -1), cfg)
    state = init_state(model, pose0, f0, cfg)
    rngs = expert_rngs(0, 0, 1, range(3))
    with pytest.raises(ValueError, match="expects"):
        propose(state, f0[:-1], model, cfg, rngs)
    with pytest.raises(ValueError, match="NaN"):
        propose(state, np.where(f0 > 0.5, np.nan, f0), model, cfg, rngs)
    with pytest.raises(ValueError, match="one rng per proposed expert"):
        propose(state, f0, model, cfg, rngs[:2])
    with pytest.raises(ValueError, match="lie in"):
        propose(state, f0, model, cfg, rngs[:1], expert_indices=[3])
    with pytest.raises(ValueError, match="duplicates"):
        propose(state, f0, model, cfg, rngs[:2], expert_indices=[1, 1])
    other, _ = fit_head_model_to_box(seq.box, f0.shape, n_lon=5, n_lat=5)
    with pytest.raises(ValueError, match="vertices"):
        propose(state, f0, other, cfg, rngs)
    part = propose(state, f0, model, cfg, rngs[:2], expert_indices=[0, 2])
    with pytest.raises(ValueError, match="all 3 experts"):
        update(state, part, f0, model, cfg, np.random.default_rng(0))
