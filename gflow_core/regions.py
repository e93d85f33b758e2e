"""Resampling an image region to a fixed resolution: the one place where the appearance
trackers cut the region under a box out of a frame (or out of its feature channels).

Coordinates are image (x, y) pixels with the origin at the top-left pixel centre.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["region"]


def region(feat: np.ndarray, centre: np.ndarray, size: tuple[float, float], k: float) -> np.ndarray:
    """The region of ``feat`` centred at ``centre`` (x, y) of ``size`` (w, h) image pixels,
    resampled by ``k`` (output pixels per image pixel): (round(h k), round(w k), C) float32.

    Down-sampling (k < 1) is preceded by a Gaussian of sigma 0.4 / k against aliasing.
    Outside the frame the border is replicated.
    """
    W, H = max(2, int(round(size[0] * k))), max(2, int(round(size[1] * k)))
    src = feat if k >= 1 else cv2.GaussianBlur(feat, (0, 0), 0.4 / k)
    # output pixel (u, v) -> image (x, y) = centre + ((u, v) - (W - 1) / 2) / k
    M = np.array([[1.0 / k, 0.0, centre[0] - (W / 2.0 - 0.5) / k],
                  [0.0, 1.0 / k, centre[1] - (H / 2.0 - 0.5) / k]], dtype=np.float64)
    out = cv2.warpAffine(src, M, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(H, W, -1)
