"""Helpers shared by the commands: errors, zenoh options, running a plan."""

from __future__ import annotations

import argparse
import importlib
import math
import os
import dataclasses  # noqa: F401 (common.dataclasses: tests replace a run's settings with it)
from typing import IO, TYPE_CHECKING, Any

from pipeline.app.errors import RequestError as CliError  # a user error: printed as one line, exit status 2
from pipeline.cli.endpoints import parse_endpoint
from pipeline.cli.security_options import add_security_args, apply_security

if TYPE_CHECKING:  # imported when first asked for (__getattr__ below)
    from pipeline.runtime.graph import Plan
    from pipeline.runtime.transport import ZenohSettings  # imported where used: the transport (zenoh, ssl) cost
    # every command ~0.1 s of CPU
    from pipeline.app import (DEFAULT_ENDPOINT, check_stage_values, parse_sets, sets_as_given,
                              temporary_recording)
    from pipeline.cli.commands._recording import Recording

#: what this module hands on from the application layer (and :class:`Recording`), imported when a
#: command first asks for it: the commands that run no graph (info, verify, eval, the live tools...)
#: start without the application layer (about 0.1 s of CPU at every start)
_LAZY = {**dict.fromkeys(("DEFAULT_ENDPOINT", "check_stage_values", "parse_sets", "sets_as_given",
                          "temporary_recording"), "pipeline.app"),
         "Recording": "pipeline.cli.commands._recording"}


def __getattr__(name: str) -> Any:
    where = _LAZY.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(where), name)
    globals()[name] = value
    return value

__all__ = ["CliError", "run_status", "start_work", "work_started", "refuse_same_source", "DEFAULT_ENDPOINT", "parse_box", "parse_endpoint", "positive_float", "positive_int", "nonnegative_float", "nonnegative_int", "whole_number", "number", "frame_range", "range_note", "range_past_note", "say_notes", "source_frames", "check_outputs", "check_new_file", "check_model_out", "refuse_recording", "refuse_dangling_link", "chosen_topics",
           "check_stage_values", "sets_as_given", "parse_sets", "zenoh_from_args", "tool_zenoh", "stream_of",
           "launcher_zenoh", "add_record_args", "Recording", "add_zenoh_args", "add_placement_args", "place",
           "temporary_recording", "run_plan", "torn_segments", "warn_if_torn"]


#: whether the command running has begun its work (:func:`start_work`)
_work_started = [False]


def start_work(started: bool = True) -> None:
    """Say that the command's checks are done and its work begins: from here on a ValueError is the work
    failing (``gflow``: exit status 1), not a mistake in the command found before any work (exit status 2).
    The errors that name a mistake whenever they come (:class:`CliError`, a path refused, a graph's mistake...)
    stay exit status 2. ``start_work(False)``: not begun (``gflow``, as each command starts)."""
    _work_started[0] = started


def work_started() -> bool:
    """Whether the command running has said its work began (:func:`start_work`)."""
    return _work_started[0]


def refuse_same_source(paths: list, given: list[str], what: str) -> None:
    """A training source named twice (``gflow learn m2 A A``, or a dataset folder and its ``frames/``): each of its
    frames was learned from twice without a word, as if it were twice as common. ``paths``: the files or folders
    the sources ``given`` resolve to; refused naming both, before any is read."""
    from pathlib import Path

    seen: dict = {}
    for path, text in zip(paths, given):
        key = Path(path).resolve()
        if key in seen:
            also = "" if seen[key] == text else f" (as {seen[key]} and as {text})"
            raise CliError(f"{what} {text} is given twice{also}; give each {what} once (its frames would be learned "
                           "from twice)")
        seen[key] = text


def parse_box(text: str) -> tuple[float, float, float, float]:
    try:
        vals = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,W,H numbers, got {text!r}") from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"expected 4 numbers X,Y,W,H, got {len(vals)}")
    if not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError("box has NaN or inf")
    if vals[2] <= 0 or vals[3] <= 0:
        raise argparse.ArgumentTypeError(f"box width and height must be positive, got W={vals[2]}, H={vals[3]}")
    return vals


def _at_least(text: str, kind: type, least: float, inclusive: bool) -> float:
    """``text`` read as a finite ``kind`` (float or int) above ``least`` (or equal, with ``inclusive``),
    or ``argparse.ArgumentTypeError`` saying what it must be (the argparse types below)."""
    whole = kind is int
    try:
        v = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {'a whole number' if whole else 'a number'}, got {text!r}") from None
    # a whole number is finite however large (math.isfinite overflows on one past a float's range)
    if not ((whole or math.isfinite(v)) and (v >= least if inclusive else v > least)):
        raise argparse.ArgumentTypeError(f"must be {'' if whole else 'a number '}{'>=' if inclusive else '>'} "
                                         f"{least:g}, got {text.strip()}")
    return v


