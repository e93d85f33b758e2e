"""Frames, image gradients and bilinear sampling at subpixel vertex positions.

Frames are grey ``(H, W)`` float64 with values in ``[0, 1]``, indexed ``(row, col)``.
Points are ``(x, y)`` pixels with the origin at the top-left pixel centre, so
``frame[r, c]`` is the value at ``(x, y) = (c, r)``.

Sampling is bilinear with the border replicated: a point outside
``[0, W - 1] x [0, H - 1]`` takes the value at the nearest point inside, and its
derivative along a clamped axis is zero. The paper's projection ``a_v(u)`` maps a
vertex to one pixel; bilinear interpolation is its smooth version, which
Gauss-Newton needs. ``cv2.remap`` is not used because its bilinear weights are
quantised to 1/32 pixel, too coarse for Gauss-Newton and finite-difference tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "validate_frame", "FrameData", "prepare_frame", "frame_pyramid", "BilinearStencil", "bilinear_stencil",
    "stencil_xy", "local_contrast",
]


def validate_frame(frame: np.ndarray, name: str = "frame", shape: tuple[int, int] | None = None) -> np.ndarray:
    """Check a grey frame and return it as C-contiguous float64.

    Parameters
    ----------
    frame : (H, W) floating
        Values in ``[0, 1]``.
    shape : (H, W), optional
        Required shape.

    Raises
    ------
    ValueError
        Wrong dimensionality, dtype or shape, fewer than 2 rows/columns, NaN or
        infinite values, or values outside ``[0, 1]``.
    """
    a = np.asarray(frame)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D grey image (H, W), got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(
            f"{name} must be floating point with values in [0, 1], got dtype {a.dtype} "
            "(convert 8-bit frames with frame / 255.0)"
        )
    if a.shape[0] < 2 or a.shape[1] < 2:
        raise ValueError(f"{name} must be at least 2x2 pixels, got shape {a.shape}")
    if shape is not None and a.shape != tuple(shape):
        raise ValueError(f"{name} has shape {a.shape} but the tracker state expects {tuple(shape)}")
    a = np.ascontiguousarray(a, dtype=np.float64)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    lo, hi = float(a.min()), float(a.max())
    if lo < 0.0 or hi > 1.0:
        raise ValueError(f"{name} values must lie in [0, 1], got [{lo:.6g}, {hi:.6g}]")
    return a


@dataclass(frozen=True)
class FrameData:
    """A validated frame with its flattened intensity and gradient images.

    Attributes
    ----------
    image : (H, W) float64
    flat, gx, gy : (H*W,) float64
        Intensity and its central-difference derivatives along x (columns) and
        y (rows), one-sided at the border (``numpy.gradient``).
    derived : dict
        Images computed from this one alone, each once, by whoever needs it first (a stage makes
        them ahead, while it waits for the experts): ``{key: array}``, e.g. the local background
        (:func:`.pose_opinion.local_background_of`). Not part of the frame's identity.
    """

    image: np.ndarray
    flat: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    derived: dict[Any, np.ndarray] = field(default_factory=dict, compare=False, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape


def prepare_frame(frame: np.ndarray, shape: tuple[int, int] | None = None) -> FrameData:
    """Validate a frame and precompute its gradient images."""
    img = validate_frame(frame, shape=shape)
    gy, gx = np.gradient(img)
    return FrameData(img, img.reshape(-1), np.ascontiguousarray(gx).reshape(-1), np.ascontiguousarray(gy).reshape(-1))


def frame_pyramid(fd: FrameData, levels: int) -> list[FrameData]:
    """Image pyramid ``[level 0 = fd, level 1, ...]`` for coarse-to-fine Gauss-Newton.

    Level ``l + 1`` is ``cv2.pyrDown`` of level ``l`` (5x5 binomial blur, every second
    pixel), so its pixel ``(x, y)`` is centred on level-``l`` pixel ``(2x, 2y)`` and a point
    ``x`` of level 0 is at ``x / 2^l`` on level ``l``. Levels stop early when the image
    would be smaller than 8 pixels on a side. Deterministic (integer-free float64 arithmetic
    in a fixed order).
    """
    import cv2

    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    out = [fd]
    img = fd.image
    for _ in range(levels - 1):
        if min(img.shape) < 16:
            break
        img = cv2.pyrDown(img)
        gy, gx = np.gradient(img)
        out.append(FrameData(img, img.reshape(-1), np.ascontiguousarray(gx).reshape(-1),
                             np.ascontiguousarray(gy).reshape(-1)))
    return out


#: :func:`local_contrast`: the floor of the local standard deviation (grey levels in [0, 1]) and
#: the softness of the squashing (in local standard deviations).
CONTRAST_FLOOR = 0.02
CONTRAST_SOFTNESS = 2.0


def local_contrast(frame: np.ndarray, sigma: float) -> np.ndarray:
    """Local contrast normalisation of a grey frame (a departure from the paper's raw intensities).

    ``z = (y - G*y) / sqrt(G*(y - G*y)^2 + f^2)`` with ``G`` a Gaussian of std ``sigma`` pixels and
    ``f`` = :data:`CONTRAST_FLOOR`, squashed back into ``[0, 1]`` as ``0.5 + 0.5 tanh(z / 2)``. Each
    pixel is read against its neighbourhood, so a change of light that is smooth over ``sigma``
    pixels (brightness, contrast, a slow shading gradient) leaves it unchanged, and a face
    template learned in the dark still matches in the light. The floor keeps the noise of flat,
    dark regions from being amplified.

    Parameters
    ----------
    frame : (H, W) float64 in [0, 1]
    sigma : float > 0

    Returns
    -------
    (H, W) float64 in (0, 1)
    """
    import cv2

    img = validate_frame(frame)
    m = cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    d = img - m
    v = cv2.GaussianBlur(d * d, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    z = d / np.sqrt(v + CONTRAST_FLOOR ** 2)
    return 0.5 + 0.5 * np.tanh(z / CONTRAST_SOFTNESS)


class BilinearStencil:
    """Precomputed bilinear interpolation stencil for a set of points.

    Attributes
    ----------
    idx : (...) intp
        Flat index ``row * W + col`` of the top-left neighbour.
    fx, fy : (...) float64
        Fractional offsets in ``[0, 1]``.
    dx_ok, dy_ok : (...) bool
        False where the coordinate was clamped (the derivative along it is 0). Computed on
        first use (most callers need only the values).
    inside : (...) bool
        Point lies in ``[0, W - 1] x [0, H - 1]`` (computed on first use).
    width, size : int
        ``W`` and ``H * W``.
    """

    __slots__ = ("idx", "fx", "fy", "width", "size", "_x", "_y", "_H", "_dx_ok", "_dy_ok", "_inside")
    _dx_ok: np.ndarray | None
    _dy_ok: np.ndarray | None
    _inside: np.ndarray | None

    def __init__(self, idx: np.ndarray, fx: np.ndarray, fy: np.ndarray, x: np.ndarray, y: np.ndarray,
                 shape: tuple[int, int]) -> None:
        self.idx, self.fx, self.fy = idx, fx, fy
        self._x, self._y = x, y  # the points (non-finite ones as given)
        self._H, self.width = int(shape[0]), int(shape[1])
        self.size = self._H * self.width
        self._dx_ok = self._dy_ok = self._inside = None

    @property
    def dx_ok(self) -> np.ndarray:
        if self._dx_ok is None:
            # NaN and +-inf compare False on one side, so they are never ok (nor inside)
            self._dx_ok = (self._x > 0.0) & (self._x < self.width - 1)
        return self._dx_ok

    @property
    def dy_ok(self) -> np.ndarray:
        if self._dy_ok is None:
            self._dy_ok = (self._y > 0.0) & (self._y < self._H - 1)
        return self._dy_ok

    @property
    def inside(self) -> np.ndarray:
        if self._inside is None:
            x, y = self._x, self._y
            self._inside = (x >= 0.0) & (x <= self.width - 1) & (y >= 0.0) & (y <= self._H - 1)
        return self._inside

    def _corners(self, flat: np.ndarray, offset: np.ndarray | int = 0):
        i = self.idx + offset if not isinstance(offset, int) or offset else self.idx
        W = self.width
        # take: the same values as flat[i], at about half the cost of fancy indexing
        return flat.take(i), flat.take(i + 1), flat.take(i + W), flat.take(i + (W + 1))

    def sample(self, flat: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Bilinear values of a flattened image ``(H*W,)`` or image stack ``(R*H*W,)``.

        Parameters
        ----------
        flat : (H*W,) or (R*H*W,) float64
        rows : (...) intp, optional
            For an image stack: which image each point samples (broadcast against
            the points).
        """
        off = 0 if rows is None else rows * self.size
        v00, v01, v10, v11 = self._corners(flat, off)
        top = v00 + self.fx * (v01 - v00)
        bot = v10 + self.fx * (v11 - v10)
        return top + self.fy * (bot - top)

    def sample_with_gradient(self, flat: np.ndarray, rows: np.ndarray | None = None):
        """Bilinear values and the derivatives of the bilinear interpolant.

        Returns
        -------
        value, d_dx, d_dy : (...) float64
        """
        off = 0 if rows is None else rows * self.size
        v00, v01, v10, v11 = self._corners(flat, off)
        top = v00 + self.fx * (v01 - v00)
        bot = v10 + self.fx * (v11 - v10)
        val = top + self.fy * (bot - top)
        ddx = (v01 - v00) + self.fy * ((v11 - v10) - (v01 - v00))
        ddy = bot - top
        return val, np.where(self.dx_ok, ddx, 0.0), np.where(self.dy_ok, ddy, 0.0)

    def sample_gradient_images(self, fd: FrameData) -> tuple[np.ndarray, np.ndarray]:
        """Frame gradient ``(dy/dx, dy/dy)`` at the points, from the central-difference images."""
        gx = np.where(self.dx_ok, self.sample(fd.gx), 0.0)
        gy = np.where(self.dy_ok, self.sample(fd.gy), 0.0)
        return gx, gy


def bilinear_stencil(points: np.ndarray, shape: tuple[int, int]) -> BilinearStencil:
    """Bilinear stencil for points ``(..., 2)`` ``(x, y)`` in an ``(H, W)`` image.

    Non-finite coordinates are treated as outside (clamped to the centre of pixel 0).
    """
    return stencil_xy(points[..., 0], points[..., 1], shape)


def stencil_xy(x: np.ndarray, y: np.ndarray, shape: tuple[int, int]) -> BilinearStencil:
    """:func:`bilinear_stencil` of points given as separate ``x`` and ``y`` arrays ``(...)``."""
    H, W = int(shape[0]), int(shape[1])
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        finite = np.isfinite(x) & np.isfinite(y)
        xs, ys = np.where(finite, x, 0.0), np.where(finite, y, 0.0)
        # keep the masks of the points as given (non-finite: outside, no derivative)
        xm, ym = np.where(finite, x, np.nan), np.where(finite, y, np.nan)
    else:
        xs, ys = xm, ym = x, y
    xc = np.minimum(np.maximum(xs, 0.0), W - 1.0)
    yc = np.minimum(np.maximum(ys, 0.0), H - 1.0)
    # floor of a number >= 0 is its truncation; the last column / row uses the cell before it
    x0 = np.minimum(xc.astype(np.intp), W - 2)
    y0 = np.minimum(yc.astype(np.intp), H - 2)
    idx = y0 * W + x0
    return BilinearStencil(idx, xc - x0, yc - y0, xm, ym, (H, W))
