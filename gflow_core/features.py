"""Image features: grey levels, gradients, Canny edges and chamfer images.

All functions are pure: they take arrays and return new arrays. Images are indexed
(row, col). The chamfer image is the distance transform of the edge map passed through
the chamfer profile g(.) of Toyama & Blake (2002), eq. 4-5:

    gamma(z, r) = min_{s'} g(|r_z(s') - r|)

with the quadratic profile g(u) = u^2 or the truncated profile g(u) = min(u^2, g0).

Departure (off by default, ``preprocess.match_resolution``): :func:`resampled_edges` computes the
edges and the chamfer image on the frame resampled by a factor f, one level of an image pyramid, and
reads them back on the frame's grid, so an M2 model meets a target larger than its training targets
at its own resolution; the paper matches at the frame's resolution.
"""

from __future__ import annotations

import math
from typing import Literal

import cv2
import numpy as np

__all__ = ["to_grey", "to_uint8", "gradients", "gaussian_blur", "edge_map", "auto_canny_thresholds", "distance_transform", "chamfer_image",
           "canny_calibrated", "box_pixels", "MIN_CALIBRATION_SIDE", "edges_and_chamfer", "resampled_edges", "resample_grey", "resampled_size",
           "upsample_to", "PROFILES"]

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


def to_uint8(img: np.ndarray) -> np.ndarray:
    """An image as uint8, channels kept: float images are taken in [0, 1], integer ones clipped to
    [0, 255]. Raises ``ValueError`` for an array that is not an image (:func:`to_grey`'s rules)."""
    img = _check_image(img)
    if img.dtype != np.uint8:
        if img.dtype.kind == "f":
            img = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
        else:
            img = np.clip(img, 0, 255).astype(np.uint8)
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
    img = to_uint8(img)
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


#: the pixels a side of the image the box the Canny thresholds are calibrated on must cover
MIN_CALIBRATION_SIDE = 2


def box_pixels(box: tuple[float, float, float, float], width: int, height: int) -> tuple[int, int, int, int]:
    """(c0, r0, c1, r1): the columns c0..c1 - 1 and rows r0..r1 - 1 of a ``width`` x ``height`` image that the box
    (x, y, w, h) covers, a pixel counted when the box reaches into it (c1 - c0 <= 0: none)."""
    x, y, w, h = box
    c0, r0 = max(int(x), 0), max(int(y), 0)
    return c0, r0, min(int(np.ceil(x + w)), width), min(int(np.ceil(y + h)), height)


