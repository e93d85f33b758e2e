"""``gflow render FILE.mcap OUT.mp4|OUT_DIR/``: the tracking overlays drawn into a video or PNGs."""

from __future__ import annotations

import errno
import sys
from pathlib import Path

from pipeline.cli.commands.common import (CliError, frame_range, positive_int, range_past_note, refuse_dangling_link,
                                          say_notes, video_rate)

ORDER = 58

VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov")


def _messages(path: str):
    """Per frame: Frame, estimate, posterior particles (decoded), in frame order."""
    from gflow_msgs.messages import Estimate, Frame, MessageError, Particles, PoseEstimate, decode

    from pipeline.io.mcap_io import iter_records

    frames: dict[int, Frame] = {}
    est: dict[int, object] = {}
    parts: dict[int, Particles] = {}
    for r in iter_records(path):
        if r.type not in ("Frame", "Estimate", "PoseEstimate", "Particles"):
            continue
        try:
            m = decode(r.data)
        except MessageError:
            continue
        if isinstance(m, Frame):
            frames[m.header.seq] = m
        elif isinstance(m, (Estimate, PoseEstimate)):
            est[m.header.seq] = m
        elif isinstance(m, Particles) and m.kind == "posterior":
            parts[m.header.seq] = m
    return frames, est, parts


def cmd_render(args) -> int:
    out = Path(args.out)
    video = out.suffix.lower() in VIDEO_SUFFIXES
    if out.suffix and not video and not out.is_dir():
        raise CliError(f"{args.out}: unknown output kind {out.suffix!r}; give a video ({', '.join(VIDEO_SUFFIXES)}) "
                       f"or a folder name for PNG frames")
    if video:
        from pipeline.cli.commands.common import check_new_picture

        check_new_picture(args.out)
    else:
        refuse_dangling_link(args.out, "OUT")  # a folder for the frames
        if out.exists() and not out.is_dir():
            raise CliError(f"{args.out} exists and is not a folder")
    first, end = frame_range(args.frames)  # a reversed range refused before the reading
    from pipeline.cli.commands.common import warn_if_torn

    warn_if_torn(args.file)
    frames, est, parts = _messages(args.file)
    seqs = [s for s in sorted(frames) if s in est]
    if not seqs:  # a damaged or torn file says where it ends, so the cut is not taken for what the run recorded
        from pipeline.io.mcap_io import damage_cause, torn_cause

        why = damage_cause(args.file) or torn_cause(args.file)
        raise CliError(f"{args.file} has no frame with an estimate to draw (it needs Frame and Estimate messages)"
                       + (f": {why}" if why else ""))
    held = (seqs[0], seqs[-1])
    seqs = [s for s in seqs if s >= first and (end is None or s < end)]
    if not seqs:
        raise CliError(f"--frames {args.frames}: no frame to draw; {args.file} holds frames {held[0]}..{held[1]}")
    _refuse_scale_past_any_picture(args, frames, seqs)
    there = [out / f"{s:06d}.png" for s in seqs if not video and (out / f"{s:06d}.png").exists()]
    if there:
        raise CliError(f"{out} already holds {len(there)} of the pictures it would write ({there[0].name}, ...); "
                       f"gflow never writes over a picture: give another folder (or empty it first)")
    say_notes(range_past_note(f"--frames {args.frames}", (first, end), args.file, held, (seqs[0], seqs[-1]), "drawing"))
    pictures = _pictures(args, frames, est, parts, seqs)
    if video:
        _write_video(out, pictures, args.fps)
    else:
        _write_pictures(out, pictures)
    print(f"drew {len(seqs)} frames into {out}")
    from pipeline.cli.commands.common import partial_if_damaged

    return partial_if_damaged(args.file, "render", str(out))


def _refuse_scale_past_any_picture(args, frames: dict, seqs: list[int]) -> None:
    """``--scale`` that draws a frame of ``seqs`` larger than any picture a side (frame.py's ``MAX_SIDE``): refused
    before any drawing, naming the largest scale that fits (it ended in OpenCV's out-of-memory 'internal error')."""
    from pipeline.cli.commands.frame import MAX_SIDE

    h, w = max((tuple(frames[s].image.shape[:2]) for s in seqs), key=max)
    if max(w, h) * args.scale > MAX_SIDE:
        raise CliError(f"--scale {args.scale}: {args.file}'s frames ({w}x{h}) drawn {args.scale}x are "
                       f"{w * args.scale}x{h * args.scale} pixels, more than {MAX_SIDE} a side; give a --scale of at "
                       f"most {max(1, MAX_SIDE // max(w, h))}")


