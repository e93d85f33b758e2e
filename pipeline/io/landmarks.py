"""Face landmark files: reference landmarks (``.npz``) and tracked points (``.csv``).

* A **landmark file** is a ``numpy.savez`` archive with one array of shape
  ``(frames, landmarks, 2 or 3)``, float, under the key ``landmarks`` (another key can be
  named): ``x, y`` in pixels of the frame (origin at the top-left pixel centre), ``z`` (if
  any) in the same units, away from the camera; a frame whose landmarks were not found is
  NaN. ``../shared/data/david_indoor/landmarks.npz`` (MediaPipe Face Mesh, 468 points) is one.
  A dataset folder holding ``landmarks.npz`` stands for that file.
* A **points file** is CSV ``frame,landmark,x,y``: one row per tracked vertex and frame,
  ``landmark`` being the reference landmark index the vertex was learned from
  (``gflow track --tracker gflow --points-out P.csv`` writes it).

Every problem (missing file or key, wrong shape or dtype, a torn or non-numeric row) raises
an error naming the file.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from pipeline.io.csv_rows import FARTHEST, csv_rows
from pipeline.io.npz_files import read_npz
from pipeline.io.path_errors import MissingPath

__all__ = ["LANDMARK_KEY", "resolve_landmarks", "read_landmarks", "read_points", "write_points"]

#: The default key of the landmark array in a landmark file.
LANDMARK_KEY = "landmarks"


def resolve_landmarks(source: str | os.PathLike) -> Path:
    """The landmark file of ``source``: the file itself, or ``source/landmarks.npz`` for a folder."""
    p = Path(source)
    if p.is_dir():
        q = p / "landmarks.npz"
        if not q.is_file():
            raise MissingPath(f"{p} is a folder without landmarks.npz")
        return q
    if not p.is_file():
        raise MissingPath(f"landmark file not found: {p}")
    return p


def read_landmarks(source: str | os.PathLike, key: str = LANDMARK_KEY, dims: tuple[int, ...] = (2, 3)) -> np.ndarray:
    """Read a landmark file.

    Parameters
    ----------
    source : an ``.npz`` file, or a folder holding ``landmarks.npz``.
    key : the array's name in the archive.
    dims : accepted sizes of the last axis (``(3,)`` to require 3-D landmarks).

    Returns
    -------
    (T, N, D) float64, NaN where a frame has no landmarks.

    Raises
    ------
    FileNotFoundError, ValueError
        With a one-line message naming the file and what is wrong.
    """
    p = resolve_landmarks(source)
    arrays = read_npz(p, "landmark file")
    if key not in arrays:
        raise ValueError(f"{p}: no array {key!r} (it holds {', '.join(arrays) or 'nothing'})")
    a = arrays[key]
    if a.ndim != 3 or a.shape[2] not in dims or a.shape[1] < 1:
        want = " or ".join(str(d) for d in dims)
        raise ValueError(f"{p}: {key!r} must have shape (frames, landmarks, {want}), got {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"{p}: {key!r} must be floating point (pixels, NaN for frames without a face), got {a.dtype}")
    a = np.asarray(a, dtype=np.float64)
    if np.isinf(a).any():
        raise ValueError(f"{p}: {key!r} has infinite values (use NaN for a frame without landmarks)")
    if (np.abs(a) >= FARTHEST).any():  # as a box's or a point's: numpy's overflow warnings, then no frame scored
        raise ValueError(f"{p}: {key!r} has values beyond any image ({np.nanmax(np.abs(a)):g}; landmarks are pixels, "
                         f"within +-2^31)")
    return a


def write_points(path: str | os.PathLike, points: dict[int, tuple[np.ndarray, np.ndarray]], new: bool = False) -> Path:
    """Write ``frame,landmark,x,y`` rows. ``new``: beside ``path`` and moved there once complete, never over a
    file (:func:`pipeline.io.recording_files.write_text_new`): a write that fails leaves no part of it.

    Parameters
    ----------
    points : {frame: (landmarks (n,) int, xy (n, 2) float)}
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)

    def rows(f) -> None:
        w = csv.writer(f, lineterminator="\n")  # LF: a CSV reads the same on every platform and in diff
        w.writerow(["frame", "landmark", "x", "y"])
        for frame in sorted(points):
            lm, xy = points[frame]
            for i, (x, y) in zip(np.asarray(lm).tolist(), np.asarray(xy, dtype=np.float64).tolist()):
                w.writerow([int(frame), int(i), f"{x:.3f}", f"{y:.3f}"])

    if new:
        from pipeline.io.recording_files import write_text_new

        write_text_new(p, rows)
        return p
    with open(p, "w", newline="") as f:
        rows(f)
    return p


def read_points(path: str | os.PathLike) -> dict[int, dict[int, tuple[float, float]]]:
    """Read a points file: ``{frame: {landmark: (x, y)}}`` (a header line is optional)."""
    p = Path(path)
    out: dict[int, dict[int, tuple[float, float]]] = {}
    first: dict[tuple[int, int], int] = {}
    for lineno, row in csv_rows(p, "frame,landmark,x,y", "points"):
        try:
            frame, lm = int(row[0]), int(row[1])
            x, y = float(row[2]), float(row[3])
        except ValueError:
            raise ValueError(f"{p}:{lineno}: not numbers: {','.join(row)}") from None
        if frame < 0 or lm < 0:  # no source has such a frame, no face mesh such a landmark: the row was never scored
            raise ValueError(f"{p}:{lineno}: {'frame' if frame < 0 else 'landmark'} {frame if frame < 0 else lm}: "
                             f"frame and landmark numbers start at 0")
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"{p}:{lineno}: point has NaN or inf")
        if max(abs(x), abs(y)) >= FARTHEST:  # its distance from the reference overflowed: the frame was not scored
            raise ValueError(f"{p}:{lineno}: point {max(x, y, key=abs):g} is beyond any image (x and y are pixels, "
                             f"within +-2^31)")
        if (frame, lm) in first:  # the later row would replace the earlier one without a word
            raise ValueError(f"{p}:{lineno}: frame {frame} landmark {lm} again (first at line "
                             f"{first[frame, lm]}): one point a landmark a frame")
        first[frame, lm] = lineno
        out.setdefault(frame, {})[lm] = (x, y)
    if not out:
        raise ValueError(f"{p}: no points")
    return out