def auto_canny_thresholds(grey: np.ndarray, percentile: float = 85.0, ratio: float = 0.4,
                          box: tuple[float, float, float, float] | None = None) -> tuple[float, float]:
    """Adaptive Canny thresholds: ``high`` is a percentile of the Sobel gradient magnitude
    (the same 3x3 L2 magnitude that Canny thresholds), ``low = ratio * high``.

    With ``box`` = (x, y, w, h) the percentile is taken over the pixels of that box only:
    the thresholds are calibrated on the target. Fixed thresholds find no edge on a dim,
    low-contrast target (OTB "Crossing"), and a whole-image percentile floods a smooth
    textured background with edges; calibrating on the target avoids both.
    """
    g = np.asarray(grey, dtype=np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    mag = cv2.magnitude(gx, gy)
    if box is not None:
        H, W = mag.shape
        c0, r0, c1, r1 = box_pixels(box, W, H)
        m = MIN_CALIBRATION_SIDE
        if c1 - c0 < m or r1 - r0 < m:
            raise ValueError(f"the box {','.join(f'{v:g}' for v in box)} covers {max(c1 - c0, 0)}x{max(r1 - r0, 0)} "
                             f"pixels of the {W}x{H} image: the edges' thresholds are calibrated on at least {m}x{m} "
                             f"of its pixels")
        mag = mag[r0:r1, c0:c1]
    high = max(float(np.percentile(mag, percentile)), 1.0)
    return ratio * high, high


def gaussian_blur(grey: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of a grey image with standard deviation ``sigma`` pixels (0: unchanged)."""
    return cv2.GaussianBlur(grey, (0, 0), sigma) if sigma > 0 else grey


def edge_map(grey: np.ndarray, low: float | None = None, high: float | None = None, blur: float = 1.0,
             percentile: float = 85.0) -> np.ndarray:
    """Canny edge map.

    Parameters
    ----------
    grey : (H, W) uint8
    low, high : float or None
        Canny hysteresis thresholds on the L2 Sobel magnitude. ``None`` (both) chooses
        them per frame with :func:`auto_canny_thresholds` at ``percentile``.
    blur : float
        Standard deviation (pixels) of a Gaussian pre-blur; 0 disables it.

    Returns
    -------
    (H, W) uint8, 255 on edges and 0 elsewhere.
    """
    g = gaussian_blur(to_grey(grey), blur)
    if low is None or high is None:
        low, high = auto_canny_thresholds(g, percentile)
    if not (0 <= low <= high):
        raise ValueError(f"Canny thresholds must satisfy 0 <= low <= high, got low={low}, high={high}")
    return cv2.Canny(g, low, high, L2gradient=True)


def canny_calibrated(grey: np.ndarray, blur: float, percentile: float,
                     box: tuple[float, float, float, float]) -> tuple[float, float]:
    """Canny thresholds calibrated on the pixels of ``box``: :func:`auto_canny_thresholds` of the
    grey image blurred as :func:`edge_map` blurs it (the contour trackers choose them once, on the
    first frame's target). Raises ``ValueError`` for a box that misses the image."""
    return auto_canny_thresholds(gaussian_blur(grey, blur), percentile, box=box)


def edges_and_chamfer(grey: np.ndarray, thresholds: tuple[float, float] | None, blur: float, percentile: float,
                      profile: Profile, g0: float, resample: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """What the contour trackers read of a grey frame: the Canny edge map (:func:`edge_map` with
    ``thresholds``, or chosen on the whole frame when None) and its chamfer image
    (:func:`chamfer_image`). Returns ((H, W) uint8, (H, W) float32).

    With ``resample`` f != 1 both are computed on the frame resampled by f (:func:`resampled_edges`),
    as one level of an image pyramid, and mapped back to the frame's (H, W) grid: the chamfer values
    are then in the resampled frame's (squared) pixels."""
    low, high = thresholds if thresholds is not None else (None, None)
    if resample != 1.0:
        return resampled_edges(grey, resample, (low, high), blur, percentile, profile, g0)
    edges = edge_map(grey, low, high, blur, percentile)
    return edges, chamfer_image(edges, profile, g0)


def resampled_size(shape: tuple[int, ...], f: float) -> tuple[int, int]:
    """(rows, cols) of an (H, W) image resampled by ``f``: each side rounded, at least 2."""
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f"resampling factor must be finite and positive, got {f}")
    return max(2, int(round(shape[0] * f))), max(2, int(round(shape[1] * f)))


def resample_grey(grey: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """An (H, W) uint8 grey image resampled to ``size`` = (rows, cols): the mean over each output
    pixel's footprint when shrinking (OpenCV's area interpolation, a pyramid level's anti-aliasing),
    bilinear when enlarging. Returns (rows, cols) uint8."""
    rows, cols = size
    shrink = rows * cols < grey.shape[0] * grey.shape[1]
    return cv2.resize(grey, (cols, rows), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def _axis_map(n_full: int, n_small: int) -> tuple[np.ndarray, np.ndarray]:
    """The small grid's coordinate of each full-grid pixel centre along one axis, c' = (c + 1/2) n_small /
    n_full - 1/2 (the pixel-area convention of :func:`resample_grey`), as the lower neighbour (n_full,)
    intp and the weight of the upper one (n_full,) float32, clamped to the small grid."""
    c = (np.arange(n_full, dtype=np.float64) + 0.5) * (n_small / n_full) - 0.5
    c = np.clip(c, 0.0, n_small - 1.0)
    i0 = np.minimum(np.floor(c).astype(np.intp), n_small - 2)
    return i0, (c - i0).astype(np.float32)


def upsample_to(img: np.ndarray, shape: tuple[int, int], nearest: bool = False) -> np.ndarray:
    """A (h, w) image of a grid resampled from an (H, W) one, read back at the (H, W) grid's pixel
    centres (:func:`_axis_map`): bilinearly (float32), or the nearest pixel (``nearest``, same dtype).

    Parameters
    ----------
    img : (h, w) array, h, w >= 2; shape : (H, W).

    Returns
    -------
    (H, W) float32, or img's dtype with ``nearest``.
    """
    r0, fr = _axis_map(shape[0], img.shape[0])
    c0, fc = _axis_map(shape[1], img.shape[1])
    if nearest:
        return img[np.ix_(r0 + (fr >= 0.5), c0 + (fc >= 0.5))]
    a = img.astype(np.float32)
    # (1 - w) a_0 + w a_1: exactly a_0 at w = 0 and a_1 at w = 1 (a grid read back on itself is unchanged)
    wc, wr = fc[None, :], fr[:, None]
    top = (1 - wc) * a[r0][:, c0] + wc * a[r0][:, c0 + 1]
    bot = (1 - wc) * a[r0 + 1][:, c0] + wc * a[r0 + 1][:, c0 + 1]
    return (1 - wr) * top + wr * bot


def resampled_edges(grey: np.ndarray, f: float, thresholds: tuple[float | None, float | None], blur: float,
                    percentile: float, profile: Profile, g0: float) -> tuple[np.ndarray, np.ndarray]:
    """Edges and chamfer image of a grey frame at another resolution, on the frame's own grid.

    The (H, W) frame is resampled by ``f`` (:func:`resample_grey`), its Canny edges
    (:func:`edge_map`: the blur in the resampled frame's pixels) and chamfer image
    (:func:`chamfer_image`) computed there, and both read back at the (H, W) pixel centres
    (:func:`upsample_to`: the chamfer image bilinearly, the edges at the nearest pixel). A point p of
    the frame then reads gamma of the resampled frame at f p: distances measured as they would be on
    a target f times its size, in that frame's (squared, for the quadratic profile) pixels, to the map
    back's interpolation: a point between the resampled frame's pixels reads gamma interpolated twice,
    which for the quadratic profile near an edge adds about a quarter px^2 at f = 0.5 (measured on a
    synthetic outline, ``tests/test_m2_transfer.py``).

    Returns
    -------
    edges : (H, W) uint8, 255 on the resampled frame's edges; chamfer : (H, W) float32.
    """
    g = to_grey(grey)
    small = resample_grey(g, resampled_size(g.shape, f))
    edges = edge_map(small, thresholds[0], thresholds[1], blur, percentile)
    cham = chamfer_image(edges, profile, g0)
    shape = (g.shape[0], g.shape[1])
    return upsample_to(edges, shape, nearest=True), upsample_to(cham, shape)


#: below this squared image diagonal (1024 px), OpenCV's distances are made exact (see distance_transform)
_EXACT_SQ = 2 ** 20


def distance_transform(edges: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance from every pixel to the nearest edge pixel.

    The exact distance is sqrt(n) for an integer squared distance n. OpenCV's precise
    transform (Felzenszwalb's, ``DIST_MASK_PRECISE``) returns float32 values that differ in
    the last place depending on how the process's OpenCV thread pool was first set up
    (measured with OpenCV 5.0, even with one thread at the call), which would break bit-exact
    re-execution from a recording in another process. So its value d is taken only to find
    n = rint(d * d) -- exact while n < 2^20 for any d within 2 ulps of sqrt(n), checked for
    every such n -- and the distance is recomputed as float32 sqrt(n), correctly rounded, which
    is SciPy's exact EDT rounded to float32 (the former implementation; the same bits on every
    frame of the four shared sequences, 1 or 2 OpenCV threads, and on random edge maps up to
    700x700). 1.5-2.5 ms per 384x288 frame against SciPy's 5-5.5 ms. Images whose diagonal
    exceeds 1024 px use SciPy's exact EDT.

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
    free = e == 0  # distance to the nearest zero of the transform's input: the edges are the zeros
    if (e.shape[0] - 1) ** 2 + (e.shape[1] - 1) ** 2 < _EXACT_SQ:
        d = cv2.distanceTransform(free.view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        np.multiply(d, d, out=d)
        np.rint(d, out=d)  # n, exactly
        return np.sqrt(d, out=d)
    from scipy import ndimage  # imported here: 0.3 s at start-up for the processes that never need it

    return ndimage.distance_transform_edt(free).astype(np.float32)


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
