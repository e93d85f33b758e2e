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

from dataclasses import dataclass

import numpy as np

__all__ = [
    "validate_frame", "FrameData", "prepare_frame", "frame_pyramid", "BilinearStencil", "bilinear_stencil",
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
    """

    image: np.ndarray
    flat: np.ndarray
    gx: np.ndarray
    gy: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape  # type: ignore[return-value]


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


@dataclass(frozen=True)
class BilinearStencil:
    """Precomputed bilinear interpolation stencil for a set of points.

    Attributes
    ----------
    idx : (...) intp
        Flat index ``row * W + col`` of the top-left neighbour.
    fx, fy : (...) float64
        Fractional offsets in ``[0, 1]``.
    dx_ok, dy_ok : (...) bool
        False where the coordinate was clamped (the derivative along it is 0).
    inside : (...) bool
        Point lies in ``[0, W - 1] x [0, H - 1]``.
    width, size : int
        ``W`` and ``H * W``.
    """

    idx: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    dx_ok: np.ndarray
    dy_ok: np.ndarray
    inside: np.ndarray
    width: int
    size: int

    def _corners(self, flat: np.ndarray, offset: np.ndarray | int = 0):
        i = self.idx + offset
        W = self.width
        return flat[i], flat[i + 1], flat[i + W], flat[i + W + 1]

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
    H, W = int(shape[0]), int(shape[1])
    x = points[..., 0]
    y = points[..., 1]
    finite = np.isfinite(x) & np.isfinite(y)
    x = np.where(finite, x, 0.0)
    y = np.where(finite, y, 0.0)
    inside = finite & (x >= 0.0) & (x <= W - 1) & (y >= 0.0) & (y <= H - 1)
    dx_ok = finite & (x > 0.0) & (x < W - 1)
    dy_ok = finite & (y > 0.0) & (y < H - 1)
    xc = np.clip(x, 0.0, W - 1.0)
    yc = np.clip(y, 0.0, H - 1.0)
    x0 = np.minimum(np.floor(xc), W - 2.0)
    y0 = np.minimum(np.floor(yc), H - 2.0)
    idx = (y0 * W + x0).astype(np.intp)
    return BilinearStencil(idx, xc - x0, yc - y0, dx_ok, dy_ok, inside, W, H * W)
