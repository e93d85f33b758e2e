"""G-flow's local background (``GFlowConfig.local_background``): the object's data term weighed against
the frame read about each pixel, so a flat patch gains nothing by being claimed."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.gflow.coarse_search import translation_costs, translation_sums
from gflow_core.gflow.filter import GFlowConfig
from gflow_core.gflow.geometry import make_pose
from gflow_core.gflow.image import prepare_frame, stencil_xy
from gflow_core.gflow.params import GFlowParams
from gflow_core.gflow.pose_opinion import TextureView, local_background, log_likelihood

SIGMA_W = 1e-2


def _grid_model(side: int = 8, step: float = 3.0) -> np.ndarray:
    """A flat rigid model (k = 1): ``side x side`` vertices ``step`` pixels apart, ``(n, 3, 1)``."""
    g = (np.arange(side) - (side - 1) / 2.0) * step
    xx, yy = np.meshgrid(g, g)
    return np.stack([xx.ravel(), yy.ravel(), np.zeros(side * side)], axis=1)[:, :, None]


def _scene(rng: np.random.Generator):
    """A frame (120, 160) at 0.5 with a textured patch about (40, 60) (each pixel 0.5 +- 0.2) and a flat
    one about (110, 60); texels that correlate 0.4 with the textured patch at the vertices."""
    img = 0.5 + 0.005 * rng.standard_normal((120, 160))
    tex = np.where(rng.random((40, 40)) < 0.5, -0.2, 0.2)
    img[40:80, 20:60] = 0.5 + tex
    bases = _grid_model()
    on_face = make_pose(None, (40.0, 60.0), [1.0])
    pts = (bases[:, :2, 0] + on_face[3:5]).round().astype(int)
    y_face = img[pts[:, 1], pts[:, 0]]
    other = np.where(rng.random(y_face.size) < 0.5, -0.2, 0.2)
    # texels: 0.4 of the face's pattern and 0.6 of another (a look that has changed, as in a turn)
    mu = 0.5 + (0.4 * (y_face - 0.5) + np.sqrt(1 - 0.4 ** 2) * other)
    return img, bases, on_face, make_pose(None, (110.0, 60.0), [1.0]), mu


def test_the_local_background_prefers_the_textured_patch_the_object_term_alone_does_not() -> None:
    """Without a background the squared residual of texels that fit the face only partly is smaller on a
    flat patch; with the local background (both terms of eq. 14) the face, which the frame about it
    does not explain as background, wins."""
    img, bases, face, flat, mu = _scene(np.random.default_rng(5))
    fd = prepare_frame(img)
    poses = np.stack([face, flat])[None]  # (1, 2, P)
    tv = TextureView(mean=mu[None], var=np.full((1, mu.size), 1e-3))
    plain = log_likelihood(bases, fd, poses, tv, SIGMA_W)[0]
    local = log_likelihood(bases, fd, poses, TextureView(mean=tv.mean, var=tv.var, local=3.0), SIGMA_W)[0]
    assert plain[1] > plain[0], "the scene must show the flat patch winning the object term alone"
    assert local[0] > local[1]


def test_the_local_background_is_twice_the_negative_log_density_of_each_pixel() -> None:
    rng = np.random.default_rng(2)
    img = np.clip(0.5 + 0.1 * rng.standard_normal((30, 40)), 0, 1)
    b = local_background(img, 2.0, SIGMA_W)
    import cv2

    m = cv2.GaussianBlur(img, (0, 0), 2.0, borderType=cv2.BORDER_REFLECT)
    v = np.maximum(cv2.GaussianBlur((img - m) ** 2, (0, 0), 2.0, borderType=cv2.BORDER_REFLECT), SIGMA_W)
    assert b.shape == img.shape
    np.testing.assert_allclose(b, (img - m) ** 2 / v + np.log(v), rtol=1e-12)
    # a flat frame: every pixel at the floor, log sigma_w
    np.testing.assert_allclose(local_background(np.full((10, 10), 0.3), 2.0, SIGMA_W), np.log(SIGMA_W))


@pytest.mark.parametrize("shifts", [np.array([[0.0, 0.0], [2.0, -1.0], [-3.0, 4.0]]),
                                    np.array([[0.5, 0.25], [-1.5, 2.0]])])
def test_translation_sums_are_the_sums_of_the_shifted_samples(shifts) -> None:
    """Whole-pixel shifts (the lattice) and others (one by one) give the sums of the image sampled at each
    shifted vertex, vertices near and beyond the border included; translation_costs is unchanged."""
    rng = np.random.default_rng(3)
    img = rng.random((20, 30))
    x = rng.uniform(-3, 32, (4, 7))
    y = rng.uniform(-3, 22, (4, 7))
    got = translation_sums(img, x, y, shifts, block_vertices=10)
    want = np.array([[stencil_xy(x[e] + dx, y[e] + dy, img.shape).sample(img.reshape(-1)).sum() for dx, dy in shifts]
                     for e in range(4)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    mu, w = rng.random((4, 7)), rng.random((4, 7))
    cost = np.array([[(w[e] * (stencil_xy(x[e] + dx, y[e] + dy, img.shape).sample(img.reshape(-1)) - mu[e]) ** 2).sum()
                      for dx, dy in shifts] for e in range(4)])
    np.testing.assert_allclose(translation_costs(img, x, y, shifts, mu, w, block_vertices=10), cost, rtol=1e-10)


@pytest.mark.parametrize("value, match", [(-1.0, "local_background must be"), (float("nan"), "local_background must be"),
                                          (True, "local_background must be")])
def test_a_bad_local_background_is_refused_in_one_line(value, match) -> None:
    with pytest.raises(ValueError, match=match) as e:
        GFlowParams(local_background=value)
    assert "\n" not in str(e.value)


def test_the_local_and_the_generic_background_are_not_set_together() -> None:
    with pytest.raises(ValueError, match="set one"):
        GFlowParams(local_background=5.0, generic_background=True)
    assert GFlowParams(local_background=5.0).config().local_background == 5.0
    assert GFlowConfig.__dataclass_fields__["local_background"].default == 0.0
