"""The departures the face tracker uses: the morph prior (an AR(1) on the expression), texels reverting
toward the first look, local contrast normalisation, the frontal reset of the rotation, and the
confidence (the fraction of vertices the frame explains)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gflow_core.gflow import GFlowConfig, init_state, propose, update
from gflow_core.gflow.filter import expert_rngs
from gflow_core.gflow.geometry import make_pose, rotation_angle_deg
from gflow_core.gflow.image import local_contrast
from gflow_core.gflow.pose_opinion import RotationReset, prior_mean
from gflow_core.gflow.synthetic_head import synthetic_sequence
from gflow_core.gflow.texture import anchored_predict, kalman_predict


def _log_normal(x, m, s):
    return -0.5 * ((x - m) / s) ** 2 - math.log(s) - 0.5 * math.log(2 * math.pi)


def test_morph_prior_is_the_normalised_product_of_walk_and_stationary_factor() -> None:
    cfg = GFlowConfig(prior_std_coefficients=(0.5, 0.2, 0.3), morph_prior_std=(1.0, 2.0))
    a, std = cfg.morph_shrink(3), cfg.prior_std(3)[5:]
    assert a[0] == 1.0 and std[0] == 0.5  # the scale keeps its random walk
    prev = 1.7
    for j, (rw, m) in enumerate(((0.2, 1.0), (0.3, 2.0)), start=1):
        c = np.linspace(-3, 3, 7)
        # N(c; prev, rw^2) N(c; 0, m^2) = const * N(c; a prev, std^2)
        diff = _log_normal(c, prev, rw) + _log_normal(c, 0.0, m) - _log_normal(c, a[j] * prev, std[j])
        np.testing.assert_allclose(diff, diff[0], atol=1e-12)
    u = make_pose(None, [0, 0], [60.0, 3.0, -2.0])
    np.testing.assert_allclose(prior_mean(u, 1.0, a)[5:], [60.0, 3.0 * a[1], -2.0 * a[2]])
    assert GFlowConfig().morph_shrink(3) is None
    with pytest.raises(ValueError, match="k - 1 = 1"):
        GFlowConfig(morph_prior_std=(1.0, 2.0)).prior_std(2)


def test_texels_revert_toward_the_first_look() -> None:
    mean, var = np.array([0.9, 0.1]), np.array([0.0, 0.0])
    np.testing.assert_array_equal(anchored_predict(mean, var, 1e-3, 1.0, np.zeros(2))[1],
                                  kalman_predict(mean, var, 1e-3)[1])
    anchor = np.array([0.5, 0.5])
    for _ in range(400):  # predictions only: the mean goes to the anchor, the variance to Psi / (1 - a^2)
        mean, var = anchored_predict(mean, var, 1e-3, 0.9, anchor)
    np.testing.assert_allclose(mean, anchor, atol=1e-12)
    np.testing.assert_allclose(var, 1e-3 / (1 - 0.81), rtol=1e-9)


def test_local_contrast_ignores_smooth_light_changes() -> None:
    rng = np.random.default_rng(0)
    import cv2

    img = np.clip(0.4 + 0.2 * cv2.GaussianBlur(rng.standard_normal((60, 80)), (0, 0), 1.5) * 3, 0, 1)
    a = local_contrast(img, 4.0)
    b = local_contrast(0.5 * img + 0.3, 4.0)  # darker contrast, brighter
    assert 0.0 < a.min() and a.max() < 1.0
    assert np.abs(a - b).mean() < 0.03 and np.abs(a - local_contrast(np.full_like(img, 0.5), 4.0)).mean() > 0.1
    assert np.abs(img - (0.5 * img + 0.3)).mean() > 0.1  # while the raw frames differ


def test_rotation_reset_density_is_the_mixture() -> None:
    r = RotationReset(rate=0.01, std=0.35, min_angle=0.17, walk_std=np.array([0.05, 0.05, 0.05]))
    w = np.array([[0.0, 0.0, 0.0], [0.1, -0.05, 0.02], [0.6, 0.0, 0.0]])
    poses = np.concatenate([w, np.zeros((3, 3))], axis=1)
    got = r.neg_log_rotation(np.zeros((3, 6)), poses)  # prior mean at the identity: d = w

    def iso(x, s):
        return np.exp(sum(_log_normal(v, 0.0, s) for v in x))

    want = [-math.log(0.99 * iso(x, 0.05) + 0.01 * iso(x, 0.35)) for x in w]
    np.testing.assert_allclose(got, want, rtol=1e-10)


@pytest.fixture(scope="module")
def head():
    return synthetic_sequence(np.random.default_rng(3), 2, (120, 160), rot_amp_deg=(0, 0, 0), trans_amp_px=(0, 0),
                              scale_amp=0.0)


def test_a_turned_expert_comes_back_to_frontal_with_the_reset(head) -> None:
    """An expert whose pose is wrongly turned 25 degrees (yaw), with texels of the (true) frontal head:
    the random walk (1.1 degrees a frame) keeps it turned (measured: 23.5 degrees after the step); the
    reset brings it back (0.8)."""
    seq = head
    base = dict(n_experts=1, n_samples=4, sigma_w=1e-2, psi_v=1e-5, v_init_var=2e-4, prior_std_rotation=0.02,
                pyramid_levels=2)
    true = seq.poses[0]
    turned = make_pose(np.array([0.0, math.radians(25.0), 0.0]), true[3:5], true[5:])
    angles = {}
    for rate in (0.0, 0.01):
        cfg = GFlowConfig(reset_rate=rate, **base)
        st = init_state(seq.model, true, seq.frames[0], cfg)  # texels of the frontal head
        st = type(st)(**{**st.__dict__, "poses": turned[None].copy()})
        props = propose(st, seq.frames[1], seq.model, cfg, expert_rngs(0, 0, 1, [0]))
        angles[rate] = rotation_angle_deg(props.u_hat[0], seq.poses[1])
    assert angles[0.0] > 10.0 and angles[0.01] < 3.0, angles


def test_confidence_falls_when_the_face_is_covered(head) -> None:
    seq = head
    cfg = GFlowConfig(n_experts=4, n_samples=4, sigma_w=2e-4, psi_v=1e-5, v_init_var=2e-4)
    st = init_state(seq.model, seq.poses[0], seq.frames[0], cfg)
    covered = seq.frames[1].copy()
    x, y, w, h = seq.box
    rng = np.random.default_rng(1)
    covered[int(y):int(y + 0.6 * h), int(x):int(x + w)] = rng.uniform(0, 1, (int(y + 0.6 * h) - int(y),
                                                                            int(x + w) - int(x)))
    frac = {}
    for name, frame in (("clear", seq.frames[1]), ("covered", covered)):
        props = propose(st, frame, seq.model, cfg, expert_rngs(0, 0, 1, range(4)))
        frac[name] = update(st, props, frame, seq.model, cfg, np.random.default_rng(0))[1].inlier_fraction
    assert frac["clear"] > 0.9 and frac["covered"] < 0.6, frac