def whole_number(text: str) -> int:
    """A whole number of any sign (argparse type), for an option whose range the command checks itself
    (naming the option and why); not one (``abc``, ``1.5``): "expected a whole number", as the bounded types
    say it, not argparse's "invalid int value"."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def number(text: str) -> float:
    """A finite number of any sign (argparse type), for an option whose range the command checks itself;
    not one: "expected a number" (not argparse's "invalid float value"), and NaN or infinity is refused."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text.strip()}")
    return v


def positive_float(text: str) -> float:
    """A finite number > 0 (argparse type)."""
    return float(_at_least(text, float, 0, inclusive=False))


def source_rate(text: str) -> float:
    """A source's frame rate (argparse type): a finite number of at least ``gflow_msgs.source.MIN_FPS`` frames/s
    (a rate of 1e-300 stamped frames past any integer: the source failed in an OverflowError)."""
    from gflow_msgs.source import MIN_FPS

    return float(_at_least(text, float, MIN_FPS, inclusive=True))


#: the frame rates a video file is written at (``gflow render --fps``): outside them OpenCV's writer would not
#: open an .mp4 (and said so in lines of its own, before an error that blamed the file's kind), and an .avi past
#: 1000 frames/s read back short (an error that asked about a full disk)
VIDEO_FPS = (0.01, 1000.0)


def video_rate(text: str) -> float:
    """A video file's frame rate (argparse type): a number in :data:`VIDEO_FPS`."""
    low, high = VIDEO_FPS
    v = float(_at_least(text, float, low, inclusive=True))
    if v > high:
        raise argparse.ArgumentTypeError(f"a video's frame rate is {low:g}-{high:g}, got {text.strip()}")
    return v


def nonnegative_float(text: str) -> float:
    """A finite number >= 0 (argparse type)."""
    return float(_at_least(text, float, 0, inclusive=True))


def nonnegative_int(text: str) -> int:
    """A whole number >= 0 (argparse type)."""
    return int(_at_least(text, int, 0, inclusive=True))


def positive_int(text: str) -> int:
    """A whole number >= 1 (argparse type)."""
    return int(_at_least(text, int, 1, inclusive=True))


def frame_range(text: str | None, option: str = "--frames") -> tuple[int, int | None]:
    """``--frames A:B`` as every command reads it (:func:`pipeline.io.datasets.parse_range`: ``5`` is frame 5
    alone, ``A:`` frame A on, none every frame) -> (start, stop); a malformed, negative or empty range is a
    :class:`CliError` naming ``option`` and the value typed."""
    from pipeline.io.datasets import parse_range

    try:
        return parse_range(text)
    except ValueError as e:
        raise CliError(f"{option} {text}: {e}") from None


def range_note(asked: str, where: str, held: str, took: str) -> str:
    """The line that says what a range option that runs past its input took: ``note: --frames 19:25: run.mcap
    holds frames 0..19; drawing 19..19`` (``asked``: the option as typed; ``held``: what ``where`` holds;
    ``took``: what the command does with the part it took). A range clipped to its input was taken without a
    word, as though every frame asked for were there; one that takes nothing is an error instead."""
    return f"note: {asked}: {where} holds {held}; {took}"


def range_past_note(asked: str, want: tuple[int, int | None], where: str, held: tuple[int, int],
                    took: tuple[int, int], verb: str, unit: str = "frames") -> str:
    """:func:`range_note` when the range ``want`` (start, stop: start <= frame < stop) runs before the first or
    past the last of the frames ``held`` (first, last) by ``where``; ``took``: the first and last frame taken,
    said after ``verb`` ("drawing"); ``unit``: what the numbers count. "" when the range lies within them."""
    (start, stop), (first, last) = want, held
    if start < first or (stop is not None and stop > last + 1):
        return range_note(asked, where, f"{unit} {first}..{last}", f"{verb} {took[0]}..{took[1]}")
    return ""


def say_notes(*lines: str) -> None:
    """Each line that is not empty, on stderr (:func:`range_past_note`'s, once the command's checks are done: a
    mistake's error is then the one line there)."""
    import sys

    for line in lines:
        if line:
            print(line, file=sys.stderr)


def source_frames(source: str | os.PathLike) -> int | None:
    """How many frames (0..n-1) an image folder (or a dataset folder with frames/) or a video holds, when it can
    be known without decoding them; None otherwise (an AVLetters file's frames are chosen by utterance)."""
    from stages.source import SourceParams

    from pipeline.io.datasets import resolve_source
    from pipeline.io.frame_readers import count_frames

    kind, path = resolve_source(source)
    if kind == "avletters":
        return None
    return count_frames(SourceParams(kind=kind, path=str(path))) or None


def check_outputs(**paths: str | None) -> None:
    """Refuse, before any work, output paths that are folders or cannot be written.

    ``check_outputs(out=args.out, record=args.record)``: each keyword names the option (an
    upper-case keyword, ``FIXED=...``, names a positional argument).
    """
    from pathlib import Path

    from pipeline.runtime.preflight import check_writable

    given: dict[Path, str] = {}  # two outputs on one file: the last one written would be all that is left
    for opt, path in paths.items():
        if path:
            name = _option_name(opt)
            same = given.setdefault(Path(path).resolve(), name)
            if same != name:
                raise CliError(f"{name} {path} is also {same}: give each output a file of its own")
            refuse_recording(path, name)
            check_writable(path, name)


def _option_name(keyword: str) -> str:
    """The option as typed for a keyword of :func:`check_outputs` (``points_out`` -> ``--points-out``)."""
    return keyword if keyword.isupper() else "--" + keyword.replace("_", "-")


def check_new_file(**paths: str | None) -> None:
    """:func:`check_outputs`, and refuse a file that is already there: boxes, face points or a model
    written over it would replace an earlier answer without a word (as a recording, a picture or
    a video is never written over). Keywords as :func:`check_outputs`'s."""
    check_outputs(**paths)
    for opt, path in paths.items():
        if path and os.path.lexists(path):
            raise CliError(f"{_option_name(opt)} {path} exists; gflow never writes over an earlier output: "
                           f"give another name (or remove it first)")


def check_model_out(path: str) -> None:
    """``gflow learn --out``: a new model file is named .npz (``gflow info`` and ``gflow track`` know it by
    that); any other name, a training frame's say, would be written over with the model."""
    check_outputs(out=path)
    if not path.lower().endswith(".npz"):
        raise CliError(f"--out {path}: a model file's name ends in .npz")
    check_new_file(out=path)  # an earlier model


def check_new_picture(path: str, option: str = "OUT") -> None:
    """:func:`check_outputs`, and refuse an existing file: a video or picture written there would
    replace it (as a recording is never written over)."""
    check_outputs(**{option: path})
    if os.path.lexists(path):
        raise CliError(f"{path} exists; gflow never writes over a picture or video: give another name "
                       f"(or remove it first)")


def refuse_dangling_link(path: str | None, option: str) -> None:
    """Refuse an output ``path`` that is a symbolic link to nothing, naming ``option`` and where the link points
    (:func:`pipeline.io.path_errors.dangling_link`): for the outputs :func:`check_outputs` does not see (a folder
    to write into, a file written by another program)."""
    from pipeline.io.path_errors import dangling_link

    why = dangling_link(path, option) if path else ""
    if why:
        raise CliError(why)


def refuse_recording(path: str, option: str) -> None:
    """Refuse to write over a recording: ``path`` is an existing file that begins as an MCAP file
    does (whatever its name), so a CSV, model or picture written there would destroy it."""
    try:
        with open(path, "rb") as f:
            from pipeline.io.mcap_writer import MAGIC  # (mcap) only when there is a file to look at

            head = f.read(len(MAGIC))
    except OSError:
        return  # no such file (or not readable: check_writable names it)
    if head == MAGIC:
        raise CliError(f"{option} {path} is a recording; gflow never writes over one: give another name")


def chosen_topics(patterns: list[str] | None, available, where: str) -> list[str]:
    """The topics of ``available`` that ``--topics`` names (:func:`pipeline.recording.topics.select_topics`: as typed,
    estimate, gflow/demo/estimate, patterns); a pattern matching none is a one-line error naming the option, the
    pattern, ``where`` it looked and the topics there."""
    from pipeline.recording.topics import TopicError, select_topics

    try:
        return select_topics(patterns, available, where=where)
    except TopicError as e:
        raise CliError(f"--topics {e.pattern}: no topic of {e.where} matches it; it holds: {e.held}") from None


def zenoh_from_args(args, default_connect: bool) -> ZenohSettings:
    from pipeline.runtime.transport import ZenohSettings

    security = apply_security(args)
    listen = tuple(args.listen or ())
    connect = tuple(args.connect or ())
    if default_connect and not connect and args.mode != "router":
        from pipeline.app import DEFAULT_ENDPOINT

        connect = (DEFAULT_ENDPOINT,)
    if not listen:
        listen = ("tcp/127.0.0.1:0",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=connect, multicast=args.multicast, security=security)


def tool_zenoh(args, stream: str | None = None, require: bool = True) -> tuple[ZenohSettings, list[dict]]:
    """Settings for a tool joining a live pipeline, and the announcements it connects to.

    With ``--connect`` (or in router / client mode with explicit endpoints) the user's endpoints
    are used. Otherwise the tool connects to every pipeline announced on this machine (of
    ``stream`` when given: see :mod:`pipeline.runtime.running`); with ``require`` and none running it is
    a :class:`CliError` saying so.
    """
    from pipeline.runtime.running import describe_none, running
    from pipeline.runtime.transport import ZenohSettings

    security = apply_security(args)
    if args.connect or args.mode == "router" or args.multicast:
        return zenoh_from_args(args, default_connect=False), []
    found = running(stream)
    if not found and require:
        raise CliError(describe_none(stream))
    endpoints = tuple(dict.fromkeys(e for i in found for e in i.get("endpoints", [])))
    listen = tuple(args.listen or ()) or ("tcp/127.0.0.1:0",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=endpoints, multicast=False, security=security), found


def stream_of(key: str) -> str | None:
    """The stream named by a key expression ``gflow/<stream>/...`` (None for a wildcard)."""
    parts = key.split("/")
    if len(parts) >= 2 and parts[0] == "gflow" and parts[1] and "*" not in parts[1] and "$" not in parts[1]:
        return parts[1]
    return None


def launcher_zenoh(args) -> ZenohSettings:
    """The launcher listens on 7447 (so `gflow topics` finds it) unless busy or told otherwise."""
    from pipeline.app import default_listen
    from pipeline.runtime.transport import ZenohSettings

    security = apply_security(args)
    listen = tuple(args.listen) if args.listen else default_listen()
    return ZenohSettings(mode=args.mode, listen=listen, connect=tuple(args.connect or ()), multicast=args.multicast,
                         security=security)


def add_record_args(p: argparse.ArgumentParser, default: str) -> None:
    """``--record FILE``, ``--no-record`` and ``--record-topics PATTERN``."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--record", metavar="FILE", help=f"recording path (default {default})")
    g.add_argument("--no-record", action="store_true",
                   help="keep no recording (results are still written; a re-run, replay or render needs one)")
    p.add_argument("--record-topics", action="append", metavar="PATTERN[,PATTERN]",
                   help="record only these topics, as shell patterns on the name after gflow/STREAM/, e.g. "
                        "'estimate,particles' or '*' (errors and heartbeats are always kept; raw frames are "
                        "most of a recording's size)")


def add_zenoh_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh network (default: peer mode on loopback, multicast scouting off)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer", help="zenoh session mode (default peer)")
    g.add_argument("--listen", action="append", metavar="ENDPOINT", type=parse_endpoint,
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    g.add_argument("--connect", action="append", metavar="ENDPOINT", type=parse_endpoint,
                   help="endpoint to connect to, e.g. tcp/10.0.0.5:7447 for a zenoh router (repeatable)")
    g.add_argument("--multicast", action="store_true", help="enable multicast scouting (off by default)")
    add_security_args(p.add_argument_group("security (TLS, login, signed runs: docs/security.md)"))


def stream_name(text: str) -> str:
    """A stream's name (argparse type): not empty (``--stream ''``, an empty shell variable, was taken for no --stream
    at all), without '/' or '*' (they would reach into other streams' topics)."""
    if not text.strip() or "/" in text or "*" in text:
        raise argparse.ArgumentTypeError(f"a stream is a non-empty name without '/' or '*', got {text!r}")
    return text


def add_placement_args(p: argparse.ArgumentParser, hosts: bool = True) -> None:
    """``--stream NAME`` (the run's stream; default: the graph's plus a new run id) and, for
    ``gflow run``, ``--host LABEL`` (repeatable: start only the stages placed there)."""
    g = p.add_argument_group("placement and run id (docs/deployment.md)")
    g.add_argument("--stream", metavar="NAME", type=stream_name,
                   help="this run's stream: topics are gflow/NAME/... (default: the graph's stream plus a new run id, "
                        "so two runs never mix; with --host, the graph's stream: give every host the same NAME)")
    if hosts:
        g.add_argument("--host", action="append", metavar="LABEL", dest="hosts",
                       help="start only the stages placed on this host (host: LABEL in the graph; repeatable); "
                            "without it every stage runs here")


def place(plan: Plan, args) -> tuple[str, ...]:
    """Check ``--host`` against the whole graph and choose the run's stream (see
    :mod:`pipeline.runtime.runid`); return the host labels this process runs."""
    from pipeline.app import place as place_stages

    return place_stages(plan, tuple(getattr(args, "hosts", None) or ()), getattr(args, "inline", False),
                        getattr(args, "stream", None))


def run_plan(plan: Plan, args, recording: str | None, total: int | None, quiet: bool = False, strict: bool = True):
    """Run a plan inline or as processes; return (recording path, seconds, frames, per-stage info).
    With ``strict=False`` a run that did not finish cleanly returns (``info["ok"]`` False) instead of
    raising, so the caller can keep what was tracked (:func:`pipeline.app.run_graph`)."""
    from pipeline.app import run_graph

    hosts = place(plan, args)
    return run_graph(plan, inline=getattr(args, "inline", False), zenoh=lambda: launcher_zenoh(args),
                     listen_given=bool(args.listen), recording=recording, total=total, hosts=hosts, quiet=quiet,
                     strict=strict)


def run_status(info: dict) -> int:
    """The exit status of ``gflow run`` and ``gflow demo`` from their run's ``info``, saying its failures: 130 when
    interrupted; when every frame failed (:class:`pipeline.app.failures.RunFailures`), that line on stderr and
    exit status 3 (the run made nothing: it used to end 0, 'demo: 20 frames'); when some did, how many, and 0."""
    import sys

    from pipeline.app.failures import EVERY_FRAME_FAILED, RunFailures

    if info.get("interrupted"):
        return 130
    failures = info.get("failures") or RunFailures()
    if failures.every:
        print(failures.line(), file=sys.stderr)
        return EVERY_FRAME_FAILED
    if failures.line():
        print(failures.line())
    return 0




def torn_segments(path: str) -> list[str]:
    """The segments of recording ``path`` that do not end with an MCAP footer (their writer was
    killed, or is still writing): :func:`pipeline.io.mcap_io.torn_segments`, imported when asked for
    so that a command that reads no recording does not import the MCAP reader."""
    from pipeline.io.mcap_io import torn_segments as torn

    return torn(path)


def warn_if_torn(path: str) -> bool:
    """Say in one line (on stderr) when a segment of recording ``path`` does not end with an MCAP
    footer (:func:`torn_segments`): a command reads it only up to where it ends. True when one was torn."""
    import sys

    torn = torn_segments(path)
    for seg in torn:
        print(f"warning: {seg} was not closed properly (its writer was killed, or is still writing): it is read "
              f"up to where it ends (`gflow verify` says how much is readable, `gflow recover` salvages it)",
              file=sys.stderr)
    return bool(torn)


def partial_if_damaged(recording: str, command: str, wrote: str, status: int = 1) -> int:
    """The exit status of ``gflow COMMAND`` that wrote ``wrote`` from ``recording``: 0, or ``status`` when a reader of
    this process met damage inside the recording (:func:`pipeline.io.mcap_io.damage_cause`: bytes follow the record
    that failed, or the file's end, and were not read, so ``wrote`` lacks them), said in one line on stderr with the
    damage. The output is kept (what could be read), but is not reported as a whole one."""
    import sys

    from pipeline.io.mcap_io import damage_cause, damage_told

    damage = damage_cause(recording)
    if not damage:
        return 0
    damage_told(damage)  # said here: not warned again when the command ends
    print(f"gflow {command}: {wrote} holds only what was read before the damage: {damage}", file=sys.stderr)
    return status


def write_picture(path: str, pic) -> None:
    """Encode ``pic`` as ``path``'s kind (checked writable before the frame was read) and write it beside ``path``,
    taking the name once whole (:func:`pipeline.io.recording_files.write_beside`): never over a file, and a write
    that fails (a full disk: an OSError naming ``path``, exit status 1) or is interrupted leaves nothing under the
    name. Encoding in memory keeps the image library's own complaint off stderr."""
    import cv2
    from pathlib import Path

    from pipeline.io.recording_files import write_beside

    ok, data = cv2.imencode(Path(path).suffix, pic)
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the picture")

    def write(f: IO[bytes]) -> None:
        f.write(data.tobytes())

    write_beside(path, write)
