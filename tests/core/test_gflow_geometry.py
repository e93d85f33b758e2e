"""G-flow geometry: weak perspective projection (eq. 1), tangent-space poses, Jacobians."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from gflow_core.gflow.geometry import (
    COEF,
    N_RIGID,
    ROT,
    TRANS,
    box_minus,
    box_plus,
    make_pose,
    pose_names,
    pose_size,
    project,
    projection_jacobian,
    rotation_angle_deg,
    rotation_matrices,
    skew,
)


def random_bases(rng: np.random.Generator, n: int = 11, k: int = 3) -> np.ndarray:
    return rng.normal(size=(n, 3, k))


def random_pose(rng: np.random.Generator, k: int, angle: float = 0.6) -> np.ndarray:
    w = rng.normal(size=3)
    w *= rng.uniform(0.05, angle) / np.linalg.norm(w)
    return make_pose(w, rng.uniform(20, 200, 2), rng.uniform(20.0, 60.0, k))


def test_pose_layout_constants() -> None:
    assert (ROT, TRANS, COEF, N_RIGID) == (slice(0, 3), slice(3, 5), slice(5, None), 5)
    assert pose_size(1) == 6 and pose_size(4) == 9
    assert pose_names(2) == ("w_x", "w_y", "w_z", "l_x", "l_y", "c_1", "c_2")
    u = make_pose(np.array([0.1, 0.2, 0.3]), np.array([4.0, 5.0]), np.array([6.0, 7.0]))
    np.testing.assert_array_equal(u[ROT], [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(u[TRANS], [4.0, 5.0])
    np.testing.assert_array_equal(u[COEF], [6.0, 7.0])
    with pytest.raises(ValueError, match="k >= 1"):
        pose_size(0)


def test_make_pose_accepts_matrix_and_rejects_bad_input() -> None:
    R = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()
    u = make_pose(R, [1.0, 2.0], [3.0])
    np.testing.assert_allclose(rotation_matrices(u), R, atol=1e-12)
    with pytest.raises(ValueError, match="rotation"):
        make_pose(np.eye(2), [0, 0], [1])
    with pytest.raises(ValueError, match="translation"):
        make_pose(None, [0, 0, 0], [1])
    with pytest.raises(ValueError, match="NaN"):
        make_pose(None, [np.nan, 0], [1])


def test_project_matches_eq1_vertex_by_vertex() -> None:
    rng = np.random.default_rng(0)
    bases = random_bases(rng)
    u = random_pose(rng, 3)
    g = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    r = Rotation.from_rotvec(u[ROT]).as_matrix()
    expected = np.array([g @ r @ h @ u[COEF] + u[TRANS] for h in bases])  # x_i = g r h_i c + l
    np.testing.assert_allclose(project(bases, u), expected, rtol=1e-12, atol=1e-9)


def test_project_is_vectorised_over_any_leading_shape() -> None:
    rng = np.random.default_rng(1)
    bases = random_bases(rng, n=7, k=2)
    poses = np.stack([[random_pose(rng, 2) for _ in range(4)] for _ in range(3)])  # (3, 4, P)
    x = project(bases, poses)
    assert x.shape == (3, 4, 7, 2)
    for a in range(3):
        for b in range(4):
            np.testing.assert_allclose(x[a, b], project(bases, poses[a, b]), rtol=0, atol=1e-12)


def test_box_plus_is_body_frame_exponential() -> None:
    rng = np.random.default_rng(2)
    u = random_pose(rng, 2)
    d = rng.normal(size=u.size) * 0.3
    v = box_plus(u, d)
    # r <- r expm([d_w]x)
    np.testing.assert_allclose(rotation_matrices(v), rotation_matrices(u) @ expm(skew(d[ROT])), atol=1e-12)
    np.testing.assert_allclose(v[3:], u[3:] + d[3:], atol=1e-12)  # l + d_l, c + d_c


def test_box_minus_inverts_box_plus_including_near_pi() -> None:
    rng = np.random.default_rng(3)
    a = np.stack([random_pose(rng, 1, angle=3.0) for _ in range(50)])
    d = rng.normal(size=a.shape)
    d[:, ROT] *= 3.1 / np.linalg.norm(d[:, ROT], axis=1, keepdims=True) * rng.uniform(0, 1, (50, 1))
    b = box_plus(a, d)
    np.testing.assert_allclose(box_minus(a, b), d, atol=1e-9)
    np.testing.assert_allclose(rotation_matrices(box_plus(a, box_minus(a, b))), rotation_matrices(b), atol=1e-12)
    assert np.all(rotation_angle_deg(a, a) < 1e-6)


@pytest.mark.parametrize("k", [1, 3])
def test_projection_jacobian_matches_finite_differences(k: int) -> None:
    rng = np.random.default_rng(10 + k)
    bases = random_bases(rng, n=9, k=k)
    poses = np.stack([random_pose(rng, k, angle=2.5) for _ in range(4)])
    J = projection_jacobian(bases, poses)
    P = poses.shape[1]
    assert J.shape == (4, 9, 2, P)
    h = 1e-6
    for p in range(P):
        e = np.zeros(P)
        e[p] = h
        # central difference of x_i(u [+] d) along tangent component p
        fd = (project(bases, box_plus(poses, e)) - project(bases, box_plus(poses, -e))) / (2 * h)
        np.testing.assert_allclose(J[..., p], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
