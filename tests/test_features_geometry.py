"""Chamfer images, similarity transforms and the metrics against brute force / closed form."""

import numpy as np
import pytest

from gflow_core import features, similarity
from gflow_core.evaluation.metrics import centre_error, iou, score
from gflow_core.m2.chamfer import chamfer_distance


def _edges(h=40, w=50):
    e = np.zeros((h, w), np.uint8)
    e[10, 5:45] = 255
    e[5:35, 30] = 255
    return e


def test_chamfer_image_matches_brute_force_distance():
    e = _edges()
    ys, xs = np.nonzero(e)
    rr, cc = np.mgrid[0 : e.shape[0], 0 : e.shape[1]]
    brute = np.sqrt((rr[..., None] - ys) ** 2 + (cc[..., None] - xs) ** 2).min(axis=2)
    quad = features.chamfer_image(e, "quadratic")
    assert np.allclose(quad, brute**2, atol=1e-2 * (1 + brute**2))
    trunc = features.chamfer_image(e, "truncated", g0=9.0)
    assert np.allclose(trunc, np.minimum(brute**2, 9.0), atol=1e-2 * (1 + brute**2))


def test_empty_edge_map_gives_finite_chamfer_image():
    cham = features.chamfer_image(np.zeros((20, 30), np.uint8), "quadratic")
    assert np.isfinite(cham).all() and cham.min() > 0


def test_chamfer_distance_zero_on_edges_and_quadratic_in_shift():
    e = _edges()
    cham = features.chamfer_image(e, "quadratic")
    curve = np.stack([np.arange(5, 45, dtype=float), np.full(40, 10.0)], axis=1)[None]
    assert chamfer_distance(cham, curve)[0] == pytest.approx(0.0, abs=1e-6)
    # a horizontal line shifted down by d pixels, away from the vertical edge: rho ~ d^2
    for d in (1.0, 2.0, 3.0):
        shifted = curve + [0.0, d]
        far = shifted[:, np.abs(shifted[0, :, 0] - 30) > 5]
        assert chamfer_distance(cham, far)[0] == pytest.approx(d * d, rel=0.05)


def test_similarity_inverse_and_composition():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20, 2)) * 10
    a = np.array([5.0, -3.0, 0.4, 1.3])
    b = np.array([-1.0, 2.0, -0.2, 0.8])
    assert np.allclose(similarity.apply(similarity.invert(a), similarity.apply(a, pts)), pts)
    assert np.allclose(similarity.apply(similarity.compose(a, b), pts), similarity.apply(a, similarity.apply(b, pts)))
    # rotation by 90 degrees maps (1, 0) to (0, 1) (x right, y down)
    assert np.allclose(similarity.apply(np.array([0, 0, np.pi / 2, 1.0]), np.array([[1.0, 0.0]])), [[0.0, 1.0]])


def test_metrics_closed_form():
    g = np.array([[0, 0, 10, 10]], float)
    p = np.array([[5, 0, 10, 10]], float)
    assert centre_error(g, p)[0] == pytest.approx(5.0)
    assert iou(g, p)[0] == pytest.approx(50 / 150)
    s = score({0: (0, 0, 10, 10), 1: (0, 0, 10, 10)}, {0: (0, 0, 10, 10)})
    assert s.missing == 1 and s.success == pytest.approx(0.5) and s.cle == pytest.approx(0.0)


def test_distance_transform_does_not_depend_on_opencv_threads():
    """Bit-exact re-execution on any machine: the chamfer image must not change with the
    number of OpenCV threads (OpenCV's precise transform alone does)."""
    import cv2

    rng = np.random.default_rng(0)
    e = (rng.uniform(size=(240, 320)) > 0.97).astype(np.uint8) * 255
    prev = cv2.getNumThreads()
    try:
        outs = []
        for n in (1, 2, 4):
            cv2.setNumThreads(n)
            outs.append(features.chamfer_image(e, "quadratic"))
    finally:
        cv2.setNumThreads(prev)
    assert all(np.array_equal(outs[0], o) for o in outs[1:])
    assert cv2.getNumThreads() == prev


def test_distance_transform_is_scipys_exact_edt_bit_for_bit():
    """The OpenCV-based transform gives SciPy's exact EDT (rounded to float32) bit for bit, so
    recordings made with either re-run identically: real Canny edges of caviar1, random maps
    from a single point to dense, and an image past the size where SciPy takes over."""
    import cv2
    from scipy import ndimage

    from tests.conftest import data_dir

    maps = []
    for f in sorted((data_dir("caviar1") / "frames").glob("*.jpg"))[::40]:
        maps.append(features.edge_map(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), None, None, 1.0, 80))
    rng = np.random.default_rng(1)
    for shape, density in [((288, 384), 1e-5), ((480, 640), 1e-3), ((240, 320), 0.05), ((37, 900), 0.3),
                           ((700, 800), 1e-4)]:
        e = (rng.uniform(size=shape) < density).astype(np.uint8) * 255
        e[rng.integers(shape[0]), rng.integers(shape[1])] = 255
        maps.append(e)
    for e in maps:
        want = ndimage.distance_transform_edt(e == 0).astype(np.float32)
        assert features.distance_transform(e).tobytes() == want.tobytes()
