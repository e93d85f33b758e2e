"""Learning a morphable model from landmark tracks (gflow_core/gflow/morphable_learn.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import subspace_angles
from scipy.spatial.transform import Rotation

from gflow_core.gflow.geometry import make_pose, project
from gflow_core.gflow.head_model import pose_for_box
from gflow_core.gflow.morphable_learn import (
    _rigid_generators,
    choose_vertices,
    frontal_rotation,
    learn_morphable,
    procrustes_align,
)


def _face_like(rng: np.random.Generator, n: int = 60) -> np.ndarray:
    """A non-planar point cloud (n, 3) with four 'eye and mouth' points 0..3 facing -z."""
    pts = rng.uniform(-1.0, 1.0, (n, 3)) * np.array([0.4, 0.5, 0.15])
    pts[:, 2] -= 0.3 * (1.0 - pts[:, 0] ** 2 / 0.16)  # bulges toward the camera in the middle
    pts[:4] = [[-0.25, -0.2, 0.0], [0.25, -0.2, 0.0], [-0.15, 0.25, 0.0], [0.15, 0.25, 0.0]]
    return pts - pts.mean(axis=0)


def _tracks(rng, mean, bases, amps, T, noise=0.0, max_deg=35.0):
    """Frames of ``s R (mean + sum a_j B_j) + l`` in pixels; returns (tracks, scales, rotations, coefs)."""
    a = rng.standard_normal((T, len(amps))) * np.asarray(amps)
    shapes = mean[None] + np.einsum("tj,jnx->tnx", a, bases)
    rot = Rotation.from_rotvec(rng.standard_normal((T, 3)) * np.radians(max_deg) / 2).as_matrix()
    s = rng.uniform(40.0, 90.0, T)
    l = rng.uniform(50.0, 250.0, (T, 3))
    x = s[:, None, None] * np.einsum("tij,tnj->tni", rot, shapes) + l[:, None, :]
    return x + noise * rng.standard_normal(x.shape), s, rot, a


def _deformations(rng, mean, k1):
    """k1 orthonormal deformations of ``mean`` (no scale, rotation or translation in them), (k1, n, 3)."""
    g = _rigid_generators(mean)
    b = rng.standard_normal((mean.size, k1))
    b -= g @ (g.T @ b)
    q, _ = np.linalg.qr(b)
    return q.T.reshape(k1, *mean.shape) * np.sqrt((mean * mean).sum())


def test_rigid_copies_align_exactly() -> None:
    rng = np.random.default_rng(0)
    mean = _face_like(rng)
    x, *_ = _tracks(rng, mean, np.zeros((0, *mean.shape)), [], 20)
    aligned, ref, scales, cen = procrustes_align(x)
    np.testing.assert_allclose(aligned, np.broadcast_to(ref, aligned.shape), atol=1e-10)
    assert np.sqrt((ref * ref).sum()) == pytest.approx(1.0)
    np.testing.assert_allclose(cen, x.mean(axis=1), atol=1e-12)


def test_bases_are_recovered_up_to_a_rotation_of_the_subspace() -> None:
    rng = np.random.default_rng(1)
    mean = _face_like(rng, 80)
    true = _deformations(rng, mean, 3)
    amps = [0.06, 0.035, 0.015]
    x, *_ = _tracks(rng, mean, true, amps, 300, noise=0.01)
    face = learn_morphable([x], k=4, frontal=None, keep=())
    m = face.model
    assert m.n_bases == 4 and m.n_vertices == 80
    np.testing.assert_array_equal(m.landmarks, np.arange(80))
    # the learned model is the truth turned and scaled: find that similarity from the means
    learned_mean = m.bases[:, :, 0]
    u, sv, vt = np.linalg.svd(learned_mean.T @ mean)
    r = u @ vt
    s = sv.sum() / (learned_mean * learned_mean).sum()
    np.testing.assert_allclose(s * learned_mean @ r, mean, atol=2e-3)
    learned = np.stack([(m.bases[:, :, j] @ r).reshape(-1) for j in range(1, 4)], axis=1)
    angles = np.degrees(subspace_angles(learned, true.reshape(3, -1).T))
    assert angles.max() < 3.0, angles
    # each basis lines up with the true one of the same rank (distinct amplitudes)
    for j in range(3):
        cos = abs(learned[:, j] @ true[j].reshape(-1)) / np.linalg.norm(learned[:, j]) / np.linalg.norm(true[j])
        assert cos > 0.99, (j, cos)
    assert np.all(np.diff(face.explained) < 0) and face.explained.sum() > 0.95
    # the spread of c_j / c_1 is the amplitude (in units of the mean's norm)
    np.testing.assert_allclose(m.morph_std[1:], amps, rtol=0.15)
    assert m.morph_std[0] == 0.0
    # a unit change of any coefficient moves the vertices by the same RMS distance as the scale's
    norms = np.sqrt((m.bases ** 2).sum(axis=(0, 1)))
    np.testing.assert_allclose(norms, norms[0], rtol=1e-12)


def test_frontal_frame_unit_height_and_frames_with_nan_left_out() -> None:
    rng = np.random.default_rng(2)
    mean = _face_like(rng)
    nose = np.array([[0.0, 0.0, -0.4]])
    mean = np.concatenate([mean, nose - nose.mean(axis=0) * 0])
    x, *_ = _tracks(rng, mean, np.zeros((0, *mean.shape)), [], 30)
    x[[3, 7]] = np.nan
    face = learn_morphable([x], k=1, frontal=(0, 1, 2, 3), keep=())
    assert face.frames == 28
    b = face.model.bases[:, :, 0]
    eye = b[1] - b[0]
    assert eye[0] > 0 and abs(eye[1]) < 1e-9 and abs(eye[2]) < 1e-9  # eye line along +x
    assert (b[2, 1] + b[3, 1]) / 2 > (b[0, 1] + b[1, 1]) / 2  # the mouth below the eyes (+y down)
    assert b[-1, 2] < b[:-1, 2].mean()  # the nose toward the camera (-z)
    assert b[:, 1].max() - b[:, 1].min() == pytest.approx(1.0)  # one unit high
    np.testing.assert_allclose(b.mean(axis=0), 0.0, atol=1e-12)
    r = frontal_rotation(b, (0, 1, 2, 3))
    np.testing.assert_allclose(r, np.eye(3), atol=1e-9)


def test_vertex_choice_keeps_the_scored_landmarks_and_spreads_the_rest() -> None:
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 1, (400, 2))
    keep = (5, 17, 123)
    sel = choose_vertices(p, 40, keep)
    assert sel.size == 40 and set(keep) <= set(sel.tolist()) and np.all(np.diff(sel) > 0)
    np.testing.assert_array_equal(sel, choose_vertices(p, 40, keep))  # deterministic

    def min_gap(idx):
        d = np.linalg.norm(p[idx, None] - p[None, idx], axis=-1)
        return d[np.triu_indices(len(idx), 1)].min()

    others = [i for i in sel if i not in keep]
    randoms = [min_gap(rng.choice(400, len(others), replace=False)) for _ in range(20)]
    assert min_gap(others) > max(randoms)
    np.testing.assert_array_equal(choose_vertices(p, None), np.arange(400))
    with pytest.raises(ValueError, match="at least"):
        choose_vertices(p, 2, keep)


def test_reference_box_places_the_model_where_the_user_box_sits() -> None:
    rng = np.random.default_rng(4)
    mean = _face_like(rng)
    x, s, rot, _ = _tracks(rng, mean, np.zeros((0, *mean.shape)), [], 40, max_deg=0.0)
    # the user's box: a fixed box in face units about the centroid, in every frame
    rel = np.array([-0.3, -0.35, 0.55, 0.7])
    cen = x[:, :, :2].mean(axis=1)
    boxes = np.concatenate([cen + s[:, None] * rel[:2], s[:, None] * rel[2:]], axis=1)
    face = learn_morphable([x], k=1, frontal=(0, 1, 2, 3), boxes=[boxes], keep=())
    m = face.model
    # placed in frame 5's box, the model's points fall on frame 5's landmarks (frontal, no rotation)
    pose = pose_for_box(m, boxes[5], (480, 640))
    pts = project(m.bases, pose)
    np.testing.assert_allclose(pts, x[5, :, :2], atol=1e-6)


def test_learning_rejects_what_it_cannot_use() -> None:
    rng = np.random.default_rng(5)
    x = rng.standard_normal((10, 20, 3))
    with pytest.raises(ValueError, match="no frame has all"):
        learn_morphable([np.full((3, 20, 3), np.nan)], k=1, frontal=None)
    with pytest.raises(ValueError, match="at least 6 frames"):
        learn_morphable([x[:5]], k=6, frontal=None)
    with pytest.raises(ValueError, match="same landmark layout"):
        learn_morphable([x, x[:, :10]], k=2, frontal=None)
    with pytest.raises(ValueError, match=r"\(frames, landmarks, 3\)"):
        learn_morphable([x[:, :, :2]], k=2, frontal=None)
    with pytest.raises(ValueError, match="frontal landmarks"):
        learn_morphable([x], k=2, frontal=(0, 1, 2, 99))
    assert make_pose(None, [0, 0], [1.0]).shape == (6,)
