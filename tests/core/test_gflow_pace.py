"""G-flow at a camera's pace: a step that spans dt frame periods (a live source skips frames) is dt
one-period steps of the pose walk, the texels' AR(1) prediction and the frontal reset composed
(GFlowConfig.at_pace), and the filter's texel prediction spans the periods its proposals did."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gflow_core.gflow import (
    GFlowParams,
    concatenate_proposals,
    expert_rngs,
    fit_head_model_to_box,
    init_state,
    paper_config,
    propose,
    update,
)
from gflow_core.gflow.pose_opinion import prior_mean
from gflow_core.gflow.synthetic_head import synthetic_sequence
from gflow_core.gflow.texture import anchored_predict


@pytest.fixture(scope="module")
def scene():
    """Two frames of a rendered head, the generic head model and its pose in the first."""
    seq = synthetic_sequence(np.random.default_rng(8), 2, (60, 80), rot_amp_deg=(4, 6, 3), trans_amp_px=(4, 2))
    return (seq, *fit_head_model_to_box(seq.box, seq.frames.shape[1:]))


def test_one_period_is_the_configuration_itself() -> None:
    cfg = GFlowParams().config()
    assert cfg.at_pace(1.0) is cfg


@pytest.mark.parametrize("dt", [0.5, 0.0, -1.0, math.nan, math.inf])
def test_a_step_shorter_than_a_period_or_not_finite_is_refused(dt: float) -> None:
    with pytest.raises(ValueError, match="dt must be finite and >= 1"):
        GFlowParams().config().at_pace(dt)


@pytest.mark.parametrize("dt", [2, 3, 5])
def test_a_step_of_dt_periods_is_dt_one_period_steps_composed(dt: int) -> None:
    cfg = GFlowParams().config()  # texture_decay 0.9, prior_rotation_decay 0.98, reset_rate 0.01
    slow = cfg.at_pace(float(dt))
    # the pose random walk: variances add up over the periods
    np.testing.assert_allclose(slow.prior_std(1), cfg.prior_std(1) * np.sqrt(dt), rtol=1e-15)
    # the prior mean's rotation decays dt times
    prev = np.array([[0.3, -0.2, 0.1, 10.0, 20.0, 50.0]])
    m = prev
    for _ in range(dt):
        m = prior_mean(m, cfg.prior_rotation_decay)
    np.testing.assert_allclose(prior_mean(prev, slow.prior_rotation_decay), m, rtol=1e-13)
    # the texels' AR(1) prediction about the first look, dt times, in one step
    rng = np.random.default_rng(1)
    anchor, mean, var = rng.uniform(0, 1, 50), rng.uniform(0, 1, (3, 50)), rng.uniform(1e-4, 1e-2, (3, 50))
    m1, v1 = mean, var
    for _ in range(dt):
        m1, v1 = anchored_predict(m1, v1, cfg.psi_v, cfg.texture_decay, anchor)
    m2, v2 = anchored_predict(mean, var, slow.psi_v, slow.texture_decay, anchor)
    np.testing.assert_allclose(m2, m1, rtol=1e-12)
    np.testing.assert_allclose(v2, v1, rtol=1e-12)
    # at least one frontal reset in dt periods
    assert slow.reset_rate == pytest.approx(1.0 - (1.0 - cfg.reset_rate) ** dt, rel=1e-15)


def test_a_random_walk_of_texels_adds_dt_process_noises() -> None:
    cfg = paper_config()  # texture_decay 1: the paper's random walk
    assert cfg.at_pace(4.0).psi_v == pytest.approx(4.0 * cfg.psi_v, rel=1e-15)
    assert cfg.at_pace(4.0).texture_decay == 1.0


def test_the_filter_predicts_the_texels_over_the_periods_of_its_proposals(scene) -> None:
    seq, model, pose0 = scene
    cfg = paper_config(n_experts=4, n_samples=3, texture_decay=0.9)
    state = init_state(model, pose0, seq.frames[0], cfg)
    props = propose(state, seq.frames[1], model, cfg, expert_rngs(1, 2, 1, range(4)), dt=3.0)
    assert props.dt == 3.0
    # the same proposals, weighed and updated as a 3-period step, whichever way the filter is told
    a, ea = update(state, props, seq.frames[1], model, cfg, np.random.default_rng(7))
    b, eb = update(state, dataclasses.replace(props, dt=1.0), seq.frames[1], model, cfg.at_pace(3.0),
                   np.random.default_rng(7))
    np.testing.assert_array_equal(a.tex_var, b.tex_var)
    np.testing.assert_array_equal(a.tex_mean, b.tex_mean)
    c, _ = update(state, dataclasses.replace(props, dt=1.0), seq.frames[1], model, cfg, np.random.default_rng(7))
    assert not np.array_equal(a.tex_var, c.tex_var)


def test_shards_made_for_different_steps_do_not_join(scene) -> None:
    seq, model, pose0 = scene
    cfg = paper_config(n_experts=4, n_samples=3)
    state = init_state(model, pose0, seq.frames[0], cfg)
    one = propose(state, seq.frames[1], model, cfg, expert_rngs(1, 2, 1, [0, 1]), [0, 1], dt=1.0)
    three = propose(state, seq.frames[1], model, cfg, expert_rngs(1, 2, 1, [2, 3]), [2, 3], dt=3.0)
    with pytest.raises(ValueError, match="different time steps"):
        concatenate_proposals([one, three])
    assert concatenate_proposals([three, dataclasses.replace(one, dt=3.0)]).dt == 3.0
