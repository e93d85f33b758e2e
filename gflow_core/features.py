"""Image features: grey levels, gradients, Canny edges and chamfer images.

All functions are pure: they take arrays and return new arrays. Images are indexed
(row, col). The chamfer image is the distance transform of the edge map passed through
the chamfer profile g(.) of Toyama & Blake (2002), eq. 4-5:

    gamma(z, r) = min_{s'} g(|r_z(s') - r|)

with the quadratic profile g(u) = u^2 or the truncated profile g(u) = min(u^2, g0).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

__all__ = ["to_grey", "gradients", "edge_map", "distance_transform", "chamfer_image", "PROFILES"]

PROFILES = ("linear", "quadratic", "truncated")
Profile = Literal["linear", "quadratic", "truncated"]


def _check_image(img: np.ndarray, name: str = "image") -> np.ndarray:
    img = np.asarray(img)
    if img.ndim not in (2, 3) or img.shape[0] < 2 or img.shape[1] < 2:
        raise ValueError(f"{name} must be (H, W) or (H, W, C) with H, W >= 2, got shape {img.shape}")
    if img.ndim == 3 and img.shape[2] not in (1, 3, 4):
        raise ValueError(f"{name} must have 1, 3 or 4 channels, got {img.shape[2]}")
    if img.dtype.kind == "f" and not np.isfinite(img).all():
        raise ValueError(f"{name} contains NaN or inf")
    return img


def to_grey(img: np.ndarray) -> np.ndarray:
    """Convert an image to 8-bit grey levels.

    Parameters
    ----------
    img : (H, W) or (H, W, 3) uint8, BGR channel order (OpenCV's), or float in [0, 1].

    Returns
    -------
    (H, W) uint8
    """
    img = _check_image(img)
    if img.dtype != np.uint8:
        if img.dtype.kind == "f":
            img = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
        else:
            img = np.clip(img, 0, 255).astype(np.uint8)
    if img.ndim == 3:
        if img.shape[2] == 1:
            return np.ascontiguousarray(img[:, :, 0])
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return cv2.cvtColor(img, code)
    return np.ascontiguousarray(img)


def gradients(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sobel gradients of a grey image (3x3 kernels, per-pixel intensity units / 8).

    Parameters
    ----------
    grey : (H, W) uint8 or float

    Returns
    -------
    gx, gy : (H, W) float32
        d I / d col and d I / d row, scaled so that a unit ramp gives 1.
    """
    g = _check_image(grey, "grey").astype(np.float32)
    # Sobel 3x3 has gain 8 on a unit ramp; divide to get intensity per pixel.
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return gx, gy


def edge_map(grey: np.ndarray, low: float = 50.0, high: float = 150.0, blur: float = 1.0) -> np.ndarray:
    """Canny edge map.

    Parameters
    ----------
    grey : (H, W) uint8
    low, high : float
        Canny hysteresis thresholds on the Sobel magnitude (0-255 scale).
    blur : float
        Standard deviation (pixels) of a Gaussian pre-blur; 0 disables it.

    Returns
    -------
    (H, W) uint8, 255 on edges and 0 elsewhere.
    """
    g = to_grey(grey)
    if not (0 <= low <= high):
        raise ValueError(f"Canny thresholds must satisfy 0 <= low <= high, got low={low}, high={high}")
    if blur > 0:
        g = cv2.GaussianBlur(g, (0, 0), blur)
    return cv2.Canny(g, low, high, L2gradient=True)


def distance_transform(edges: np.ndarray) -> np.ndarray:
    """Euclidean distance from every pixel to the nearest edge pixel.

    Parameters
    ----------
    edges : (H, W) uint8 or bool, non-zero on edges.

    Returns
    -------
    (H, W) float32 distances in pixels. If there are no edges at all, every pixel gets
    the image diagonal (the largest distance any edge could be), not infinity.
    """
    e = _check_image(edges, "edge map")
    if e.ndim != 2:
        raise ValueError(f"edge map must be 2-D, got shape {e.shape}")
    if not e.any():
        diag = float(np.hypot(*e.shape))
        return np.full(e.shape, diag, dtype=np.float32)
    # distanceTransform measures distance to the nearest ZERO pixel, so invert.
    inv = np.where(e > 0, 0, 255).astype(np.uint8)
    return cv2.distanceTransform(inv, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def chamfer_image(edges: np.ndarray, profile: Profile = "truncated", g0: float = 100.0) -> np.ndarray:
    """Chamfer image gamma(z, r) of Toyama & Blake (2002), eq. 5.

    Parameters
    ----------
    edges : (H, W) uint8, non-zero on edges.
    profile : {"quadratic", "truncated", "linear"}
        ``quadratic``: g(u) = u^2; ``truncated``: g(u) = min(u^2, g0) (eq. 4 and text);
        ``linear``: g(u) = u (the classic chamfer of Gavrila & Philomin, for comparison).
    g0 : float
        Truncation level of the truncated profile, in squared pixels.

    Returns
    -------
    (H, W) float32
    """
    if profile not in PROFILES:
        raise ValueError(f"unknown chamfer profile {profile!r}; choose one of {PROFILES}")
    if profile == "truncated" and not g0 > 0:
        raise ValueError(f"truncation level g0 must be positive, got {g0}")
    u = distance_transform(edges)
    if profile == "linear":
        return u
    # g(u) = u^2
    g = u * u
    if profile == "truncated":
        # g(u) = min(u^2, g0)
        np.minimum(g, np.float32(g0), out=g)
    return g
