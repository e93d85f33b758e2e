"""Geometry of G-flow: the morphable model under weak perspective (eq. 1, 2).

A non-rigid object is ``n`` vertices; vertex ``i`` in all ``k`` morph bases is the
fixed ``3 x k`` matrix ``h_i``. With rotation ``r``, translation ``l`` and morph
coefficients ``c`` its image location is (eq. 1)::

    x_i = g r h_i c + l,        g = [[1, 0, 0], [0, 1, 0]]

Frames
------
Camera frame: ``x`` right, ``y`` down, ``z`` away from the camera (right-handed).
Image points are ``(x, y)`` in pixels with the origin at the centre of the top-left
pixel, so pixel ``(row, col)`` has its centre at ``(x, y) = (col, row)``. A surface
facing the camera has a normal with a negative ``z`` component.

Pose vector layout (``P = 5 + k`` float64; the paper's ``u_t = {r, l, c}``, eq. 2)
---------------------------------------------------------------------------------
=========  ===========  ===================================================
``ROT``    ``u[0:3]``   rotation vector ``w`` (axis * angle, radians);
                        ``r = exp([w]x)`` (Rodrigues)
``TRANS``  ``u[3:5]``   translation ``l = (l_x, l_y)`` in pixels
``COEF``   ``u[5:]``    morph coefficients ``c``, ``(k,)``
=========  ===========  ===================================================

Scale is folded into ``c``: the model bases are in model units and ``c`` is in pixels
per model unit. For a rigid model (``k = 1``) ``c`` is the scale, as in the paper's
rigid case; for ``k > 1`` multiplying ``c`` by ``s`` scales the shape by ``s``.

Increments
----------
Gauss-Newton, the Laplace covariance, the proposal samples and the pose transition
prior all live in the *tangent space* at a pose: an increment ``d`` has the same
layout, and ``u [+] d`` (:func:`box_plus`) is::

    r <- r exp([d_w]x)      (body-frame rotation increment)
    l <- l + d_l
    c <- c + d_c

:func:`box_minus` is its inverse: ``box_minus(a, b) = (log(r_a^T r_b), l_b - l_a,
c_b - c_a)`` so that ``box_plus(a, box_minus(a, b)) == b``. Keeping the rotation as
a rotation vector in the state and stepping through ``exp`` avoids gimbal lock and
keeps every pose a proper rotation.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

__all__ = [
    "ROT",
    "TRANS",
    "COEF",
    "N_RIGID",
    "pose_size",
    "pose_names",
    "make_pose",
    "rotation_matrices",
    "quaternion_matrices",
    "pose_quaternions",
    "relative_rotvecs",
    "rotvec_from_matrices",
    "skew",
    "box_plus",
    "box_minus",
    "shape_vertices",
    "project",
    "projection_jacobian",
    "rotation_angle_deg",
]

#: Rotation vector components of a pose vector (radians).
ROT = slice(0, 3)
#: Translation components of a pose vector (pixels).
TRANS = slice(3, 5)
#: Morph coefficient components of a pose vector.
COEF = slice(5, None)
#: Number of rigid components (3 rotation + 2 translation) before the coefficients.
N_RIGID = 5


def pose_size(k: int) -> int:
    """Length ``P = 5 + k`` of a pose vector for a model with ``k`` morph bases."""
    if k < 1:
        raise ValueError(f"a morphable model needs k >= 1 morph bases, got k={k}")
    return N_RIGID + int(k)


def pose_names(k: int) -> tuple[str, ...]:
    """Names of the pose components: ``('w_x', 'w_y', 'w_z', 'l_x', 'l_y', 'c_1', ...)``."""
    return ("w_x", "w_y", "w_z", "l_x", "l_y") + tuple(f"c_{j + 1}" for j in range(pose_size(k) - N_RIGID))


def make_pose(rotation: npt.ArrayLike | None, translation: npt.ArrayLike, coefficients: npt.ArrayLike) -> np.ndarray:
    """Build a pose vector ``u`` (eq. 2) from its parts.

    Parameters
    ----------
    rotation : (3, 3) float64 rotation matrix, (3,) rotation vector, or None (identity)
    translation : (2,) float64
        ``l`` in pixels.
    coefficients : (k,) float64
        Morph coefficients ``c`` (pixels per model unit).

    Returns
    -------
    u : (5 + k,) float64
    """
    if rotation is None:
        w = np.zeros(3)
    else:
        rot = np.asarray(rotation, dtype=np.float64)
        if rot.shape == (3, 3):
            w = Rotation.from_matrix(np.array(rot, copy=True)).as_rotvec()
        elif rot.shape == (3,):
            w = rot
        else:
            raise ValueError(f"rotation must be a (3, 3) matrix or a (3,) rotation vector, got shape {rot.shape}")
    l = np.asarray(translation, dtype=np.float64).reshape(-1)
    c = np.atleast_1d(np.asarray(coefficients, dtype=np.float64))
    if l.shape != (2,):
        raise ValueError(f"translation must have shape (2,), got {l.shape}")
    if c.ndim != 1 or c.size < 1:
        raise ValueError(f"coefficients must have shape (k,), k >= 1, got {c.shape}")
    u = np.concatenate([w, l, c])
    if not np.isfinite(u).all():
        raise ValueError("pose contains NaN or infinite values")
    return u


def rotation_matrices(poses: np.ndarray) -> np.ndarray:
    """Rotation matrices ``r = exp([w]x)`` of pose vectors (Rodrigues).

    Computed from the unit quaternion ``(v, s)`` of ``w`` as
    ``r_ab = sum_ij D_abij q_i q_j`` (``r = (s^2 - |v|^2) I + 2 v v^T + 2 s [v]x``), in plain
    numpy: scipy's ``Rotation`` costs several times more per call on the small batches of
    the Gauss-Newton loop.

    Parameters
    ----------
    poses : (..., P) float64

    Returns
    -------
    r : (..., 3, 3) float64
    """
    poses = np.asarray(poses, dtype=np.float64)
    return quaternion_matrices(_quaternions(poses[..., ROT]))


def quaternion_matrices(q: np.ndarray, rows: int = 3) -> np.ndarray:
    """The first ``rows`` rows of the rotation matrices of unit quaternions ``(..., 4)``
    ``(x, y, z, s)``: ``(..., rows, 3)``."""
    return np.einsum("...i,...j,abij->...ab", q, q, _ROT_QUAD[:rows])


def _rot_quad() -> np.ndarray:
    """``D`` with ``r_ab = sum_ij D_abij q_i q_j`` for a unit quaternion ``(x, y, z, s)``."""
    d = np.zeros((3, 3, 4, 4))
    x, y, z, s = range(4)
    for a, terms in enumerate(((((s, s), 1), ((x, x), 1), ((y, y), -1), ((z, z), -1)),
                               (((s, s), 1), ((x, x), -1), ((y, y), 1), ((z, z), -1)),
                               (((s, s), 1), ((x, x), -1), ((y, y), -1), ((z, z), 1)))):
        for (i, j), v in terms:
            d[a, a, i, j] += v
    # off-diagonal: 2 (v_a v_b -+ s v_c)
    for a, b, c, sign in ((0, 1, z, -1), (1, 0, z, 1), (0, 2, y, 1), (2, 0, y, -1), (1, 2, x, -1), (2, 1, x, 1)):
        d[a, b, a, b] += 1.0
        d[a, b, b, a] += 1.0
        d[a, b, s, c] += sign
        d[a, b, c, s] += sign
    return d


_ROT_QUAD = _rot_quad()


def _quaternions(w: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, s)`` of rotation vectors ``(..., 3) -> (..., 4)``."""
    h = 0.5 * np.sqrt((w * w).sum(axis=-1))  # theta / 2
    # sin(theta/2) w / theta; at theta = 0, w = 0 and so is the product
    k = 0.5 * np.sin(h) / np.maximum(h, 1e-300)
    return np.concatenate([k[..., None] * w, np.cos(h)[..., None]], axis=-1)


