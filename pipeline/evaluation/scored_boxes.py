"""Boxes read for scoring (``gflow eval``, ``gflow plot --gt``), with OTB's convention for a box of no size.

A row whose width or height is 0, or whose x, y, w or h is NaN, holds no box: in the ground truth the target is
absent on that frame (it is left out of the scores); in a tracker's boxes the tracker gave no box (a failure:
overlap 0, a miss for the centre error). A negative width or height is damage, not a convention: an error naming
the file and the line, before anything is scored (negative sizes would be scored as boxes reaching back from
their corner, their centres on the wrong side of it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ScoredBoxes", "read_scored_boxes", "has_size", "CONVENTION"]

Box = tuple[float, float, float, float]

#: the convention, in the words of the commands' help
CONVENTION = ("a row whose w or h is 0, or with NaN in x, y, w or h, holds no box: in the ground truth the target is "
              "absent on that frame, which is left out of the scores (the count is reported); in the predictions it "
              "is a failure (overlap 0, a miss). A negative width or height in either file is damage: an error "
              "naming the file and the line, before anything is scored")


def has_size(box) -> bool:
    """Whether ``box`` (x, y, w, h) is a box: all finite and w, h > 0."""
    return all(math.isfinite(v) for v in box) and box[2] > 0 and box[3] > 0


@dataclass(frozen=True)
class ScoredBoxes:
    """The boxes of a CSV by frame, and the frames whose row holds no box (w or h 0, or NaN)."""

    boxes: dict[int, Box]
    empty: frozenset[int]

    def frames(self, lo: int | None = None, hi: int | None = None) -> "ScoredBoxes":
        """Only the frames lo <= frame < hi (hi None: no end)."""
        keep = (lambda f: (lo is None or f >= lo) and (hi is None or f < hi))
        return ScoredBoxes({f: b for f, b in self.boxes.items() if keep(f)}, frozenset(filter(keep, self.empty)))


def read_scored_boxes(path: str | Path) -> ScoredBoxes:
    """Read ``frame,x,y,w,h`` rows (columns after the fifth are not read) as :class:`ScoredBoxes`. Errors name the
    file and line: a value not a number, an infinite one, a negative width or height, a frame given twice."""
    from pipeline.recording.results import box_rows

    p = Path(path)
    boxes: dict[int, Box] = {}
    empty: set[int] = set()
    seen = False
    for lineno, row, frame, box in box_rows(p, allow_nan=True):
        seen = True
        if box[2] < 0 or box[3] < 0:
            raise ValueError(f"{p}:{lineno}: negative width or height (w={row[3].strip()}, h={row[4].strip()}): a box "
                             "of no size is written w=0 or h=0 (or NaN)")
        if has_size(box):
            boxes[frame] = box
        else:
            empty.add(frame)
    if not seen:
        raise ValueError(f"{p}: no boxes")
    return ScoredBoxes(boxes, frozenset(empty))
