"""``gflow info`` and ``gflow replay``: what a file holds, and putting a recording back on zenoh."""

from __future__ import annotations

ORDER = 50

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.cli.commands.common import (CliError, add_zenoh_args, chosen_topics, nonnegative_float, nonnegative_int,
                                          positive_float, stream_name, tool_zenoh)

if TYPE_CHECKING:
    from pipeline.io.mcap_io import RecordingSummary
    from pipeline.recording.unread import NotRead

# file suffix -> callable(path, as_json) printing a description; other modules add to it
DESCRIBERS: dict = {}


def describe_recording(path: str, as_json: bool) -> int:
    """Print what recording ``path`` holds (text, or JSON with ``as_json``); 1 when it cannot be trusted as a
    record of its run (damaged, or no message read), with one line on stderr saying why and where."""
    from pipeline.io.mcap_io import summarize

    from pipeline.recording.live_record import live_summary

    s = summarize(path)
    if not s.damaged:  # damage the reader passes over (a record's opcode): found as `gflow verify` finds it
        from pipeline.recording.verify import recording_damage

        found = recording_damage(path)
        if found:
            s.truncated, s.damaged, s.damage = "; ".join(t for t in (found, s.truncated) if t), True, found
    missed = None
    if s.damaged:  # the chunks the count leaves out, and their messages, as far as the file tells
        from pipeline.recording.unread import not_read

        missed = not_read(path)
    elif s.truncated:  # torn, and read to the cut: the record it ends inside
        from pipeline.recording.unread import cut_short

        missed = cut_short(path, s.messages)
    live = live_summary(path)  # None unless a live source made it
    bad = s.unreadable
    if as_json:
        print(json.dumps(dict(s.to_json(), **({"live": live.to_json()} if live else {}),
                              unreadable=bad or None, not_read=missed.to_json() if missed else None), indent=1))
        return 1 if bad else 0
    print(f"file:      {s.path}")
    print(f"messages:  {s.messages}   duration: {s.duration_s:.3f} s")
    if missed is not None:
        print(f"not read:  {missed.line(path, s.messages)}")
    if s.segments:
        print(f"segments:  {', '.join(s.segments)} (a restarted recorder; read as one recording)")
    if s.truncated:
        print(f"WARNING:   {s.truncated}")
    for line in s.sessions.lines():
        print(f"outside:   {line}")
    print("topics:")
    for t, ts in sorted(s.topics.items()):
        seqs = f"seq {ts.first_seq}..{ts.last_seq}" if ts.first_seq >= 0 else ""
        print(f"  {t:42s} {ts.type:20s} {ts.count:7d} msgs {ts.rate_hz:8.1f} Hz {ts.bytes / 2**20:9.2f} MiB  {seqs}")
    if live is not None:
        print("live:     " + "\n          ".join(live.lines()))
    print("schemas:  " + ", ".join(f"{n} ({e})" for n, e in sorted(s.schemas.items())))
    for name, md in s.metadata.items():
        print(f"metadata {name}:")
        for k, v in md.items():
            v1 = v if len(v) < 200 else v[:200] + f"... ({len(v)} chars)"
            print(f"  {k}: {v1}" if "\n" not in v1 else f"  {k}: |\n    " + v1.replace("\n", "\n    "))
    if bad:  # exit 1: a script must not take this file for a good recording
        from pipeline.io.mcap_io import damage_cause, damage_told

        damage_told(damage_cause(path))  # said above, in the WARNING line of the summary
        print(_unreadable_line(path, s, missed), file=sys.stderr)
        return 1
    return 0


def _unreadable_line(path: str, s: RecordingSummary, missed: NotRead | None) -> str:
    """info's one line on stderr for a recording it cannot vouch for: why, where the damage is (its byte, as the
    WARNING line and `gflow verify` name it), the messages read and what was not read."""
    from pipeline.io.mcap_io import damage_place

    place = ""
    if s.damaged:
        place = damage_place(s.damage, path)
        if not place:  # a reader's report that names no byte (a damaged length ran a record to the file's end)
            from pipeline.recording.verify import recording_damage

            place = damage_place(recording_damage(path), path)
    lost = f"; {missed.short()}" if missed is not None else ""
    return (f"gflow info: {path}: {s.unreadable}{f' at {place}' if place else ''} ({s.messages} "
            f"message{'s' * (s.messages != 1)} read{lost})")