def _hamilton() -> np.ndarray:
    """``C`` with ``(p q)_i = sum_jk C_ijk p_j q_k`` for quaternions ``(x, y, z, s)``."""
    c = np.zeros((4, 4, 4))
    for i, j, k, v in ((0, 3, 0, 1), (0, 0, 3, 1), (0, 1, 2, 1), (0, 2, 1, -1),
                       (1, 3, 1, 1), (1, 0, 2, -1), (1, 1, 3, 1), (1, 2, 0, 1),
                       (2, 3, 2, 1), (2, 0, 1, 1), (2, 1, 0, -1), (2, 2, 3, 1),
                       (3, 3, 3, 1), (3, 0, 0, -1), (3, 1, 1, -1), (3, 2, 2, -1)):
        c[i, j, k] = v
    return c


_HAMILTON = _hamilton()
_CONJ = np.array([-1.0, -1.0, -1.0, 1.0])


def _quat_mul(p: np.ndarray, q: np.ndarray, conj_p: bool = False) -> np.ndarray:
    """Hamilton product ``p q`` (or ``p* q``) of quaternions ``(..., 4)`` ``(x, y, z, s)``.

    One ``einsum`` (its own loops, no BLAS: each row's sum is done in the same order
    whatever the batch, which the bit-exact sharding of the experts needs)."""
    if conj_p:
        p = p * _CONJ
    p, q = np.broadcast_arrays(p, q)
    return np.einsum("...j,...k,ijk->...i", p, q, _HAMILTON)


