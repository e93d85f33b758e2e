"""G-flow's local background (``GFlowConfig.local_background``): the object's data term weighed against
the frame read about each pixel, so a flat patch gains nothing by being claimed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gflow_core.gflow.filter import GFlowConfig
from gflow_core.gflow.geometry import make_pose
from gflow_core.gflow.image import prepare_frame
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


def test_the_objective_the_chains_are_compared_by_subtracts_half_the_local_terms_at_the_vertices() -> None:
    """eq. 14 with the local background: the object's objective minus 1/2 sum_i B(x_i), B the local
    background's two terms of each pixel, bilinearly read at the vertices."""
    from gflow_core.gflow.image import stencil_xy
    from gflow_core.gflow.pose_opinion import gauss_newton_objective

    img, bases, face, flat, mu = _scene(np.random.default_rng(5))
    fd = prepare_frame(img)
    poses = np.stack([face, flat])
    tv = TextureView(mean=np.stack([mu, mu]), var=np.full((2, mu.size), 1e-3))
    std = np.full(poses.shape[1], 5.0)
    plain = gauss_newton_objective(bases, fd, poses, poses, tv, SIGMA_W, std)
    local = gauss_newton_objective(bases, fd, poses, poses, TextureView(mean=tv.mean, var=tv.var, local=3.0),
                                   SIGMA_W, std)
    b = local_background(img, 3.0, SIGMA_W)
    for row, pose in enumerate(poses):
        pts = bases[:, :2, 0] + pose[3:5]
        at = stencil_xy(pts[:, 0], pts[:, 1], img.shape).sample(b.reshape(-1))
        np.testing.assert_allclose(local[row], plain[row] - 0.5 * at.sum(), rtol=1e-10)
    assert local[0] < local[1] and plain[0] > plain[1]


def test_shards_of_the_experts_propose_as_one_batch_with_the_local_background() -> None:
    """The local background is read from the frame alone: proposals made for two shards of the experts
    are those of one call, bit for bit (the pipeline's proposal processes), and differ from the
    proposals without it."""
    from gflow_core.gflow import model_setup
    from gflow_core.gflow.filter import init_state, propose
    from gflow_core.gflow.synthetic_head import synthetic_sequence
    from gflow_core.gflow.tracker import observation
    from gflow_scenes import SYNTH

    seq = synthetic_sequence(np.random.default_rng(3), n_frames=2, image_shape=(60, 80))
    grey = np.rint(seq.frames * 255).astype(np.uint8)
    params = GFlowParams(**dict(SYNTH, n_experts=6, local_background=4.0, init_jitter=(0.05, 2.0, 0.02)))
    setup = model_setup(params, seq.box, grey.shape[1:])
    y0, y1 = observation(grey[0], setup.contrast_sigma), observation(grey[1], setup.contrast_sigma)
    state = init_state(setup.model, setup.pose0, y0, setup.cfg, rng=np.random.default_rng(1),
                       pose_jitter_std=np.r_[np.full(3, 0.05), np.full(2, 2.0), 0.02 * abs(setup.pose0[5:])])

    def rngs(idx):
        return [np.random.default_rng([7, int(i)]) for i in idx]

    whole = propose(state, y1, setup.model, setup.cfg, rngs(range(6)), None, 3.0)
    parts = [propose(state, y1, setup.model, setup.cfg, rngs(ix), ix, 3.0) for ix in ([0, 1, 2], [3, 4, 5])]
    for name in ("u_hat", "samples", "log_weights", "log_evidence", "gn_objective"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name))
    off = dataclasses.replace(setup.cfg, local_background=0.0)
    assert not np.array_equal(propose(state, y1, setup.model, off, rngs(range(6)), None, 3.0).log_weights,
                              whole.log_weights)
