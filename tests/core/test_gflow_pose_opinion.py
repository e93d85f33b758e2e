"""Pose opinion: likelihood (eq. 13), Gauss-Newton on eq. 14, Laplace proposal, weights (eq. 16)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_normal, norm

from gflow_core.gflow.geometry import ROT, box_minus, box_plus, make_pose, project, rotation_angle_deg
from gflow_core.gflow.head_model import MorphableModel, fit_head_to_box
from gflow_core.gflow.image import prepare_frame
from gflow_core.gflow.pose_opinion import (
    TextureView,
    background_image_terms,
    gauss_newton_objective,
    gauss_newton_peak,
    laplace_proposal,
    linearise_objective,
    log_importance_weights,
    log_likelihood,
    log_pose_prior,
    prior_precision,
)
from gflow_core.gflow.synthetic_head import SphereTexture, render_head, smooth_background


def vertex_model(pix: np.ndarray) -> MorphableModel:
    """k = 1 model whose vertices project onto ``pix`` at the identity pose with c = 1, l = 0."""
    z = np.linspace(-1.0, 1.0, len(pix))
    return MorphableModel(np.column_stack([pix, z])[:, :, None])


@pytest.mark.parametrize("background", [True, False])
def test_log_likelihood_is_eq13_with_the_dense_projection(background: bool) -> None:
    rng = np.random.default_rng(0)
    H, W = 5, 6
    pix = np.array([[1.0, 1.0], [4.0, 2.0], [2.0, 3.0], [5.0, 4.0]])
    n, m = len(pix), H * W
    model = vertex_model(pix)
    u = make_pose(None, [0.0, 0.0], [1.0])
    sw, psi_b = 2e-3, 1e-4
    mu_v, var_v = rng.uniform(0, 1, (1, n)), rng.uniform(1e-4, 1e-2, (1, n))  # predicted (eq. 9, 10)
    mu_b, var_b = rng.uniform(0, 1, (1, H, W)), rng.uniform(1e-4, 1e-2, (1, H, W))  # posterior at t-1
    y = rng.uniform(0, 1, (H, W))
    fd = prepare_frame(y)
    a_v = np.zeros((m, n))
    a_v[(pix[:, 1] * W + pix[:, 0]).astype(int), np.arange(n)] = 1.0
    if background:
        tv = TextureView(mu_v, var_v, mu_b, var_b, np.array([0]), psi_b)
        ll = log_likelihood(model.bases, fd, u[None, None], tv, sw, background_image_terms(y, tv, sw))
        # Y = a (V; B) + W, a = [a_v, I - a_v a_v^T]                                    (eq. 4)
        a = np.hstack([a_v, np.eye(m) - a_v @ a_v.T])
        mean = a @ np.concatenate([mu_v[0], mu_b.ravel()])
        cov = a @ np.diag(np.concatenate([var_v[0], var_b.ravel() + psi_b])) @ a.T + sw * np.eye(m)
        expected = multivariate_normal(mean, cov).logpdf(y.ravel())
    else:
        tv = TextureView(mu_v, var_v)
        ll = log_likelihood(model.bases, fd, u[None, None], tv, sw)
        expected = norm(mu_v[0], np.sqrt(var_v[0] + sw)).logpdf(y.ravel() @ a_v).sum()
    assert ll.shape == (1, 1)
    assert ll[0, 0] == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize("background", [False, True])
def test_gauss_newton_gradient_matches_finite_differences(background: bool) -> None:
    """On a linear image, bilinear sampling and central differences are exact, so is the GN gradient."""
    rng = np.random.default_rng(1)
    H, W = 40, 50
    r, c = np.mgrid[0:H, 0:W]
    fd = prepare_frame(0.1 + 0.01 * c + 0.009 * r)
    head, _ = fit_head_to_box(np.array([15.0, 10.0, 16.0, 20.0]), (H, W), n_lon=5, n_lat=5)
    model = head.model()
    u = np.stack([make_pose(np.array([0.1, -0.2, 0.15]), [23.0, 20.0], [20.0]), make_pose(None, [25.0, 19.0], [18.0])])
    prev = box_plus(u, np.array([0.0, 0.0, 0.0, 1.5, -2.0, 0.3]))  # rotation difference 0: prior linear
    n = model.n_vertices
    bg = dict(
        bg_mean=(0.3 + 0.004 * c + 0.007 * r)[None].repeat(2, 0),
        bg_var=np.full((2, H, W), 2e-3),
        bg_rows=np.array([0, 1]),
        psi_b=1e-4,
    )
    tv = TextureView(rng.uniform(0.2, 0.8, (2, n)), rng.uniform(1e-4, 1e-3, (2, n)), **(bg if background else {}))
    std = np.array([0.1, 0.1, 0.1, 5.0, 5.0, 2.0])
    g, Hs, f = linearise_objective(model.bases, fd, prev, u, tv, 1e-3, prior_precision(std), background)
    f0 = gauss_newton_objective(model.bases, fd, prev, u, tv, 1e-3, std, background)
    np.testing.assert_allclose(f, f0, rtol=1e-12)
    h = 1e-6
    for p in range(u.shape[1]):
        e = np.zeros(u.shape[1])
        e[p] = h
        fp = gauss_newton_objective(model.bases, fd, prev, box_plus(u, e), tv, 1e-3, std, background)
        fm = gauss_newton_objective(model.bases, fd, prev, box_plus(u, -e), tv, 1e-3, std, background)
        np.testing.assert_allclose(g[:, p], (fp - fm) / (2 * h), rtol=1e-5, atol=1e-6 * np.abs(g).max())
    assert np.all(np.linalg.eigvalsh(Hs) > 0)


def test_gauss_newton_converges_on_a_render_with_known_pose() -> None:
    rng = np.random.default_rng(1)
    shape = (160, 200)
    head, pose0 = fit_head_to_box(np.array([60.0, 30.0, 80.0, 100.0]), shape)
    model = head.model()
    tex = SphereTexture.random(rng)
    true = make_pose(np.radians([6.0, -8.0, 4.0]), pose0[3:5] + [3.0, -2.0], pose0[5:] * 1.03)
    frame = render_head(head, true, tex, smooth_background(shape, rng), rng=rng, noise_std=0.005)
    tv = TextureView(tex(head.directions())[None], np.full((1, model.n_vertices), 1e-4))
    start = box_plus(true, np.r_[np.radians([3.0, -3.0, 2.0]), 2.0, -1.5, -2.0])[None]
    res = gauss_newton_peak(model.bases, prepare_frame(frame), start, tv, 1e-4, np.full(6, np.inf), 8)
    f_start = gauss_newton_objective(model.bases, prepare_frame(frame), start, start, tv, 1e-4, np.full(6, np.inf))
    rot_err = float(rotation_angle_deg(res.u_hat[0], true))
    px_err = float(np.abs(project(model.bases, res.u_hat[0]) - project(model.bases, true)).max())
    print(f"GN from 4.7 deg / 2.5 px off: rotation error {rot_err:.2f} deg, max vertex error {px_err:.2f} px")
    assert rot_err < 2.0 and px_err < 1.5
    assert res.objective[0] < f_start[0] / 50


def test_laplace_proposal_samples_the_laplace_gaussian() -> None:
    rng = np.random.default_rng(2)
    P = 6
    A = rng.normal(size=(P, P))
    Hm = A @ A.T + P * np.eye(P)
    u_hat = make_pose(np.array([0.3, -0.1, 0.2]), [50.0, 60.0], [30.0])
    alpha, s = 0.5, 20000
    samples, log_g, sigma = laplace_proposal(u_hat[None], Hm[None], alpha, s, [np.random.default_rng(7)])
    np.testing.assert_allclose(sigma[0], np.linalg.inv(Hm), rtol=1e-10)
    d = box_minus(u_hat, samples[0])
    np.testing.assert_allclose(np.cov(d.T), alpha * sigma[0], atol=0.05 * np.abs(alpha * sigma[0]).max())
    np.testing.assert_allclose(log_g[0], multivariate_normal(np.zeros(P), alpha * sigma[0]).logpdf(d), rtol=1e-9)
    # alpha -> 0: every sample is u_hat, log g is the alpha = 1 density at its mode
    s0, lg0, _ = laplace_proposal(u_hat[None], Hm[None], 0.0, 3, [np.random.default_rng(7)])
    np.testing.assert_array_equal(s0[0], np.repeat(u_hat[None], 3, 0))
    np.testing.assert_allclose(lg0[0], multivariate_normal(np.zeros(P), sigma[0]).logpdf(np.zeros(P)), rtol=1e-12)
    with pytest.raises(ValueError, match="one rng per expert"):
        laplace_proposal(u_hat[None], Hm[None], alpha, 3, [])


def test_pose_prior_is_a_gaussian_random_walk_in_the_tangent_space() -> None:
    rng = np.random.default_rng(3)
    prev = np.stack([make_pose(np.array([0.2, 0.1, -0.3]), [10.0, 20.0], [40.0, 5.0])] * 2)
    d = rng.normal(size=(2, 4, 7)) * 0.1
    poses = box_plus(prev[:, None], d)
    std = np.array([0.1, 0.2, 0.3, 4.0, 5.0, np.inf, 2.0])
    lp = log_pose_prior(prev, poses, std)
    fin = np.isfinite(std)
    np.testing.assert_allclose(lp, norm(0, std[fin]).logpdf(d[..., fin]).sum(-1), rtol=1e-10)
    # eq. 16: log w = log prior + log likelihood - log proposal
    np.testing.assert_allclose(log_importance_weights(lp, 2 * lp, lp), 2 * lp)


def test_rotation_slice_constant_is_used_for_the_prior() -> None:
    assert prior_precision(np.array([0.5, np.inf]))[1] == 0.0
    assert ROT == slice(0, 3)
