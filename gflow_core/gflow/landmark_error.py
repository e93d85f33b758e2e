"""Scoring tracked face points against reference landmarks (the paper's fig. 3 measure).

The paper scored its tracker by the distance of 6 hand-labelled points from the tracked
ones. Here the points are the eye corners 33, 133, 362, 263 and the mouth corners 61, 291 of
MediaPipe Face Mesh's layout, and the error of a frame is their mean distance (pixels);
the **normalised mean error** (NME) divides it by that frame's reference distance between
the outer eye corners 33 and 263, so faces of any size compare. Frames whose reference is
NaN (no face found) are not scored.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

__all__ = ["SCORED_LANDMARKS", "NORMALISING_PAIR", "LandmarkScore", "landmark_score"]

#: Eye corners 33, 133, 362, 263 and mouth corners 61, 291.
SCORED_LANDMARKS = (33, 133, 362, 263, 61, 291)
#: The outer eye corners, whose distance normalises the error.
NORMALISING_PAIR = (33, 263)


@dataclass(frozen=True)
class LandmarkScore:
    """Landmark error over a sequence.

    Attributes
    ----------
    frames : int
        Frames with a reference (finite scored landmarks).
    missing : int
        Of those, frames with no tracked point for some scored landmark (not in the means).
    nme : float
        Mean over scored frames of the per-frame NME (NaN if none).
    px : float
        Mean over scored frames of the per-frame mean distance (pixels).
    per_frame : dict
        ``{frame: (nme, px)}`` of every scored frame.
    """

    frames: int
    missing: int
    nme: float
    px: float
    per_frame: dict[int, tuple[float, float]]

    def to_json(self) -> dict:
        return {"frames": self.frames, "missing": self.missing, "nme": self.nme, "px": self.px}


def landmark_score(reference: np.ndarray, points: Mapping[int, Mapping[int, tuple[float, float]]],
                   scored: Sequence[int] = SCORED_LANDMARKS, pair: Sequence[int] = NORMALISING_PAIR,
                   frames: Sequence[int] | None = None) -> LandmarkScore:
    """Per-frame error of tracked points against reference landmarks.

    Parameters
    ----------
    reference : (T, N, D) float64
        Reference landmarks (``x, y`` pixels first), NaN where there is none.
    points : {frame: {landmark: (x, y)}}
        Tracked points.
    scored : landmark indices scored.
    pair : two landmark indices whose reference distance normalises each frame's error.
    frames : frames to score (default: every frame of ``reference``).

    Returns
    -------
    LandmarkScore

    Raises
    ------
    ValueError
        An index outside the reference's landmarks, or tracked points that never include the
        scored landmarks.
    """
    ref = np.asarray(reference, dtype=np.float64)
    T, N = ref.shape[:2]
    idx = [int(i) for i in scored]
    a, b = (int(i) for i in pair)
    if min(idx + [a, b]) < 0 or max(idx + [a, b]) >= N:
        raise ValueError(f"landmarks {sorted(set(idx + [a, b]))} are not all among the reference's {N} landmarks")
    have = set().union(*(set(v) for v in points.values())) if points else set()
    if points and not set(idx) & have:
        raise ValueError(f"the tracked points include none of the scored landmarks {idx} (they have landmarks "
                         f"{sorted(have)[:8]}{'...' if len(have) > 8 else ''})")
    per: dict[int, tuple[float, float]] = {}
    n_ref = missing = 0
    for t in (range(T) if frames is None else frames):
        if not 0 <= t < T:
            continue
        r = ref[t, idx, :2]
        io = float(np.linalg.norm(ref[t, a, :2] - ref[t, b, :2]))
        if not (np.isfinite(r).all() and np.isfinite(io)) or io <= 0:
            continue
        n_ref += 1
        got = points.get(t, {})
        if not all(i in got for i in idx):
            missing += 1
            continue
        p = np.array([got[i] for i in idx], dtype=np.float64)
        # mean distance of the scored points, and over the outer eye corners' distance (NME)
        px = float(np.linalg.norm(p - r, axis=1).mean())
        per[t] = (px / io, px)
    v = np.array(list(per.values())) if per else np.full((1, 2), np.nan)
    return LandmarkScore(frames=n_ref, missing=missing, nme=float(np.mean(v[:, 0])), px=float(np.mean(v[:, 1])),
                         per_frame=per)
