"""``gflow frame SOURCE N OUT.png``: one frame of a source with a pixel grid and rulers, so the
``--init X,Y,W,H`` box of ``gflow track`` can be read off it."""

from __future__ import annotations

ORDER = 25

import sys
from pathlib import Path
from typing import Literal

from pipeline.cli.commands.common import CliError, check_new_picture, positive_int, whole_number, write_picture


#: the longest side of the picture written, in pixels (PNG and JPEG viewers' common limit)
MAX_SIDE = 32767


def grid_picture(img, step: int, scale: int):
    """The image scaled by ``scale``, with grid lines every ``step`` source pixels and their
    coordinates in a margin on the top (x) and the left (y)."""
    import cv2
    import numpy as np

    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    h, w = img.shape[:2]
    big = cv2.resize(img, (w * scale, h * scale), interpolation=cv2.INTER_NEAREST)
    font, fs = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    (tw, th), _ = cv2.getTextSize(str(max(w, h)), font, fs, 1)
    mx, my = tw + 8, th + 10
    pic = np.full((h * scale + my, w * scale + mx, 3), 255, np.uint8)
    pic[my:, mx:] = big
    for i, x in enumerate(range(0, w, step)):
        X = mx + x * scale
        major = i % 2 == 0
        cv2.line(pic, (X, my), (X, my + h * scale - 1), (0, 255, 255) if major else (0, 160, 255), 1)
        if major or step * scale >= 2 * tw:
            cv2.putText(pic, str(x), (X + 2, my - 4), font, fs, (0, 0, 0), 1, cv2.LINE_AA)
    for i, y in enumerate(range(0, h, step)):
        Y = my + y * scale
        major = i % 2 == 0
        cv2.line(pic, (mx, Y), (mx + w * scale - 1, Y), (0, 255, 255) if major else (0, 160, 255), 1)
        if major or step * scale >= 2 * th:
            cv2.putText(pic, str(y), (2, Y + th + 2), font, fs, (0, 0, 0), 1, cv2.LINE_AA)
    return pic


def cmd_frame(args) -> int:
    import cv2

    from stages.source import SourceParams

    from pipeline.runtime.preflight import PreflightError, first_frame

    check_new_picture(args.out)
    if not cv2.haveImageWriter(args.out):
        raise CliError(f"{args.out}: OpenCV cannot write {Path(args.out).suffix or 'files without an extension'!r} "
                       f"pictures (give a .png or .jpg)")
    p = Path(args.source)
    kind: Literal["folder", "video", "mcap"]
    if p.is_dir():
        if (p / "frames").is_dir():
            p = p / "frames"
        kind = "folder"
    elif p.is_file():
        kind = "mcap" if p.suffix == ".mcap" else "video"
    else:
        raise CliError(f"source not found: {args.source} (give an image folder, a video file or an .mcap recording)")
    if args.index < 0:
        raise CliError(f"frame index must be >= 0, got {args.index}")
    if kind == "mcap":  # "no frame at or after frame 0" of a recording with none sent the user looking for frame 0
        from pipeline.io.mcap_io import recorded_topics
        from pipeline.recording.topics import describe_topics

        topics = recorded_topics(p)
        if topics and not any(t.endswith("/frames") for t in topics):
            raise CliError(f"{args.source} holds no frames to draw (it was recorded without them; it holds "
                           f"{describe_topics(topics)})")
    try:  # a frame past where a torn recording ends: the error says the recording is torn
        raw = first_frame(SourceParams(kind=kind, path=str(p), start=args.index, stop=args.index + 1))
    except PreflightError as e:
        raise CliError(str(e).replace("--start", "frame")) from None
    if kind == "mcap":  # read only up to where a torn one ends: said once the frame is found
        from pipeline.cli.commands.common import warn_if_torn

        warn_if_torn(str(p))
    if raw.index != args.index:
        raise CliError(f"{args.source} has no frame {args.index} (the next one is {raw.index})")
    assert raw.image is not None  # first_frame refuses a frame without an image
    h, w = raw.image.shape[:2]
    scale = args.scale or (3 if max(w, h) <= 200 else 2 if max(w, h) <= 500 else 1)
    step = args.grid or (10 if max(w, h) <= 200 else 20 if max(w, h) <= 500 else 50)
    if max(w, h) * scale > MAX_SIDE:  # it ended in an out-of-memory 'internal error' (or a picture no viewer opens)
        raise CliError(f"--scale {scale}: frame {args.index} ({w}x{h}) drawn {scale}x is {w * scale}x{h * scale} "
                       f"pixels, more than {MAX_SIDE} a side; give a --scale of at most {max(1, MAX_SIDE // max(w, h))}")
    write_picture(args.out, grid_picture(raw.image, step, scale))
    print(f"wrote {args.out}: frame {args.index} of {args.source}, {w}x{h} pixels, grid every {step} px, drawn "
          f"{scale}x; read the box's top-left corner (x on top, y on the left) and its size, then "
          f"gflow track {args.source} --init X,Y,W,H" + (f" --start {args.index}" if args.index else ""),
          file=sys.stdout)
    return 0


def register(sub) -> None:
    p = sub.add_parser("frame", help="write one frame with a pixel grid, to choose the --init box",
                       description="Writes frame N of an image folder, video or recording as a picture with a grid "
                                   "and pixel coordinates (x along the top, y down the left), so the initial box "
                                   "X,Y,W,H of `gflow track --init` can be read off it.",
                       epilog="example: gflow frame clip.mp4 0 first.png")
    p.add_argument("source", help="image folder (or dataset folder with frames/), video file or .mcap recording")
    p.add_argument("index", type=whole_number, help="frame index (0 = the first)")
    p.add_argument("out", help="picture to write (.png or .jpg)")
    p.add_argument("--grid", type=positive_int, metavar="PX", help="grid spacing in source pixels (default by image size)")
    p.add_argument("--scale", type=positive_int, help="magnification (default 3 for small images, 2, or 1 for large)")
    p.set_defaults(func=cmd_frame)