DESCRIBERS[".mcap"] = describe_recording


def describe_model(path: str, as_json: bool) -> None:
    from pipeline.io.modelfile import describe  # lazy: numpy model code only when a model is described

    describe(path, as_json)


DESCRIBERS[".npz"] = describe_model


def cmd_info(args) -> int:
    from pipeline.cli.trackers import TRACKERS  # the registry: imported (with numpy) when asked for, below

    if not Path(args.file).is_file() and args.file in TRACKERS:
        from pipeline.cli.tracker_info import print_tracker

        print_tracker(args.file, args.json)
        return 0
    suffix = Path(args.file).suffix.lower()
    if Path(args.file).is_dir() and suffix != ".npz":  # a model file's name: its reader says it is a folder
        from pipeline.io.mcap_io import check_recording

        check_recording(args.file)  # "adir is a folder, not a recording file", as every command that reads one says
    fn = DESCRIBERS.get(suffix)
    if fn is None:
        raise CliError(f"do not know how to describe {args.file} (known: {', '.join(sorted(DESCRIBERS))} files, or a "
                   f"tracker: {', '.join(sorted(TRACKERS))})")
    return int(fn(args.file, args.json) or 0)


def recording_topics(path: str, patterns: list[str]) -> list[str]:
    """The topics of recording ``path`` that ``patterns`` name (:func:`pipeline.recording.topics.select_topics`);
    a pattern matching none is a one-line error listing the recording's topics."""
    from pipeline.io.mcap_io import recorded_topics

    return chosen_topics(patterns, recorded_topics(path), where=path)


#: the slowest --speed: 1000 times slower than recorded (a slower one waited past what a sleep can take)
MIN_SPEED = 0.001


def replay_speed(text: str) -> float:
    """A timing factor, a finite number >= :data:`MIN_SPEED` (argparse type): ``--speed 1e-308`` ended in an
    'internal error' (a wait of more seconds than the clock holds) once the first message was sent."""
    import argparse

    v = positive_float(text)  # a number > 0 (not NaN, not inf)
    if v < MIN_SPEED:
        raise argparse.ArgumentTypeError(f"must be >= {MIN_SPEED:g} (1000 times slower than recorded), got "
                                         f"{text.strip()}")
    return v


def _lockstep(text: str | None) -> tuple[str, ...]:
    """The stages ``--lockstep`` names: ``,`` (nothing named) was replayed with no lockstep without a word, and a
    stage named twice waited for its heartbeat and then said ``no heartbeat from filter, filter``."""
    from pipeline.app.names import comma_names

    if text is None:
        return ()
    try:
        names = comma_names(text, "--lockstep")
    except ValueError as e:
        raise CliError(str(e)) from None
    if not names:
        raise CliError(f"--lockstep {text!r} names no stage (give the stages' names, e.g. filter,proposal)")
    return tuple(names)


