"""``cv2.remap`` at a list of points, however many.

OpenCV's remap refuses an output of 32767 rows or more (``dst.rows < SHRT_MAX``): a particle filter that looks its
N particles up in a response map as an (N, 1) image failed on its first frame with ``--set tracker.particles=100000``.
:func:`remap_points` looks them up in blocks of fewer rows; below the limit it is the one call it always was, so
the values (and every run's bits) are unchanged.
"""

from __future__ import annotations

import cv2
import numpy as np

#: the most rows one ``cv2.remap`` writes (it needs ``dst.rows < SHRT_MAX``)
MAX_ROWS = 32766


def remap_points(src: np.ndarray, u: np.ndarray, v: np.ndarray, interpolation: int, border_mode: int,
                 border_value: float = 0.0) -> np.ndarray:
    """(N,) ``src`` sampled at the points (``u``, ``v``), each (N,) or (N, 1) float32 map coordinates, as
    ``cv2.remap(src, u.reshape(-1, 1), v.reshape(-1, 1), ...).ravel()`` would give them without OpenCV's limit
    on the rows it writes (:data:`MAX_ROWS`)."""
    u = u.reshape(-1, 1)
    v = v.reshape(-1, 1)

    def one(a: int, b: int) -> np.ndarray:
        return cv2.remap(src, u[a:b], v[a:b], interpolation, borderMode=border_mode, borderValue=border_value).ravel()

    n = u.shape[0]
    if n <= MAX_ROWS:
        return one(0, n)
    return np.concatenate([one(a, min(a + MAX_ROWS, n)) for a in range(0, n, MAX_ROWS)])