def pose_quaternions(poses: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, s)`` of the rotations of pose vectors ``(..., P) -> (..., 4)``."""
    return _quaternions(np.asarray(poses, dtype=np.float64)[..., ROT])


def relative_rotvecs(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """``log(r_a^T r_b)`` from unit quaternions ``(..., 4)`` (the rotation part of :func:`box_minus`)."""
    return _rotvecs(_quat_mul(qa, qb, conj_p=True))


def _rotvecs(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (angle in ``[0, pi]``) of unit quaternions ``(..., 4) -> (..., 3)``.

    ``2 atan2(|v|, |s|) v / |v|`` (the sign of ``q`` chosen so that ``s >= 0``); ``atan2`` keeps
    full relative precision at small angles, where the ratio tends to ``2 / s``."""
    v, s = q[..., :3], q[..., 3]
    nv = np.sqrt((v * v).sum(axis=-1))
    k = 2.0 * np.arctan2(nv, np.abs(s)) / np.maximum(nv, 1e-300)
    return np.where(s < 0.0, -k, k)[..., None] * v


def rotvec_from_matrices(r: np.ndarray) -> np.ndarray:
    """Rotation vectors ``log(r)`` of rotation matrices, ``(..., 3, 3) -> (..., 3)``."""
    r = np.asarray(r, dtype=np.float64)
    lead = r.shape[:-2]
    return Rotation.from_matrix(np.array(r.reshape(-1, 3, 3), copy=True)).as_rotvec().reshape(lead + (3,))


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` with ``[v]x a = v x a``; ``(..., 3) -> (..., 3, 3)``."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def box_plus(poses: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """Apply tangent-space increments: ``u [+] d`` (see the module docstring).

    Parameters
    ----------
    poses : (..., P) float64
    deltas : (..., P) float64
        Broadcast against ``poses``.

    Returns
    -------
    (..., P) float64
    """
    poses = np.asarray(poses, dtype=np.float64)
    deltas = np.asarray(deltas, dtype=np.float64)
    out = poses + deltas
    # r <- r exp([d_w]x)
    out[..., ROT] = _rotvecs(_quat_mul(_quaternions(poses[..., ROT]), _quaternions(deltas[..., ROT])))
    return out


def box_minus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Tangent-space difference ``d`` with ``a [+] d == b``.

    Parameters
    ----------
    a, b : (..., P) float64
        Broadcast against each other.

    Returns
    -------
    d : (..., P) float64
        ``(log(r_a^T r_b), l_b - l_a, c_b - c_a)``.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    out = b - a
    # d_w = log(r_a^T r_b)
    out[..., ROT] = relative_rotvecs(_quaternions(a[..., ROT]), _quaternions(b[..., ROT]))
    return out


def shape_vertices(bases: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """3-D vertices ``h_i c`` of the morphable model in model coordinates (scaled by c).

    Parameters
    ----------
    bases : (n, 3, k) float64
        ``h_i`` stacked over vertices.
    coefficients : (..., k) float64

    Returns
    -------
    (..., n, 3) float64
    """
    c = np.asarray(coefficients, dtype=np.float64)
    lead = c.shape[:-1]
    n, _, k = bases.shape
    # h_i c for every vertex:  (n*3, k) @ (k, N) -> (n*3, N)
    s = bases.reshape(n * 3, k) @ c.reshape(-1, k).T
    return np.ascontiguousarray(s.T.reshape(lead + (n, 3)))


def project(bases: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Project the model vertices for many poses at once (eq. 1).

    Parameters
    ----------
    bases : (n, 3, k) float64
        Morph bases ``h_i``.
    poses : (..., P) float64
        Pose vectors (layout in the module docstring).

    Returns
    -------
    x : (..., n, 2) float64
        ``x_i = g r h_i c + l`` in pixels, ``(x, y)``, origin at the top-left pixel centre.
    """
    poses = np.asarray(poses, dtype=np.float64)
    lead = poses.shape[:-1]
    u = poses.reshape(-1, poses.shape[-1])
    # x_i = g r (h_i c) + l
    x = project_untranslated(bases, u) + u[:, None, TRANS]
    return x.reshape(lead + (bases.shape[0], 2))


def project_untranslated(bases: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """``g r (h_i c)``, the projection of eq. 1 before the translation ``l`` is added:
    ``project(bases, u) == project_untranslated(bases, u) + l`` exactly, so poses that differ
    only in ``l`` can share it.

    Parameters
    ----------
    bases : (n, 3, k) float64
    poses : (N, P) float64

    Returns
    -------
    (N, n, 2) float64
    """
    s = shape_vertices(bases, poses[:, COEF])  # (N, n, 3)
    g_r = rotation_matrices(poses)[:, :2, :]  # (N, 2, 3) = g r
    return s @ g_r.transpose(0, 2, 1)


def projection_jacobian(bases: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Jacobian of the projected vertices wrt a tangent-space increment at each pose.

    With ``x_i(u [+] d) = g r exp([d_w]x) h_i (c + d_c) + l + d_l`` (eq. 1), at ``d = 0``::

        dx_i/dd_w = -g r [h_i c]x        (2 x 3)
        dx_i/dd_l = I_2                  (2 x 2)
        dx_i/dd_c = g r h_i              (2 x k)

    Parameters
    ----------
    bases : (n, 3, k) float64
    poses : (E, P) float64

    Returns
    -------
    J : (E, n, 2, P) float64
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2:
        raise ValueError(f"poses must have shape (E, P), got {poses.shape}")
    E, P = poses.shape
    n, _, k = bases.shape
    g_r = rotation_matrices(poses)[:, :2, :]  # (E, 2, 3)
    s = shape_vertices(bases, poses[:, COEF])  # (E, n, 3)
    J = np.zeros((E, n, 2, P))
    # dx_i/dd_w = -g r [s_i]x ; row a of -r [s]x is s x r_a (r_a = row a of r)
    J[:, :, 0, ROT] = np.cross(s, g_r[:, None, 0, :])
    J[:, :, 1, ROT] = np.cross(s, g_r[:, None, 1, :])
    # dx_i/dd_l = I_2
    J[:, :, 0, 3] = 1.0
    J[:, :, 1, 4] = 1.0
    # dx_i/dd_c = g r h_i :  (E, 2, 3) @ (3, n*k) -> (E, 2, n, k)
    hc = (g_r @ bases.transpose(1, 0, 2).reshape(3, n * k)).reshape(E, 2, n, k)
    J[..., COEF] = hc.transpose(0, 2, 1, 3)
    return J


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees of the rotation between the rotations of poses ``a`` and ``b``.

    Parameters
    ----------
    a, b : (..., P) float64 pose vectors

    Returns
    -------
    (...) float64, ``|log(r_a^T r_b)|`` in degrees.
    """
    d = box_minus(a, b)[..., ROT]
    return np.degrees(np.linalg.norm(d, axis=-1))
