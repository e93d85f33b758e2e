"""Texel Kalman filters (eq. 7-10), object masks and bilinear sampling."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.gflow.image import bilinear_stencil, prepare_frame, validate_frame
from gflow_core.gflow.texture import background_predict_update, kalman_predict, kalman_update, object_mask


def tiny_scene(rng: np.random.Generator, H: int = 5, W: int = 6):
    """Three vertices on integer pixels (so bilinear sampling is the paper's a_v exactly)."""
    pix = np.array([[1, 1], [4, 2], [2, 3]])  # (x, y) = (col, row)
    n, m = len(pix), H * W
    a_v = np.zeros((m, n))
    a_v[pix[:, 1] * W + pix[:, 0], np.arange(n)] = 1.0
    a_b = np.eye(m) - a_v @ a_v.T  # a_b = I - a_v a_v^T
    return pix.astype(float), np.hstack([a_v, a_b]), n, m


def test_kalman_predict_adds_process_noise() -> None:
    mean, var = np.array([0.2, 0.7]), np.array([1e-3, 0.0])
    m2, v2 = kalman_predict(mean, var, 5e-4)
    np.testing.assert_array_equal(m2, mean)  # eq. 9
    np.testing.assert_allclose(v2, var + 5e-4)  # eq. 10


def test_kalman_update_is_the_product_of_gaussians() -> None:
    rng = np.random.default_rng(0)
    mu, var, y = rng.uniform(0, 1, 100), rng.uniform(1e-5, 1.0, 100), rng.uniform(0, 1, 100)
    sw = 3e-3
    m2, v2 = kalman_update(mu, var, y, sw)
    # N(mu, var) N(y; ., sw):  1/var' = 1/var + 1/sw,  mu' = var' (mu/var + y/sw)      (eq. 7, 8)
    prec = 1.0 / var + 1.0 / sw
    np.testing.assert_allclose(v2, 1.0 / prec, rtol=1e-12)
    np.testing.assert_allclose(m2, (mu / var + y / sw) / prec, rtol=1e-12)


def test_kalman_update_limits_and_unobserved_texels() -> None:
    mu, y = np.array([0.3, 0.3, 0.3, 0.3]), np.array([0.9, 0.9, 0.9, 0.9])
    var = np.array([0.0, np.inf, 1e-3, np.inf])
    observed = np.array([True, True, False, False])
    m2, v2 = kalman_update(mu, var, y, 1e-3, observed=observed)
    np.testing.assert_array_equal(m2[[0, 2, 3]], 0.3)  # var 0 (a template) or unobserved: unchanged
    assert m2[1] == pytest.approx(0.9, abs=1e-15)  # var inf: takes the observation
    np.testing.assert_array_equal(v2, [0.0, 1e-3, 1e-3, np.inf])
    assert np.isfinite(m2).all()


def test_eq7_8_with_the_dense_projection_matrix() -> None:
    """Diagonal updates == Gaussian conditioning of (V, B) on y = a(u) (V; B) + W (eq. 4, 7, 8)."""
    rng = np.random.default_rng(1)
    H, W = 5, 6
    pix, a, n, m = tiny_scene(rng, H, W)
    sw, psi_v, psi_b = 2e-3, 1e-4, 3e-4
    mu_v, var_v = rng.uniform(0, 1, n), rng.uniform(1e-4, 1e-2, n)
    mu_b, var_b = rng.uniform(0, 1, (1, H, W)), rng.uniform(1e-4, 1e-2, (1, H, W))
    y = rng.uniform(0, 1, (H, W))
    # dense: predicted prior, then condition on y
    mu = np.concatenate([mu_v, mu_b.ravel()])
    var = np.concatenate([var_v + psi_v, var_b.ravel() + psi_b])
    prec_post = np.diag(1.0 / var) + a.T @ a / sw  # eq. 7
    cov_post = np.linalg.inv(prec_post)
    mean_post = cov_post @ (mu / var + a.T @ y.ravel() / sw)  # eq. 8
    assert np.allclose(cov_post, np.diag(np.diag(cov_post)), atol=1e-15)  # stays diagonal
    # diagonal implementation
    yv = bilinear_stencil(pix, (H, W)).sample(y.ravel())
    mv, vv = kalman_update(*kalman_predict(mu_v, var_v, psi_v), yv, sw)
    mb, vb = mu_b.copy(), var_b.copy()
    mb, vb = background_predict_update(mb, vb, y, psi_b, sw, [object_mask(pix, (H, W), "vertices")])
    np.testing.assert_allclose(np.concatenate([mv, mb.ravel()]), mean_post, rtol=1e-10)
    np.testing.assert_allclose(np.concatenate([vv, vb.ravel()]), np.diag(cov_post), rtol=1e-10)


def test_object_masks() -> None:
    pts = np.array([[2.0, 2.0], [12.0, 2.0], [12.0, 9.0], [2.0, 9.0], [7.0, 5.0], [-50.0, 3.0]])
    mv = object_mask(pts, (12, 16), "vertices")
    assert mv.sum() == 5 and mv[5, 7] and mv[2, 2]
    mh = object_mask(pts[:5], (12, 16), "hull")
    assert mh[2:10, 2:13].all() and mh.sum() == 8 * 11
    mm = object_mask(pts[:5], (12, 16), "hull", margin=0.2)
    assert mm.sum() > mh.sum() and mm[mh].all()
    with pytest.raises(ValueError, match="'vertices' or 'hull'"):
        object_mask(pts, (12, 16), "disc")


def test_bilinear_sampling_is_exact_on_linear_images_and_replicates_the_border() -> None:
    H, W = 7, 9
    r, c = np.mgrid[0:H, 0:W]
    img = 0.1 + 0.05 * c + 0.08 * r  # value at (x, y) = 0.1 + 0.05 x + 0.08 y
    img = img / img.max()
    fd = prepare_frame(img)
    pts = np.array([[0.0, 0.0], [3.25, 2.5], [8.0, 6.0], [7.9, 0.1], [-3.0, 2.0], [4.0, 10.0]])
    st = bilinear_stencil(pts, (H, W))
    v, dx, dy = st.sample_with_gradient(fd.flat)
    xc, yc = np.clip(pts[:, 0], 0, W - 1), np.clip(pts[:, 1], 0, H - 1)
    s = 1.0 / (0.1 + 0.05 * (W - 1) + 0.08 * (H - 1))
    np.testing.assert_allclose(v, (0.1 + 0.05 * xc + 0.08 * yc) * s, rtol=1e-12)
    gx, gy = st.sample_gradient_images(fd)
    np.testing.assert_array_equal(st.inside, [True, True, True, True, False, False])
    np.testing.assert_allclose(gx, np.where(st.dx_ok, 0.05 * s, 0.0), rtol=1e-12)
    np.testing.assert_allclose(dx, np.where(st.dx_ok, 0.05 * s, 0.0), rtol=1e-12)
    np.testing.assert_allclose(gy[:5], np.where(st.dy_ok[:5], 0.08 * s, 0.0), rtol=1e-12)
    assert gy[5] == 0.0 and dy[5] == 0.0 and gx[4] == 0.0  # clamped coordinates have no derivative
    # non-finite points are outside, and sampling stays finite
    st2 = bilinear_stencil(np.array([[np.nan, 1.0], [np.inf, -np.inf]]), (H, W))
    assert not st2.inside.any() and np.isfinite(st2.sample(fd.flat)).all()


@pytest.mark.parametrize(
    ("frame", "match"),
    [
        (np.zeros((4, 4, 3)), "2-D grey"),
        (np.zeros((4, 4), dtype=np.uint8), "floating point"),
        (np.zeros((1, 4)), "at least 2x2"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.full((4, 4), 1.5), r"\[0, 1\]"),
        (np.full((4, 5), 0.5), "expects"),
    ],
)
def test_frame_validation(frame, match) -> None:
    with pytest.raises(ValueError, match=match):
        validate_frame(frame, shape=(4, 4) if frame.shape == (4, 5) else None)


def test_background_update_from_parents_equals_gather_then_update_in_place() -> None:
    rng = np.random.default_rng(4)
    mean, var = rng.uniform(0, 1, (3, 6, 7)), rng.uniform(1e-4, 1e-2, (3, 6, 7))
    y = rng.uniform(0, 1, (6, 7))
    masks = [rng.uniform(size=(6, 7)) < 0.3 for _ in range(4)]
    parents = np.array([2, 0, 2, 1])
    out = background_predict_update(mean, var, y, 1e-4, 1e-3, masks, parents, (np.empty((4, 6, 7)), np.empty((4, 6, 7))))
    m2, v2 = mean[parents], var[parents]
    background_predict_update(m2, v2, y, 1e-4, 1e-3, masks)
    np.testing.assert_array_equal(out[0], m2)
    np.testing.assert_array_equal(out[1], v2)
    for e in range(4):  # object pixels: prediction only
        np.testing.assert_array_equal(out[0][e][masks[e]], mean[parents[e]][masks[e]])
        np.testing.assert_allclose(out[1][e][masks[e]], var[parents[e]][masks[e]] + 1e-4)
    with pytest.raises(ValueError, match="parents=None"):
        background_predict_update(mean, var, y, 1e-4, 1e-3, masks, parents)
    with pytest.raises(ValueError, match="one object mask per expert"):
        background_predict_update(mean, var, y, 1e-4, 1e-3, masks[:2])
