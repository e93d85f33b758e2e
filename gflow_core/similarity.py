"""Euclidean similarity transforms T_alpha, alpha = (u, theta, s) (Toyama & Blake 2002, sec. 3.2).

    T_alpha r = u + R(theta) s r

Points are (x, y) in pixels with the origin at the top-left pixel centre. A transform is
stored as a length-4 vector ``alpha = (ux, uy, theta, s)`` with ``theta`` in radians,
counter-clockwise in the image as displayed with y down (i.e. R(theta) = [[c, -s], [s, c]]
applied to (x, y)), and ``s > 0``. Arrays of transforms are (N, 4).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["ALPHA_DIM", "IDENTITY", "apply", "apply_many", "invert", "compose", "to_affine", "warp_patch", "check_alpha"]

ALPHA_DIM = 4
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def check_alpha(alpha: np.ndarray) -> np.ndarray:
    """Validate transforms: (4,) or (N, 4), finite, positive scale."""
    a = np.asarray(alpha, dtype=np.float64)
    if a.shape[-1] != ALPHA_DIM or a.ndim not in (1, 2):
        raise ValueError(f"alpha must be (4,) or (N, 4) = (ux, uy, theta, s), got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError("alpha contains NaN or inf")
    if (a[..., 3] <= 0).any():
        raise ValueError("alpha scale s must be positive")
    return a


def apply(alpha: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply one transform to points.

    Parameters
    ----------
    alpha : (4,) float64
    pts : (P, 2) float64, (x, y)

    Returns
    -------
    (P, 2) float64
    """
    return apply_many(np.asarray(alpha, dtype=np.float64)[None], pts)[0]


def apply_many(alpha: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply N transforms to one point set (or N point sets).

    Parameters
    ----------
    alpha : (N, 4) float64
    pts : (P, 2) or (N, P, 2) float64

    Returns
    -------
    (N, P, 2) float64
    """
    a = np.asarray(alpha, dtype=np.float64)
    p = np.asarray(pts, dtype=np.float64)
    c = np.cos(a[:, 2]) * a[:, 3]
    s = np.sin(a[:, 2]) * a[:, 3]
    if p.ndim == 2:
        x, y = p[None, :, 0], p[None, :, 1]
    else:
        x, y = p[..., 0], p[..., 1]
    # T_alpha r = u + R(theta) s r
    out = np.empty(np.broadcast_shapes(x.shape, (a.shape[0], 1)) + (2,), dtype=np.float64)
    out[..., 0] = a[:, 0:1] + c[:, None] * x - s[:, None] * y
    out[..., 1] = a[:, 1:2] + s[:, None] * x + c[:, None] * y
    return out


def invert(alpha: np.ndarray) -> np.ndarray:
    """Inverse transform: T_{inv(alpha)} T_alpha r = r. (4,) or (N, 4) -> same shape."""
    a = np.atleast_2d(np.asarray(alpha, dtype=np.float64))
    th = -a[:, 2]
    s = 1.0 / a[:, 3]
    c, sn = np.cos(th) * s, np.sin(th) * s
    # r = R(-theta)/s (z - u)
    ux = -(c * a[:, 0] - sn * a[:, 1])
    uy = -(sn * a[:, 0] + c * a[:, 1])
    out = np.stack([ux, uy, th, s], axis=1)
    return out[0] if np.ndim(alpha) == 1 else out


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Composition T_a T_b (apply b first). (4,) x (4,) -> (4,)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    u = apply(a, b[None, :2])[0]
    return np.array([u[0], u[1], a[2] + b[2], a[3] * b[3]])


def to_affine(alpha: np.ndarray) -> np.ndarray:
    """2x3 affine matrix of T_alpha, for ``cv2.warpAffine``. (4,) -> (2, 3) float64."""
    ux, uy, th, s = np.asarray(alpha, dtype=np.float64)
    c, sn = np.cos(th) * s, np.sin(th) * s
    return np.array([[c, -sn, ux], [sn, c, uy]])


def warp_patch(img: np.ndarray, alpha: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Induced transform on patches, I_z(T_alpha r) = I_x(r) (sec. 3.2), sampled the other way.

    Returns the patch x of the given ``shape`` = (rows, cols) with x(r) = z(T_alpha r), where
    r ranges over patch pixel centres (x, y) relative to the patch centre.

    Parameters
    ----------
    img : (H, W) image z
    alpha : (4,) transform placing the patch centre at u.
    shape : (rows, cols)

    Returns
    -------
    (rows, cols) float32, bilinear samples, border replicated.
    """
    rows, cols = shape
    a = check_alpha(alpha)
    # patch pixel (c, r) -> centred coords (c - cx, r - cy) -> image via T_alpha
    centre = np.array([0.0, 0.0, 0.0, 1.0])
    centre[:2] = [-(cols - 1) / 2.0, -(rows - 1) / 2.0]
    m = to_affine(compose(a, centre))
    # cv2.warpAffine with WARP_INVERSE_MAP samples dst(x, y) = src(M [x, y, 1]).
    return cv2.warpAffine(np.asarray(img, dtype=np.float32), m, (cols, rows),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
