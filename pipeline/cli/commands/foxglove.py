"""``gflow foxglove IN.mcap OUT.mcap``: a copy of a recording the Foxglove app reads entirely."""

from __future__ import annotations

ORDER = 59

import argparse
import os
import sys

from pipeline.cli.commands.common import CliError, check_outputs


def jpeg_quality(text: str) -> int:
    """A JPEG quality, a whole number 1-100 (argparse type)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number 1-100, got {text!r}") from None
    if not 1 <= v <= 100:
        raise argparse.ArgumentTypeError(f"must be 1-100, got {v}")
    return v


def cmd_foxglove(args) -> int:
    from pipeline.recording.foxglove_export import export_for_foxglove
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
    s = export_for_foxglove(args.recording, args.out, image_format=args.image_format, quality=args.quality,
                            topics=topics)
    if not s.messages:  # exit 1: the copy holds nothing to show, and is not left to look like one
        os.remove(args.out)
        if topics and s.left_out:  # the topics chosen are all ones Foxglove cannot show: the option is the mistake
            raise CliError(f"--topics {' '.join(args.topics)}: Foxglove cannot show "
                           f"{describe_topics(s.left_out)} (binary arrays), so there is nothing to copy")
        from pipeline.io.mcap_io import damage_cause, damage_told, torn_cause

        why = damage_cause(args.recording) or torn_cause(args.recording)
        damage_told(why)  # said in the line below: not warned again when the command ends
        print(f"gflow foxglove: no message of {args.recording} could be copied" + (f" ({why})" if why else "")
              + f"; {args.out} removed", file=sys.stderr)
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