def cmd_replay(args) -> int:
    from pipeline.cli.live import NoSuchStage, ReplayOptions, StreamInUse, replay

    opts = ReplayOptions(speed=None if args.max else args.speed, topics=args.topics, start_seq=args.from_seq,
                         end_seq=args.to_seq, start_s=args.start, end_s=args.end, loops=args.loop,
                         lockstep=_lockstep(args.lockstep),
                         ack_timeout=args.ack_timeout, stream=args.stream)
    import dataclasses

    from pipeline.io.mcap_io import check_recording
    from pipeline.runtime.transport import free_port

    check_recording(args.file)  # a missing or non-MCAP file is refused before joining the network
    if args.stream:
        from pipeline.runtime.transport import topic_key

        try:
            topic_key(args.stream, "x")
        except ValueError as e:
            raise CliError(f"--stream: {e}") from None
    from pipeline.cli.commands.common import warn_if_torn

    warn_if_torn(args.file)
    if args.topics:  # the names as typed (estimate, gflow/cam0/frames, *): refused before joining if none fits
        opts.topics = recording_topics(args.file, args.topics)

    settings, found = tool_zenoh(args, require=False)  # joins the running pipelines, if any
    if not args.listen and settings.mode != "client":
        settings = dataclasses.replace(settings, listen=(f"tcp/127.0.0.1:{free_port()}",))
    where = [e for e in settings.listen if not e.endswith(":0")]
    def ready() -> None:  # printed once the session is open: a Ctrl-C after this line ends the replay
        print(f"replaying {args.file}; listening on {', '.join(where)}"
              + (f"; joined {', '.join(str(i['pid']) for i in found)}" if found else ""), file=sys.stderr, flush=True)

    try:
        done = replay(settings, args.file, opts, announce_endpoints=where, ready=ready)
    except (TimeoutError, StreamInUse, NoSuchStage) as e:
        raise CliError(str(e)) from None
    if done.interrupted and done.planned:  # cut short: not taken for the whole of what was asked
        print(f"gflow replay: interrupted after {done.sent} of the {done.planned} messages to replay from "
              f"{args.file}", file=sys.stderr)
        return 130
    until = " (until interrupted)" if done.interrupted else ""
    print(f"replayed {done.sent} messages from {args.file}{until}", file=sys.stderr)
    from pipeline.cli.commands.common import partial_if_damaged

    return partial_if_damaged(args.file, "replay", "the replay")


def register(sub) -> None:
    p = sub.add_parser("info", help="what a recording (.mcap) or a learned model (.npz) holds, or a tracker's "
                                    "parameters",
                       description="For a recording: topics, counts, rates, duration, schemas and metadata. For a "
                                   "tracker (gflow info gflow): its parameters with their defaults and help, and "
                                   "each stage's own.")
    p.add_argument("file", help="MCAP recording, model file or tracker name")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="republish a recording on zenoh",
                       description="Republishes recorded messages byte for byte on their topics, so live stages or a "
                                   "viewer can consume them. Heartbeats and control messages are not replayed.",
                       epilog="examples:\n  gflow replay run.mcap --speed 2\n"
                              "  gflow replay run.mcap --max --topics gflow/cam0/frames --from-seq 100 --to-seq 200\n"
                              "  gflow replay run.mcap --topics gflow/cam0/frames --lockstep preprocess,filter --max\n"
                              "  gflow replay run.mcap --loop 0   (until Ctrl-C)",
                       formatter_class=__import__("argparse").RawDescriptionHelpFormatter)
    p.add_argument("file", help="MCAP recording")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--speed", type=replay_speed, default=1.0,
                   help=f"timing factor on the original timing, >= {MIN_SPEED:g} (default 1; 2 = twice as fast)")
    g.add_argument("--max", action="store_true", help="as fast as possible")
    p.add_argument("--topics", nargs="+", metavar="TOPIC",
                   help="only these topics: the name in the stream (frames), the full name with or without the "
                        "run id (gflow/cam0/frames), or a shell pattern (gflow/*/estimate)")
    p.add_argument("--from-seq", type=nonnegative_int, metavar="SEQ", help="first frame to replay")
    p.add_argument("--to-seq", type=nonnegative_int, metavar="SEQ", help="stop before this frame")
    p.add_argument("--start", type=nonnegative_float, metavar="S", help="start this many seconds into the recording")
    p.add_argument("--end", type=nonnegative_float, metavar="S", help="stop this many seconds into the recording")
    p.add_argument("--loop", type=nonnegative_int, default=1, metavar="N", help="play N times (0 = until Ctrl-C; default 1)")
    p.add_argument("--lockstep", metavar="STAGE[,STAGE]",
                   help="before each new frame, wait until these live stages acknowledge the previous one (a name "
                        "the pipeline running on the stream on this machine does not have is refused at once)")
    p.add_argument("--stream", metavar="NAME", type=stream_name,
                   help="publish on gflow/NAME/... instead of the recorded stream (a stream a running pipeline holds "
                        "is refused unless named here or fed with --lockstep)")
    p.add_argument("--ack-timeout", type=positive_float, default=10.0, help="with --lockstep: seconds to wait for a stage to acknowledge a frame (default 10)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_replay)