def _pictures(args, frames: dict, est: dict, parts: dict, seqs: list[int]):
    """Per frame of ``seqs``: (seq, the frame with its overlays drawn), saying the progress on stderr."""
    import cv2

    from gflow_msgs.annotations import annotations_for
    from gflow_msgs.foxglove import ImageAnnotations

    from pipeline.cli.draw import draw_annotations

    for i, s in enumerate(seqs):
        ann: ImageAnnotations = annotations_for(frames[s], est[s], parts.get(s) if args.particles else None)
        img = frames[s].image.array()
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        yield s, draw_annotations(img, ann, args.scale)
        if not args.quiet and (i % 50 == 0 or i == len(seqs) - 1):
            print(f"  {i + 1}/{len(seqs)} frames", file=sys.stderr)


def _write_video(out: Path, pictures, fps: float) -> None:
    """Write ``pictures`` into the video ``out``: under a hidden temporary name beside it (``create_beside``),
    moved to ``out`` once read back whole (``move_new``). OpenCV's writer says nothing of a write that failed (a
    full disk), hence the reading back: a video not whole is an OSError naming ``out`` (exit status 1), and
    neither ``out`` nor the temporary file is left."""
    import cv2
    from cv2.utils import logging as cv_log

    from pipeline.io.recording_files import create_beside, move_new

    f, tmp = create_beside(out, suffix=out.suffix)
    f.close()  # the name is ours; OpenCV writes it
    writer = None
    n = 0
    level = cv_log.getLogLevel()
    cv_log.setLogLevel(cv_log.LOG_LEVEL_ERROR)  # its warning at each failed frame: the one line is said below
    try:
        for _, pic in pictures:
            if writer is None:
                fourcc = cv2.VideoWriter.fourcc(*("mp4v" if out.suffix.lower() in (".mp4", ".mov") else "MJPG"))
                writer = cv2.VideoWriter(str(tmp), fourcc, fps, (pic.shape[1], pic.shape[0]))
                if not writer.isOpened():
                    raise CliError(f"OpenCV cannot write {out} (try an .avi or a folder of PNGs)")
            writer.write(pic)
            n += 1
        if writer is not None:
            writer.release()
            writer = None
        _check_video(tmp, out, n)
        move_new(tmp, out)
    except BaseException:
        if writer is not None:
            writer.release()
        tmp.unlink(missing_ok=True)
        raise
    finally:
        cv_log.setLogLevel(level)


def _check_video(tmp: Path, out: Path, n: int) -> None:
    """An OSError naming ``out`` unless the video written to ``tmp`` is there, not empty, and holds ``n`` frames."""
    import cv2

    size = tmp.stat().st_size
    got = 0
    if size:
        from pipeline.io.decoder_messages import decoder_messages

        with decoder_messages():  # FFmpeg's words on a file not written whole: the error below says it
            cap = cv2.VideoCapture(str(tmp))
        try:
            got = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        finally:
            cap.release()
    if got < n:
        raise OSError(errno.EIO, f"the video was not written whole ({max(got, 0)} of its {n} frames can be read back; "
                                 f"a full disk?); nothing written", str(out))


def _write_pictures(out: Path, pictures) -> None:
    """Write each picture as ``out/SEQ.png`` (none of them there: checked before). A write that fails (a full
    disk) is an OSError naming the picture (exit status 1), and the pictures written before it are removed, with
    ``out`` when it was made for them: a retry finds the folder as it was."""
    from pipeline.cli.commands.common import write_picture

    made = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    try:
        for s, pic in pictures:
            path = out / f"{s:06d}.png"
            write_picture(str(path), pic)
            written.append(path)
    except OSError:
        for p in written:
            p.unlink(missing_ok=True)
        if made:
            try:
                out.rmdir()
            except OSError:
                pass
        raise


def register(sub) -> None:
    p = sub.add_parser("render", help="draw the tracking overlays of a recording into a video or PNG frames",
                       description="Draws what the render stage sends to Foxglove (estimated box, ground truth, "
                                   "particles or experts, MAP contour or mesh, a status line) into each frame.")
    p.add_argument("file", help="MCAP recording")
    p.add_argument("out", help="OUT.mp4 / OUT.avi for a video, or a folder for PNG frames")
    p.add_argument("--frames", metavar="A:B", help="only frames A..B-1 (A alone: frame A)")
    p.add_argument("--scale", type=positive_int, default=2, help="upscale factor (default 2)")
    p.add_argument("--fps", type=video_rate, default=25.0, help="video frame rate (default 25; 0.01-1000)")
    p.add_argument("--no-particles", dest="particles", action="store_false", help="do not draw the particles")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_render)
