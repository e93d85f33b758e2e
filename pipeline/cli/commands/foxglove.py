"""``gflow foxglove IN.mcap OUT.mcap``: a copy of a recording the Foxglove app reads entirely."""

from __future__ import annotations

ORDER = 59

import argparse
import os
import sys
from typing import IO, TYPE_CHECKING

from pipeline.cli.commands.common import CliError, check_outputs

if TYPE_CHECKING:  # the export's modules are imported where used: the command's options and --help need none
    from pipeline.recording.foxglove_export import ExportSummary


def jpeg_quality(text: str) -> int:
    """A JPEG quality, a whole number 1-100 (argparse type)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number 1-100, got {text!r}") from None
    if not 1 <= v <= 100:
        raise argparse.ArgumentTypeError(f"must be 1-100, got {v}")
    return v


class _NothingCopied(Exception):
    """The copy holds no message: its file is not kept (:func:`_export_beside`)."""


def _export_beside(args: argparse.Namespace, topics: list[str] | None) -> ExportSummary:
    """The copy written under a hidden name beside OUT and moved there once whole, never over a file; a copy
    with no message is not kept. It was written straight into OUT: stopped midway (a full disk, Ctrl-C), it left
    the part written, a recording that looks like one, and the retry was refused as OUT existing."""
    from pipeline.io.recording_files import write_beside
    from pipeline.recording.foxglove_export import export_for_foxglove

    done: list[ExportSummary] = []

    def write(f: IO[bytes]) -> None:
        done.append(export_for_foxglove(args.recording, f, image_format=args.image_format, quality=args.quality,
                                        topics=topics))
        if not done[0].messages:
            raise _NothingCopied

    try:
        write_beside(args.out, write)
    except _NothingCopied:
        pass
    return done[0]


def cmd_foxglove(args) -> int:
    from pipeline.recording.topics import describe_topics

    from pipeline.io.mcap_io import check_recording

    check_recording(args.recording)  # missing or not MCAP: refused before OUT is created, not after
    if os.path.abspath(args.recording) == os.path.abspath(args.out):
        raise CliError("OUT must be a new file, not the recording itself")
    check_outputs(OUT=args.out)
    from pipeline.io.recording_files import refuse_existing

    refuse_existing(args.out, "OUT")  # a recording never overwrites a file
    topics = None
    if args.topics:  # as typed (frames, gflow/cam0/estimate, *): one that names nothing is an error
        from pipeline.cli.commands.recording import recording_topics

        topics = recording_topics(args.recording, args.topics)
    from pipeline.cli.commands.common import warn_if_torn

    warn_if_torn(args.recording)
    s = _export_beside(args, topics)
    if not s.messages:  # exit 1: the copy holds nothing to show, and is not left to look like one
        if topics and s.left_out:  # the topics chosen are all ones Foxglove cannot show: the option is the mistake
            raise CliError(f"--topics {' '.join(args.topics)}: Foxglove cannot show "
                           f"{describe_topics(s.left_out)} (binary arrays), so there is nothing to copy")
        from pipeline.io.mcap_io import damage_cause, damage_told, torn_cause

        why = damage_cause(args.recording) or torn_cause(args.recording)
        damage_told(why)  # said in the line below: not warned again when the command ends
        print(f"gflow foxglove: no message of {args.recording} could be copied" + (f" ({why})" if why else "")
              + f"; {args.out} not written", file=sys.stderr)
        return 1
    print(f"wrote {args.out}: {s.messages} messages on {len(s.by_topic)} topics: "
          f"{describe_topics(s.by_topic, counts=s.by_topic)}")
    left = ([f"{describe_topics(s.left_out, counts=s.left_out)} (binary arrays Foxglove cannot show)"]
            if s.left_out else []) + ([f"{s.markers} end-of-stream markers"] if s.markers else [])
    if left:
        print("left out: " + "; ".join(left))
    from pipeline.cli.commands.common import partial_if_damaged

    return partial_if_damaged(args.recording, "foxglove", args.out)


def register(sub) -> None:
    p = sub.add_parser("foxglove", help="copy a recording into one the Foxglove app reads entirely",
                       description="gflow records its messages as MessagePack, which Foxglove cannot decode. This "
                                   "writes a copy with the frames as foxglove.CompressedImage, the render stage's "
                                   "images and annotations as they are, and the estimates (box, pose, ESS, state), "
                                   "errors and heartbeats as JSON for the Plot panel, and each estimate's box as "
                                   "foxglove.ImageAnnotations on gflow/STREAM/box (an Image panel on frames draws it). "
                                   "Features, particles and snapshots are left out. Keep the original for rerun, diff and step.",
                       epilog="example: gflow foxglove run.mcap run-foxglove.mcap   (then open it in Foxglove)")
    p.add_argument("recording", help="gflow MCAP recording")
    p.add_argument("out", help="the copy to write (.mcap)")
    p.add_argument("--image-format", choices=["jpeg", "png"], default="jpeg", help="frames as (default jpeg)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC",
                   help="copy only these topics: the name in the stream (frames estimate), the full name with or "
                        "without the run id, or a shell pattern")
    p.add_argument("--quality", type=jpeg_quality, default=90, help="JPEG quality 1-100 (default 90)")
    p.set_defaults(func=cmd_foxglove)
