"""Chamfer distance from a chamfer image (Toyama & Blake 2002, eq. 4-5).

    rho(z~, z) = integral ds gamma(z, r_z~(s))                                    (5)

The integral along the exemplar curve is approximated by the *mean* of gamma over the
curve's sample points (i.e. ds = 1 / P). Dividing by the curve length keeps lambda
comparable between exemplars with different numbers of points; it only rescales rho, so
the dimension d of eq. 10 is unchanged and sigma absorbs the factor.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sample_bilinear", "chamfer_distance"]


def sample_bilinear(img: np.ndarray, pts: np.ndarray, outside: float) -> np.ndarray:
    """Bilinear samples of ``img`` at sub-pixel points.

    Parameters
    ----------
    img : (H, W) float32 or float64, indexed (row, col).
    pts : (..., 2) float64, (x, y) pixel coordinates, origin at the top-left pixel centre.
    outside : float
        Value returned for points outside ``[0, W-1] x [0, H-1]``.

    Returns
    -------
    (...) float64
    """
    h, w = img.shape
    x = pts[..., 0]
    y = pts[..., 1]
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    xc = np.clip(x, 0, w - 1.000001)
    yc = np.clip(y, 0, h - 1.000001)
    x0 = xc.astype(np.intp)
    y0 = yc.astype(np.intp)
    fx = xc - x0
    fy = yc - y0
    flat = img.ravel()
    i00 = y0 * w + x0
    v00 = flat[i00]
    v01 = flat[i00 + 1]
    v10 = flat[i00 + w]
    v11 = flat[i00 + w + 1]
    top = v00 + (v01 - v00) * fx
    bot = v10 + (v11 - v10) * fx
    val = top + (bot - top) * fy
    return np.where(inside, val, outside)


def chamfer_distance(chamfer_img: np.ndarray, curves: np.ndarray, n_points: np.ndarray | None = None,
                     outside: float | None = None) -> np.ndarray:
    """Chamfer distance (eq. 5) of transformed curves against one image.

    Parameters
    ----------
    chamfer_img : (H, W) float32
        gamma(z, .) from :func:`gflow_core.features.chamfer_image`.
    curves : (N, P, 2) float64
        Transformed exemplar points T_alpha x~_k, (x, y) pixels. Curves shorter than P
        are padded; pass their true lengths in ``n_points``.
    n_points : (N,) int, optional
        Number of valid points of each curve (the first ``n_points[i]`` are used).
    outside : float, optional
        gamma assigned to points outside the image; defaults to the image maximum
        (the truncation level g0 for the truncated profile).

    Returns
    -------
    rho : (N,) float64
    """
    img = np.asarray(chamfer_img)
    if img.ndim != 2:
        raise ValueError(f"chamfer image must be 2-D, got shape {img.shape}")
    curves = np.asarray(curves, dtype=np.float64)
    if curves.ndim != 3 or curves.shape[2] != 2:
        raise ValueError(f"curves must be (N, P, 2), got shape {curves.shape}")
    if outside is None:
        outside = float(img.max())
    g = sample_bilinear(img, curves, outside)
    if n_points is None:
        # rho = (1/P) sum_s gamma(z, r(s))
        return g.mean(axis=1)
    n_points = np.asarray(n_points)
    mask = np.arange(curves.shape[1])[None, :] < n_points[:, None]
    # rho = (1/P_k) sum_{s < P_k} gamma(z, r(s))
    return (g * mask).sum(axis=1) / np.maximum(n_points, 1)
