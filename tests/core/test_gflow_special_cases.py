"""Sec. 4: constrained optic flow (eq. 21) and template matching (eq. 22) are special cases of G-flow."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.gflow import init_state, step
from gflow_core.gflow.geometry import project, rotation_angle_deg
from gflow_core.gflow.image import bilinear_stencil
from gflow_core.gflow.synthetic_head import synthetic_sequence
from gflow_core.gflow.special_cases import (
    constrained_optic_flow,
    optic_flow_config,
    template_matching,
    template_matching_config,
)

N_ITER = 15


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(
        np.random.default_rng(11), 6, (120, 160), rot_amp_deg=(3, 5, 2), trans_amp_px=(4, 3), texture_drift=0.05
    )


def assert_same_pose(a: np.ndarray, b: np.ndarray) -> None:
    assert rotation_angle_deg(a, b) < 1e-5
    np.testing.assert_allclose(a[3:], b[3:], atol=1e-5)


def test_gflow_is_constrained_optic_flow(seq) -> None:
    """One expert, alpha -> 0, flat prior and background, Var(V_1) = kappa I, Psi_v -> inf."""
    model = seq.model
    cfg = optic_flow_config(gn_iterations=N_ITER)
    state = init_state(model, seq.poses[0], seq.frames[0], cfg)
    for t in range(1, len(seq.frames)):
        u_prev = state.poses[0]
        state, est = step(state, seq.frames[t], model, cfg, seed=0, t=t)
        direct = constrained_optic_flow(model.bases, u_prev, seq.frames[t - 1], seq.frames[t], N_ITER)
        assert_same_pose(state.poses[0], direct)
        assert_same_pose(est.pose, direct)
        # eq. 20: the template for t + 1 is y_t at the vertices of u_t
        y = bilinear_stencil(project(model.bases, state.poses[0]), seq.frames[t].shape).sample(seq.frames[t].ravel())
        np.testing.assert_allclose(state.tex_mean[0], y, atol=1e-8)
    err = rotation_angle_deg(state.poses[0], seq.poses[-1])
    print(f"optic flow after {len(seq.frames) - 1} frames: rotation error {err:.2f} deg")


def test_gflow_is_template_matching_and_the_template_never_changes(seq) -> None:
    """Var(V_1) = 0 and Psi_v -> 0: the texture stays mu_1 (eq. 22)."""
    model = seq.model
    cfg = template_matching_config(gn_iterations=N_ITER)
    state = init_state(model, seq.poses[0], seq.frames[0], cfg)
    template = state.tex_mean[0].copy()
    for t in range(1, len(seq.frames)):
        u_prev = state.poses[0]
        state, _ = step(state, seq.frames[t], model, cfg, seed=0, t=t)
        np.testing.assert_array_equal(state.tex_mean[0], template)
        np.testing.assert_array_equal(state.tex_var[0], 0.0)
        direct = template_matching(model.bases, u_prev, template, seq.frames[t], N_ITER)
        assert_same_pose(state.poses[0], direct)
