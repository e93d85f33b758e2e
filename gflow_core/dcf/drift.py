"""Template update with drift correction: the estimate re-aligned with the first frame's filter (``drift_correct``).

The running filter learns from every confident frame at the estimate, so an estimate a few pixels off
becomes the filter's idea of the target, and the next estimate is as far off: the error is learnt and
kept. On david_indoor the box slides about 8 px up and right while the face turns to profile (frames
350-400) and stays there, confident, for the remaining 260 frames (AUC 0.70 instead of 0.80 with one
seed in three). Matthews, Ishikawa & Baker ("The template update problem", PAMI 2004, sec. 2.4,
strategy 3, "template update with drift correction") track with the updated template, then align the
*first* template with the frame starting from that estimate: when the alignment p* stays within
epsilon of the estimate p, p* is the estimate and the template is updated there; otherwise the template
is not updated.

Here the first template is the first frame's filter (the anchor, :class:`.model.TargetModel`, never
updated) and the alignment is the anchor's response on the window the frame was detected in (the map
``an`` of :func:`.model.respond`): p* is its highest point within epsilon = ``drift_correct`` sqrt(w h)
of the estimate, taken when it is a peak of the map (no higher point beside it), i.e. when an ascent
from p would stop there; a highest point that is not a peak lies on the disk's edge with the map still
rising outward, an alignment beyond epsilon. Departures from the paper: its alignment is a
Lucas-Kanade descent on the image, here a search of a correlation response; its rule skips the update
beyond epsilon, which here is ``drift_hold`` (off by default: a target whose look has changed for good,
a face in profile, would then never be learnt).
"""

from __future__ import annotations

import numpy as np

from .model import Response

__all__ = ["aligned"]


def aligned(resp: Response, centre: np.ndarray, radius: float) -> np.ndarray | None:
    """The anchor's alignment p* (x, y) from the estimate ``centre`` (2,) within ``radius`` image px, or
    None when it lies beyond (the anchor's map ``resp.an`` rising past the disk) or the map is flat."""
    m = resp.an
    assert m is not None, "respond(..., anchor=True) gives the anchor's map"
    h, w = m.shape
    xs = resp.origin[0] + np.arange(w) / resp.q[0]
    ys = resp.origin[1] + np.arange(h) / resp.q[1]
    # the map positions within epsilon of p: |(x, y) - p| <= radius
    disk = (xs[None, :] - centre[0]) ** 2 + (ys[:, None] - centre[1]) ** 2 <= radius * radius
    if not disk.any():
        return None
    inside = np.where(disk, m, -np.inf)
    i, j = np.unravel_index(int(np.argmax(inside)), m.shape)
    # a peak of the whole map: no neighbour (of 8) higher, so an ascent from p stops here, within epsilon
    nb = m[max(i - 1, 0): i + 2, max(j - 1, 0): j + 2]
    if m[i, j] < nb.max() or nb.max() <= nb.min():
        return None
    return np.array([xs[j], ys[i]])

