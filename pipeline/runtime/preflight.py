"""Checks run before a pipeline starts, so a user's mistake costs a second, not a run.

* :func:`check_writable`: an output path that is a folder, or under a folder that does not
  exist (a mistyped folder is not created) or cannot be written, is refused before any tracking (a run whose result cannot be
  saved is lost work).
* :func:`first_frame`: decode the first frame the source would produce, which proves the
  file is readable (a text file named ``.mp4`` is refused here, without FFmpeg's noise) and
  that ``start`` is inside the source, and gives the image size.
* :func:`check_box_in_image`: an initial box that does not overlap the first frame, or covers fewer
  of its pixels than a stage of the run needs (:func:`box_needs`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Iterable

if TYPE_CHECKING:  # imported where used: check_writable, which every command's outputs go through, needs no stage
    from stages.source import RawFrame, SourceParams
    from pipeline.runtime.graph import Plan

__all__ = ["PreflightError", "check_writable", "first_frame", "check_box_in_image", "check_source", "check_listen",
           "box_needs"]



class PreflightError(ValueError):
    """A mistake found before the pipeline starts; the message is one line for the user."""


def check_writable(path: str | os.PathLike, what: str = "output", make_folder: bool = False) -> Path:
    """Refuse ``path`` unless a file can be written there; never leaves a file behind.

    A folder that does not exist is refused: a path the user typed with a mistake in its
    folder would put the work where they would not look for it. With ``make_folder`` (the
    program's own default places, such as ``recordings/``) it is created instead, so the check
    is the same one the writer will face later.
    """
    from pipeline.io.path_errors import dangling_link

    p = Path(path)
    if str(path).endswith(("/", os.sep)) or p.is_dir():
        raise PreflightError(f"{what} {path} is a folder; give a file name")
    if dangling_link(str(path), what):  # 'File exists' below, of a file that is not there
        raise PreflightError(dangling_link(str(path), what))
    parent = p.parent if str(p.parent) else Path(".")
    if not make_folder and not parent.exists():
        raise PreflightError(f"{what} {path}: the folder {parent} does not exist (create it first, or give another "
                             f"path)")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise PreflightError(f"{what} {path}: cannot create its folder {parent}: {e.strerror}") from None
    try:
        if p.exists():
            with open(p, "ab"):
                pass
        else:
            with open(p, "xb"):
                pass
            p.unlink()
    except OSError as e:
        raise PreflightError(f"{what} {path} cannot be written: {e.strerror}") from None
    return p


def first_frame(params: SourceParams, base_dir: str | os.PathLike = ".") -> RawFrame:
    """The first frame the source stage would emit (at ``params.start``).

    Raises :class:`PreflightError` when the source cannot be opened, holds no frame at or
    after ``start``, or its first frame cannot be decoded (the error names that frame).
    """
    from stages.source import SourceParams
    from pipeline.io.frame_readers import count_frames, open_reader

    where = params.path or "the synthetic scene"
    try:
        reader = open_reader(params, base_dir)
        frame = next(iter(reader), None)
    except (FileNotFoundError, ValueError, OSError) as e:
        raise PreflightError(str(e)) from None
    if frame is None:
        n = count_frames(SourceParams(kind=params.kind, path=params.path, frames=params.frames), base_dir) \
            if params.kind != "mcap" else None
        if n is not None and params.start >= n:
            raise PreflightError(f"--start {params.start} is beyond the end of {where} ({n} frames: 0..{n - 1})")
        if params.kind == "video":
            raise PreflightError(f"{where}: no frame can be read (not a video OpenCV can decode, or empty)")
        raise PreflightError(f"{where}: no frame at or after --start {params.start}" + (_torn(params) or _held(params)))
    if frame.image is None and frame.events and not frame.error:  # only reports: no frame was read
        raise PreflightError(f"{where}: no frame at or after --start {params.start}: {frame.events[0][1]}")
    if frame.image is None:
        which = f"frame {frame.index}" + (" (the first frame)" if frame.index == 0 else "")
        raise PreflightError(f"{where}: {which} cannot be read: {frame.error}")
    return frame


def _held(params: SourceParams) -> str:
    """`` (it holds frames 0..19)`` for a recording source with frames, so that a --start past them says what is there
    ("" for any other source: its count is said otherwise; a torn recording says where it ends instead)."""
    if params.kind != "mcap" or not params.path:
        return ""
    from pipeline.io.mcap_io import iter_records, recorded_topics

    topics = [t for t in recorded_topics(params.path) if t.endswith("/frames")]
    seqs = [r.seq for r in iter_records(params.path, topics=topics, on_truncated=lambda _: None) if r.type == "Frame"]
    return f" (it holds frames {min(seqs)}..{max(seqs)})" if seqs else ""


def _torn(params: SourceParams) -> str:
    """``: it ends early ...`` for a recording source cut by a killed writer, so a frame missing past
    the cut is not taken for the end of what was recorded ("" for any other source)."""
    if params.kind != "mcap" or not params.path:
        return ""
    from pipeline.io.mcap_io import torn_cause

    torn = torn_cause(params.path)
    return f": {torn}" if torn else ""


#: how many times the image's width (height) a box's width (height) may be: past it, a box is a typing mistake
#: (``--init 1,1,1e6,5``), which grew dcf's arrays until its stage was killed, the run stalled for 30 s
MAX_BOX_TIMES_IMAGE = 10


def check_box_in_image(box, width: int, height: int, what: str = "--init",
                       needs: tuple[int, str, str] = (1, "", "")) -> None:
    """Refuse a box with no overlap with a ``width`` x ``height`` image (partly outside is fine), one smaller than a
    pixel (a box given in the image's fractions, 0.1,0.2,0.05,0.1: every frame an error report, exit 0), one
    more than :data:`MAX_BOX_TIMES_IMAGE` times the image's size, or one covering fewer than ``needs`` = (pixels a
    side, who needs them, why: :func:`box_needs`) of the image's pixels."""
    x, y, w, h = (float(v) for v in box)
    if x >= width or y >= height or x + w <= 0 or y + h <= 0:
        raise PreflightError(f"{what} box {x:g},{y:g},{w:g},{h:g} lies outside the {width}x{height} image "
                             f"(x in 0..{width - 1}, y in 0..{height - 1}; `gflow frame SOURCE N out.png` "
                             f"draws a frame with a pixel grid)")
    if w < 1 or h < 1:
        raise PreflightError(f"{what} box {x:g},{y:g},{w:g},{h:g} is smaller than a pixel: a box is in pixels of "
                             f"the {width}x{height} image (X,Y the top-left corner, W,H at least 1)")
    k = MAX_BOX_TIMES_IMAGE
    if w > k * width or h > k * height:
        raise PreflightError(f"{what} box {x:g},{y:g},{w:g},{h:g} is more than {k} times the size of the "
                             f"{width}x{height} image (W at most {k * width}, H at most {k * height})")
    side, who, why = needs
    if side > 1:
        from gflow_core.features import box_pixels

        c0, r0, c1, r1 = box_pixels((x, y, w, h), width, height)
        if c1 - c0 < side or r1 - r0 < side:
            raise PreflightError(f"{what} box {x:g},{y:g},{w:g},{h:g} covers {c1 - c0}x{r1 - r0} pixels of the "
                                 f"{width}x{height} image: {who} needs at least {side}x{side} ({why}; W and H at "
                                 f"least {side}, inside the image)")


def box_needs(plan: Plan) -> tuple[int, str, str]:
    """(pixels a side of the first frame the initial box must cover, who needs them, why) for the stages of
    ``plan``: the most any of them asks (:meth:`gflow_msgs.params.StageFields.box_needs`), ``(1, "", "")`` when
    none asks for more than a pixel. ``who`` is the graph's tracker (chamfer: its preprocess calibrates the
    edges' thresholds on the box)."""
    import msgspec

    from gflow_msgs.params import StageFields
    from stages.registry import STAGES

    side, why = 1, ""
    who = plan.tracker.name if plan.tracker is not None else plan.name
    for name, sp in plan.stages.items():
        cls = STAGES[sp.kind].Params if sp.kind in STAGES else None
        if cls is None or not issubclass(cls, StageFields):
            continue
        n, what = msgspec.convert(plan.stage_params(name), cls, strict=False).box_needs()
        if n > side:
            side, why = n, what
    return side, who if side > 1 else "", why


def check_source(params: SourceParams, box=None, base_dir: str | os.PathLike = ".",
                 needs: tuple[int, str, str] = (1, "", "")) -> RawFrame:
    """:func:`first_frame`, and the box against its size when given (with ``needs``: :func:`check_box_in_image`)."""
    frame = first_frame(params, base_dir)
    if box is not None:
        assert frame.image is not None  # first_frame refuses a frame without an image
        h, w = frame.image.shape[:2]
        check_box_in_image(box, w, h, needs=needs)
    return frame


def check_listen(endpoints: Iterable[str]) -> None:
    """Refuse an endpoint of ``--listen`` this machine cannot listen on (a host that does not resolve, or an address
    that is not one of its own), before a run says it listens there: ``tcp/999.1.1.1:7447`` printed "listening on
    tcp/999.1.1.1:7447", then zenoh's error. A port in use is left to the run (it may pick another)."""
    import errno
    import socket

    for ep in endpoints:
        proto, _, addr = ep.partition("/")
        host, sep, port = addr.split("?")[0].split("#")[0].rpartition(":")
        if proto not in ("tcp", "tls", "udp", "quic") or not sep or not port.isdigit():
            continue
        kind = socket.SOCK_DGRAM if proto in ("udp", "quic") else socket.SOCK_STREAM
        try:
            family, _, _, _, where = socket.getaddrinfo(host.strip("[]"), int(port), type=kind)[0]
            with socket.socket(family, kind) as s:
                s.bind(where)
        except OSError as e:
            if e.errno != errno.EADDRINUSE:
                raise PreflightError(f"cannot listen on {ep}: {e.strerror or e}") from None
