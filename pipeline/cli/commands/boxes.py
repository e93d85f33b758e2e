"""``gflow boxes RECORDING --out CSV``: the boxes (frame,x,y,w,h,confidence,state) of any recording, whether it was
closed properly, torn by a killed recorder, recovered with ``gflow recover``, or written in
segments by a restarted recorder."""

from __future__ import annotations

ORDER = 57

from pipeline.cli.commands.common import CliError, check_new_file, stream_name


def cmd_boxes(args) -> int:
    # imported here: the recording's readers (mcap, the messages, OpenCV) are not needed to parse the options
    from pipeline.io.mcap_io import Damaged, damage_told, iter_records, segments
    from pipeline.recording.live_record import live_summary
    from pipeline.recording.results import (completeness, estimate_columns, renumber, reported_frames, run_estimates,
                                           write_boxes)

    check_new_file(out=args.out)  # before reading: a folder, or a file it would write over
    torn: list[str] = []
    list(iter_records(args.recording, topics=["-"], on_truncated=torn.append))  # checks the file; notes a torn end
    for text in torn:  # said below with the boxes (or in the error): the reading of the estimates does not warn again
        damage_told(text)
    est, sessions = run_estimates(args.recording, stream=args.stream)  # the run's own: what came from outside is said
    if not est:  # a torn recording says where it ends, so "no estimates" is not taken for what the run made
        raise CliError(f"{args.recording} holds no estimates" + (f" for stream {args.stream!r}" if args.stream else "")
                       + (f": the {torn[0].split(': ', 1)[-1]}" if torn else "") + _streams_with_estimates(args))
    live = live_summary(args.recording, stream=args.stream)  # a live run: rows are the camera's frames
    frame_of = live.frames if live is not None else {}
    by_seq = estimate_columns(est)
    boxes, confidence, states = (renumber(by_seq[0], frame_of), renumber(by_seq[1], frame_of),
                                 renumber(by_seq[2], frame_of))
    # beside its name, moved there once complete: a write that fails leaves no part of the file to refuse a retry
    write_boxes(args.out, boxes, confidence, states, live.inputs(boxes) if live is not None else None, new=True)
    segs = segments(args.recording)
    print(f"{len(boxes)} boxes, frames {min(boxes)}-{max(boxes)}, written to {args.out}"
          + (f" (from {len(segs)} segments)" if len(segs) > 1 else ""))
    for line in [t for t in torn if not isinstance(t, Damaged)] + sessions.lines():  # damage: said on stderr below
        print(f"  {line}")
    gaps = completeness(est, None, reported_frames(args.recording, args.stream), blank=_blank_rule(args.recording))
    for line in gaps:
        print(f"  {line}")
    from pipeline.cli.commands.common import partial_if_damaged

    return 3 if any("no estimate" in g for g in gaps) else partial_if_damaged(args.recording, "boxes", args.out, 3)


def _streams_with_estimates(args) -> str:
    """``; it holds estimates of stream cam0`` when --stream named another one (a mistyped stream)."""
    from pipeline.io.mcap_io import recorded_topics
    from pipeline.recording.topics import split_topic

    if not args.stream:
        return ""
    pairs = [split_topic(t) for t in recorded_topics(args.recording)]
    streams = sorted({p[0] for p in pairs if p is not None and p[1] == "estimate"})
    return f"; it holds estimates of stream {', '.join(streams)}" if streams else ""


def _blank_rule(recording: str) -> str:
    """What made a read frame blank for the recorded run's tracker (:func:`blank_rule` of its plan), or
    the plain words when the recording's plan cannot be read (made by another tool, or a stage kind
    not installed here)."""
    from pipeline.recording.rerun import recorded_plan
    from pipeline.recording.results import blank_rule
    from pipeline.runtime.graph import GraphError

    try:
        return blank_rule(recorded_plan(recording))
    except (GraphError, ValueError, KeyError, TypeError):
        return blank_rule(None)


def register(sub) -> None:
    p = sub.add_parser("boxes", help="write the boxes (frame,x,y,w,h,confidence,state) tracked in a recording",
                       description="Rebuild the box CSV of a run from its recording: closed, torn (a killed "
                                   "recorder), recovered, or in segments (a restarted recorder). Names the frames "
                                   "that have no estimate (exit status 3) and those that coasted; a recording "
                                   "damaged inside gives the boxes before the damage, with exit status 3 too.",
                       epilog="example: gflow boxes recordings/track-20260101-120000.mcap --out boxes.csv")
    p.add_argument("recording", help="the .mcap recording (its NAME.partN.mcap segments are read too)")
    p.add_argument("--out", required=True, metavar="CSV", help="output boxes (frame,x,y,w,h,confidence,state)")
    p.add_argument("--stream", type=stream_name, help="only this stream's estimates (default: all)")
    p.set_defaults(func=cmd_boxes)
