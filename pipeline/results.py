"""Results files: box CSVs (``frame,x,y,w,h``) and what a recording says about tracking."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from stages.messages import Estimate, Frame, MessageError, PoseEstimate, decode

from .mcap_io import iter_records

__all__ = ["read_boxes", "write_boxes", "estimates", "truth_boxes", "frame_ranges", "completeness"]

Box = tuple[float, float, float, float]


def read_boxes(path: str | Path) -> dict[int, Box]:
    """Read ``frame,x,y,w,h`` rows (a header line is optional). Errors name the file and line."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"box file not found: {p}")
    out: dict[int, Box] = {}
    with open(p, newline="") as f:
        for lineno, row in enumerate(csv.reader(f), start=1):
            if not row or not "".join(row).strip():
                continue
            if lineno == 1 and not row[0].strip().lstrip("-").isdigit():
                continue  # header
            if len(row) < 5:
                raise ValueError(f"{p}:{lineno}: expected frame,x,y,w,h, got {len(row)} column(s)")
            try:
                frame = int(row[0])
                box = tuple(float(v) for v in row[1:5])
            except ValueError:
                raise ValueError(f"{p}:{lineno}: not numbers: {','.join(row)}") from None
            if not all(math.isfinite(v) for v in box):
                raise ValueError(f"{p}:{lineno}: box has NaN or inf")
            out[frame] = box  # type: ignore[assignment]
    if not out:
        raise ValueError(f"{p}: no boxes")
    return out


def write_boxes(path: str | Path, boxes: dict[int, Box]) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with open(p, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "w", "h"])
        for k in sorted(boxes):
            w.writerow([k, *(f"{v:.2f}" for v in boxes[k])])


def estimates(recording: str | Path, stream: str | None = None) -> dict[int, Estimate]:
    """Every Estimate in a recording, by frame (the last one wins if a frame repeats)."""
    out: dict[int, Estimate] = {}
    for r in iter_records(recording):
        if r.type not in ("Estimate", "PoseEstimate") or (stream and not r.topic.startswith(f"gflow/{stream}/")):
            continue
        try:
            m = decode(r.data)
        except MessageError:
            continue
        if isinstance(m, (Estimate, PoseEstimate)):
            out[m.header.seq] = m
    return out


def truth_boxes(recording: str | Path) -> dict[int, Box]:
    """Ground-truth boxes carried by Frame messages (synthetic scenes)."""
    out: dict[int, Box] = {}
    for r in iter_records(recording):
        if r.type != "Frame":
            continue
        try:
            m = decode(r.data)
        except MessageError:
            continue
        if isinstance(m, Frame) and m.truth is not None:
            out[m.header.seq] = tuple(m.truth)  # type: ignore[assignment]
    return out


def frame_ranges(frames) -> str:
    """Frame numbers as compact ranges: ``3, 7-9, 12``."""
    out: list[str] = []
    fs = sorted(set(frames))
    i = 0
    while i < len(fs):
        j = i
        while j + 1 < len(fs) and fs[j + 1] == fs[j] + 1:
            j += 1
        out.append(str(fs[i]) if i == j else f"{fs[i]}-{fs[j]}")
        i = j + 1
    return ", ".join(out)


def completeness(est: dict, expected: range | None) -> list[str]:
    """Lines saying which frames have no estimate and which coasted (empty: every frame tracked).

    expected : the frames the source was to send (None: from the first to the last estimate)."""
    if expected is None:
        expected = range(min(est), max(est) + 1) if est else range(0)
    missing = [f for f in expected if f not in est]
    coasted = [f for f, e in est.items() if getattr(e, "state", "") == "coast"]
    lines = []
    if missing:
        lines.append(f"{len(missing)} frame(s) have no estimate: {frame_ranges(missing)}")
    if coasted:
        lines.append(f"{len(coasted)} frame(s) coasted on the dynamics (no usable input): {frame_ranges(coasted)}")
    return lines
