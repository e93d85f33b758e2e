"""Distances for M2: chamfer on curves (eq. 4-5), shuffle and L2 on patches (sec. 3.1)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.m2.curves import Curves, PointChamferImage
from gflow_core.m2.distances import ChamferMetric, L2Metric, ShuffleMetric, make_metric


def dense_line(length: float = 100.0, spacing: float = 0.25) -> np.ndarray:
    x = np.arange(-length / 2, length / 2 + 1e-9, spacing)
    return np.stack([x, np.zeros_like(x)], axis=1)


def circle(r: float = 30.0, n: int = 4000) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1)


def rect_outline(w: int = 20, h: int = 40) -> np.ndarray:
    pts = [(x, 0) for x in range(w)] + [(x, h - 1) for x in range(w)]
    pts += [(0, y) for y in range(1, h - 1)] + [(w - 1, y) for y in range(1, h - 1)]
    return np.array(pts, dtype=np.float64)


@pytest.mark.parametrize("method", ["image", "kdtree"])
def test_chamfer_of_identical_curves_is_zero(method: str) -> None:
    c = Curves.from_list([rect_outline(), rect_outline() + [3.0, -2.0]])
    D = ChamferMetric("quadratic", method=method).pairwise(c, c)
    assert D.shape == (2, 2)
    assert D[0, 0] == 0.0 and D[1, 1] == 0.0
    assert D[0, 1] > 1.0


@pytest.mark.parametrize("delta", [0.5, 1.0, 2.0, 3.0])
def test_quadratic_chamfer_of_shifted_dense_line_is_delta_squared(delta: float) -> None:
    # a dense curve shifted along its normal by delta: rho = delta^2 (eq. 4, g(u) = u^2)
    line = dense_line()
    moved = line[40:-40] + [0.0, delta]  # keep away from the ends
    # one point per canvas pixel (spacing 1 / upsample) keeps the line exact
    D = ChamferMetric("quadratic", upsample=4).pairwise(Curves.from_list([moved]), Curves.from_list([line]))
    assert D[0, 0] == pytest.approx(delta**2, rel=0.02)


def test_quadratic_chamfer_grows_quadratically_for_small_shifts() -> None:
    # circle shifted by delta: normal displacement delta cos(phi), so rho ~ delta^2 / 2
    c = circle()
    m = ChamferMetric("quadratic", method="kdtree")
    rho = np.array([m.pairwise(Curves.from_list([c + [d, 0.0]]), Curves.from_list([c]))[0, 0]
                    for d in (0.25, 0.5, 1.0, 2.0)])
    assert rho / np.array([0.25, 0.5, 1.0, 2.0]) ** 2 == pytest.approx(np.full(4, 0.5), rel=0.05)
    # and the chamfer image route agrees with the exact nearest-point route
    mi = ChamferMetric("quadratic", upsample=4)
    rho_img = np.array([mi.pairwise(Curves.from_list([c + [d, 0.0]]), Curves.from_list([c]))[0, 0]
                        for d in (1.0, 2.0)])
    assert rho_img == pytest.approx(rho[2:], rel=0.05)


def test_truncated_profile_saturates_at_g0() -> None:
    line = dense_line()
    far = Curves.from_list([line[40:-40] + [0.0, 20.0]])
    near = Curves.from_list([line[40:-40] + [0.0, 2.0]])
    ref = Curves.from_list([line])
    m = ChamferMetric("truncated", g0=25.0)
    assert m.pairwise(far, ref)[0, 0] == pytest.approx(25.0)
    assert m.pairwise(near, ref)[0, 0] == pytest.approx(4.0, rel=0.02)


def test_chamfer_is_not_symmetric() -> None:
    full = rect_outline()
    part = full[:20]  # the top edge only
    c = Curves.from_list([part, full])
    D = ChamferMetric().pairwise(c, c)
    assert D[0, 1] == 0.0  # every point of the part lies on the full outline
    assert D[1, 0] > 10.0  # most of the outline is far from the part


def test_chamfer_image_matches_kdtree_on_random_curves() -> None:
    rng = np.random.default_rng(3)
    curves = Curves.from_list([rng.uniform(-20, 20, size=(int(rng.integers(20, 60)), 2)) for _ in range(5)])
    a = ChamferMetric("quadratic", upsample=4).pairwise(curves, curves)
    b = ChamferMetric("quadratic", method="kdtree").pairwise(curves, curves)
    assert np.abs(a - b).max() < 0.05 * b.max()
    assert np.allclose(np.diag(a), 0.0, atol=0.05)


def test_point_chamfer_image_is_continuous_off_canvas() -> None:
    img = PointChamferImage(np.array([[0.0, 0.0]]), np.array([-5.0, -5.0]), np.array([5.0, 5.0]), "quadratic")
    g = img(np.array([[3.0, 0.0], [5.0, 0.0], [8.0, 0.0]]))
    assert g == pytest.approx([9.0, 25.0, 64.0], rel=0.02)


def test_chamfer_to_image_matches_pairwise_direction() -> None:
    # rho(T_alpha x~_k, z) against a frame's chamfer image equals the curve-to-curve distance
    from gflow_core.features import chamfer_image

    outline = rect_outline()
    frame = np.zeros((80, 80), dtype=np.uint8)
    z = outline + [30.0, 20.0]
    frame[z[:, 1].astype(int), z[:, 0].astype(int)] = 255
    gam = chamfer_image(frame, "quadratic")
    ex = Curves.from_list([outline, outline[:10]])
    alphas = np.array([[30.0, 20.0, 0.0, 1.0], [31.0, 20.0, 0.0, 1.0], [30.0, 20.0, 0.0, 1.0]])
    rho = ChamferMetric().to_image(ex, gam, alphas, np.array([0, 0, 1]))
    assert rho[0] == pytest.approx(0.0, abs=1e-9)
    assert rho[1] > 0.1
    assert rho[2] == pytest.approx(0.0, abs=1e-9)


def naive_shuffle(a: np.ndarray, b: np.ndarray, r: int) -> float:
    h, w = a.shape
    tot = 0.0
    for y in range(h):
        for x in range(w):
            best = np.inf
            for dy in range(-r, r + 1):
                for dx in range(-r, r + 1):
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < h and 0 <= xx < w:
                        best = min(best, (a[y, x] - b[yy, xx]) ** 2)
            tot += best
    return tot / (h * w)


def test_shuffle_matches_naive_loop() -> None:
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 255, size=(3, 6, 7))
    b = rng.uniform(0, 255, size=(2, 6, 7))
    D = ShuffleMetric(radius=1, chunk=50).pairwise(a, b)  # small chunk exercises chunking
    ref = np.array([[naive_shuffle(a[i], b[j], 1) for j in range(2)] for i in range(3)])
    assert D == pytest.approx(ref, rel=1e-12)


def test_shuffle_radius_zero_is_l2_and_shuffle_is_below_l2() -> None:
    rng = np.random.default_rng(1)
    p = rng.uniform(0, 255, size=(4, 10, 12))
    l2 = L2Metric().pairwise(p, p)
    assert ShuffleMetric(radius=0).pairwise(p, p) == pytest.approx(l2, rel=1e-9, abs=1e-9)
    direct = np.array([[np.mean((p[i] - p[j]) ** 2) for j in range(4)] for i in range(4)])
    assert l2 == pytest.approx(direct, rel=1e-9, abs=1e-6)
    sh = ShuffleMetric(radius=2).pairwise(p, p)
    assert (sh <= l2 + 1e-9).all()
    assert np.allclose(np.diag(sh), 0.0)


def test_shuffle_is_robust_to_a_one_pixel_shift() -> None:
    rng = np.random.default_rng(2)
    img = rng.uniform(0, 255, size=(30, 30))
    a = img[5:25, 5:25]
    b = img[5:25, 6:26]  # a shifted by one column
    l2 = L2Metric().pairwise(a[None], b[None])[0, 0]
    sh = ShuffleMetric(radius=1).pairwise(a[None], b[None])[0, 0]
    assert l2 > 1000.0
    # only the last column has no exact match in the neighbourhood
    assert sh < 0.1 * l2


def test_patch_to_image_indexes_by_particle() -> None:
    rng = np.random.default_rng(4)
    ex = rng.uniform(0, 255, size=(3, 8, 8))
    m = make_metric("shuffle", radius=1)
    rho_k = m.to_image(ex, ex[1])
    assert rho_k.shape == (3,) and rho_k[1] == 0.0 and rho_k[0] > 0 and rho_k[2] > 0
    k = np.array([2, 1, 1, 0])
    assert m.to_image(ex, ex[1], k=k) == pytest.approx(rho_k[k])
    with pytest.raises(ValueError, match="transforms"):
        m.to_image(ex, ex[1], alphas=np.array([0.0, 0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="does not match"):
        m.to_image(ex, ex[1, :4])


def test_patch_transform_shifts_content() -> None:
    p = np.zeros((1, 9, 9))
    p[0, 4, 4] = 1.0
    out = L2Metric().transform(p, np.array([2.0, -1.0, 0.0, 1.0]))
    assert np.unravel_index(np.argmax(out[0]), (9, 9)) == (3, 6)  # (row, col) moved by (dy, dx) = (-1, 2)


def test_metric_errors() -> None:
    with pytest.raises(ValueError, match="unknown metric"):
        make_metric("hausdorff")
    with pytest.raises(ValueError, match="profile"):
        ChamferMetric(profile="cubic")
    with pytest.raises(ValueError, match="radius"):
        ShuffleMetric(radius=-1)
    with pytest.raises(ValueError, match="no"):
        ChamferMetric().pairwise([], [])
    with pytest.raises(ValueError, match="sizes differ"):
        L2Metric().pairwise(np.zeros((1, 4, 4)), np.zeros((1, 4, 5)))
    with pytest.raises(ValueError, match="NaN"):
        L2Metric().pairwise(np.full((1, 4, 4), np.nan), np.zeros((1, 4, 4)))
