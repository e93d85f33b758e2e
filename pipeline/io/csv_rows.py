"""Reading the project's CSV tables (boxes ``frame,x,y,w,h``, face points ``frame,landmark,x,y``)."""

from __future__ import annotations

import csv
from pathlib import Path

from pipeline.io.path_errors import FolderForFile, MissingPath

__all__ = ["csv_rows", "FARTHEST"]

#: a coordinate at least this far from 0 is no pixel of any image (OpenCV's sizes and coordinates are 32-bit
#: integers); the readers of boxes, points and landmarks refuse it, whose area or distances would overflow
FARTHEST = 2.0**31


def csv_rows(path: str | Path, columns: str, what: str):
    """``(line number, row)`` of a CSV file of ``columns`` (e.g. ``"frame,x,y,w,h"``): blank lines and a
    header line are skipped; a short row, a row with more or fewer columns than the first, a missing file or a folder
    is an error naming the file (and line)."""
    p = Path(path)
    if p.is_dir():
        raise FolderForFile(f"{p} is a folder, not a {what} file (give a .csv file)")
    if not p.is_file():
        raise MissingPath(f"{what} file not found: {p}")
    n = columns.count(",") + 1
    width: tuple[int, int] | None = None  # (columns, line) of the first row
    # utf-8-sig: a byte-order mark (as some editors and spreadsheets write) is not part of the first cell, which
    # would otherwise not read as a frame number, and the first row would be skipped as a header
    with open(p, newline="", encoding="utf-8-sig") as f:
        try:
            for lineno, row in enumerate(csv.reader(f), start=1):
                if not row or not "".join(row).strip():
                    continue
                if lineno == 1 and not row[0].strip().lstrip("-").isdigit():
                    _refuse_other_kind(p, row, columns, what)
                    _refuse_other_separators(p, row, columns)
                    continue  # header
                if len(row) < n:
                    raise ValueError(f"{p}:{lineno}: expected {columns}, got {len(row)} column(s)")
                width = width or (len(row), lineno)
                if len(row) != width[0]:  # a row cut short or run on (a lost comma, a half-pasted row) was read
                    names = WIDTHS.get((what, width[0]))
                    raise ValueError(f"{p}:{lineno}: {len(row)} columns, but the rows before have {width[0]}"
                                     + (f" ({names})" if names else "") + f" (from line {width[1]}): every row "
                                     "has the same columns")
                yield lineno, row
        except (UnicodeDecodeError, csv.Error) as e:  # a recording or picture given for a CSV
            raise ValueError(f"{p}: not a {what} CSV file ({columns} as text): {e}") from None


#: the columns of the rows gflow writes, by kind of file and number of columns (named when a row has other ones)
WIDTHS = {("box", 5): "frame,x,y,w,h", ("box", 7): "frame,x,y,w,h,confidence,state",
          ("box", 8): "frame,x,y,w,h,confidence,state,input", ("visibility", 2): "frame,visible",
          ("visibility", 3): "frame,visible,perturbed", ("visibility", 4): "frame,visible,perturbed,source_frame",
          ("points", 4): "frame,landmark,x,y"}

#: the header gflow writes on each kind of CSV it reads (``--out``, ``--points-out``, visibility)
KINDS = {"frame,x,y,w,h": "box", "frame,landmark,x,y": "points", "frame,visible": "visibility"}


def _refuse_other_separators(p: Path, header: list[str], columns: str) -> None:
    """A one-line error when the line taken for a header is a row of numbers separated by tabs, semicolons or spaces
    rather than commas: it would be skipped as a header, and every row after it too fail or, in a file of one row,
    the file called empty."""
    import re

    cells = [c for c in re.split(r"[\s;]+", ",".join(header).strip()) if c]
    if len(cells) >= columns.count(",") + 1 and cells[0].lstrip("-").isdigit():
        raise ValueError(f"{p}:1: numbers separated by tabs, semicolons or spaces; gflow reads {columns} separated "
                         f"by commas")


def _refuse_other_kind(p: Path, header: list[str], columns: str, what: str) -> None:
    """A one-line error when the header line is gflow's header of another kind of file (a boxes
    file given for points, say), whose rows would otherwise fail as "not numbers" further on."""
    names = [h.strip().lower() for h in header]
    for cols, kind in KINDS.items():
        k = cols.split(",")
        if kind != what and names[:len(k)] == k and names[:len(columns.split(","))] != columns.split(","):
            raise ValueError(f"{p} is a {kind} file ({','.join(names)}), not a {what} file ({columns})")

