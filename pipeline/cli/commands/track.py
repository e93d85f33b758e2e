"""``gflow track``: one target through an image folder, a video, a recording, or a live stream or
camera (``docs/live.md``).

Each tracker is a module in ``pipeline/cli/trackers/`` with ``NAME``, ``add_args(parser)``
(its own options) and ``overrides(args) -> (graph name, {stage: {param: value}})``; it may
also have ``make_plan(graph, overrides) -> Plan`` when its graph is generated (gflow shards).

The command is a shell over the application layer: its options become a
:class:`pipeline.app.TrackRequest` (:func:`track_request`), checked here where only the command
line can say it (another tracker's option, an output path, a whole-frame model), planned by
:func:`pipeline.app.plan_track` and run by :func:`pipeline.app.track`; the CSV is written from the
estimates of the run.
"""

from __future__ import annotations

ORDER = 20

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from gflow_core.builtin_trackers import BUILTIN

from pipeline.cli.trackers import TRACKERS, OptionClash
from pipeline.runtime.trace import mark
from pipeline.cli.security_options import apply_security
from pipeline.cli.commands.common import (CliError, add_placement_args, add_record_args, add_zenoh_args, check_new_file,
                                          check_outputs, launcher_zenoh, nonnegative_int, parse_box,
                                          positive_float, positive_int, source_rate)

if TYPE_CHECKING:  # imported where used: the application layer (cv2, msgspec, mcap, the graph loader, the stages) is
    # not needed to build the options, nor to say a mistake in them (bench/bench_command_startup.py measures the start-up)
    from pipeline.app import TrackPlan, TrackRequest, TrackResult

#: tracker name -> {dest: (option, default)} of the options its ``add_args`` adds (filled by register)
_OWN_OPTIONS: dict[str, dict[str, tuple[str, object]]] = {}
#: tracker name -> why its options cannot be added (one of them is another's; filled by register)
_CLASHES: dict[str, str] = {}


def option_users(dest: str, owner: str) -> set[str]:
    """The trackers that read the option ``dest`` that tracker ``owner`` adds: ``owner``, every tracker
    with a parameter of that name (chamfer, dcf and m2 read appearance's ``--particles``) and every
    tracker whose model option it is (:attr:`gflow_core.spec.TrackerSpec.model_option`)."""
    from gflow_core.registry import trackers

    users = {owner}
    for name, spec in trackers().items():
        if dest in {f.name for f in dataclasses.fields(spec.params)} or (spec.model_option and spec.model_dest == dest):
            users.add(name)
    return users


def registered_options() -> dict[str, dict[str, tuple[str, object]]]:
    """{tracker: {dest: (option, default)}} of every tracker's ``gflow track`` options (registering them)."""
    add_track_args(_Parser(prog="gflow track", add_help=False))
    return _OWN_OPTIONS


def tracker_options(name: str) -> dict[str, tuple[str, object]]:
    """{dest: (option, default)} of the ``gflow track`` options tracker ``name`` reads (its own and
    those it shares, :func:`option_users`)."""
    return {dest: opt for owner, opts in registered_options().items() for dest, opt in opts.items()
            if name in option_users(dest, owner)}


def check_whole_frame_model(model: str, source: str, shape: tuple) -> None:
    """A whole-frame patch model (crop: frame, e.g. AVLetters mouths) sees the frame itself as the
    patch: on video not cropped like its training frames it cannot track anything (unless told to cut
    the patch from the initial box, ``--crop box``)."""
    import sys

    from pipeline.io.modelfile import load_meta

    meta = load_meta(Path(model))
    if meta.get("crop") != "frame":
        return
    size = f"{shape[1]}x{shape[0]}"
    trained = str(meta.get("frame_size", ""))
    if trained and trained != size:
        raise CliError(f"{model} was learned on whole {trained} frames (a patch model with crop: frame, e.g. cropped "
                       f"mouths); {source} has {size} frames. Such a model only fits video cropped like its training "
                       f"frames: learn one on this video (gflow learn m2 ... --boxes GT.csv), or cut the patch from --init "
                       f"with --crop box")
    print(f"note: {model} is a whole-frame patch model: the state is the exemplar, the box is the whole frame and "
          f"does not move" + ("" if trained else " (the model does not record its training frame size)"),
          file=sys.stderr)


def check_tracker_options(args) -> None:
    """An option of another tracker (``--particles`` with gflow, ``--model`` with chamfer) is an error,
    not silently ignored; a value the tracker refuses (``--particles 0``) is one line naming the option;
    a tracker whose own option is another's (:data:`_CLASHES`) cannot run."""
    if args.tracker in _CLASHES:
        raise CliError(_CLASHES[args.tracker])
    for owner, opts in _OWN_OPTIONS.items():
        for dest, (opt, default) in opts.items():
            users = option_users(dest, owner)
            if args.tracker in users:
                continue
            if getattr(args, dest, default) != default:
                raise CliError(f"{opt} is an option of --tracker {' / '.join(sorted(users))}, not of --tracker "
                               f"{args.tracker}")
    from pipeline.cli.tracker_options import check_param_values

    cls = getattr(TRACKERS[args.tracker], "PARAMS", None)
    if cls is not None:
        try:
            check_param_values(args, [c for t in TRACKERS.values() if (c := getattr(t, "PARAMS", None))], cls)
        except ValueError as e:
            raise CliError(str(e)) from None


def source_of(args) -> str:
    """The source named by the positional argument or ``--camera N`` (one of the two)."""
    from pipeline.io.live_capture import camera_device

    camera = getattr(args, "camera", None)
    if camera is not None:
        if args.source:
            raise CliError(f"give a source or --camera, not both ({args.source} and --camera {camera})")
        return camera_device(camera)
    if not args.source:
        raise CliError("give a source (an image folder, a video, a recording, a stream URL or /dev/videoN) or "
                       "--camera N")
    return args.source


def source_params(source: str, args) -> dict:
    """Source stage parameters for ``source`` with the source options of ``args`` (``fps``,
    ``realtime``, ``start``, ``stop``, ``reconnect``, ``open_timeout``): :func:`pipeline.app.source_params`."""
    from pipeline.app import TrackRequest, source_params as params_of

    return params_of(TrackRequest(source, (0.0, 0.0, 1.0, 1.0), fps=args.fps, realtime=args.realtime, start=args.start,
                                  stop=args.stop, reconnect=getattr(args, "reconnect", None),
                                  open_timeout=getattr(args, "open_timeout", None)))


def tracker_params(args) -> dict:
    """The tracker options of ``args`` ({dest: value}, every tracker's, as its ``overrides`` reads them)."""
    return {dest: getattr(args, dest, default) for opts in _OWN_OPTIONS.values() for dest, (_, default) in opts.items()}


def track_request(args) -> TrackRequest:
    """The :class:`pipeline.app.TrackRequest` of ``gflow track``'s options."""
    from pipeline.app import TrackRequest

    if args.inline:  # zenoh is not opened, but a bad --security file or TLS option is refused all the same
        apply_security(args)
    return TrackRequest(source=source_of(args), init=tuple(args.init), tracker=args.tracker, params=tracker_params(args),
                        sets=tuple(args.set or ()), seed=args.seed, record=args.record, no_record=args.no_record,
                        record_topics=tuple(args.record_topics or ()), inline=args.inline, fps=args.fps,
                        realtime=args.realtime, start=args.start, stop=args.stop,
                        reconnect=getattr(args, "reconnect", None), open_timeout=getattr(args, "open_timeout", None),
                        graph=args.graph, stream=getattr(args, "stream", None), quiet=args.quiet,
                        network=None if args.inline else launcher_zenoh(args), listen_given=bool(args.listen))


def track_plan(args) -> TrackPlan:
    """The plan ``gflow track`` runs for ``args``. Bad options or model files raise here, before anything starts."""
    check_tracker_options(args)
    check_outputs(out=args.out, record=args.record, points_out=getattr(args, "points_out", None))
    check_points_out(args)
    if args.stop is not None and args.stop <= args.start:
        raise CliError(f"--start {args.start} --stop {args.stop}: no frame to track (--stop is the frame after the "
                       f"last one, so it must be greater than --start)")
    check_new_file(out=args.out, points_out=getattr(args, "points_out", None))  # an earlier run's boxes
    return _planned(track_request(args))


def request_plan(request: TrackRequest, out: str) -> TrackPlan:
    """The plan of a request made without a command line (``gflow benchmark``), its boxes going to
    ``out``: checked as :func:`track_plan` checks ``gflow track``'s options. ``request.params`` holds
    the options given, by their ``argparse`` names (``{"model": "m.npz"}``); every other tracker
    option is its default, as on the command line."""
    options = argparse.Namespace(**{**option_defaults(), **request.params, "tracker": request.tracker})
    check_tracker_options(options)
    check_outputs(out=out, record=request.record)
    return _planned(dataclasses.replace(request, params=tracker_params(options)))


#: the tracker of gflow track (and of gflow trax, gflow.Tracker) without --tracker
DEFAULT_TRACKER = "dcf"


def option_defaults() -> dict[str, object]:
    """{dest: default} of every tracker's ``gflow track`` options."""
    return {dest: default for opts in registered_options().values() for dest, (_, default) in opts.items()}


def _planned(request: TrackRequest) -> TrackPlan:
    from pipeline.app import plan_track

    tp = plan_track(request, TRACKERS[request.tracker])
    if request.tracker == "m2" and tp.first_image_shape is not None and request.params.get("crop") != "box":
        check_whole_frame_model(str(request.params["model"]), request.source, tp.first_image_shape)
    return tp


def run_track(args, plan: TrackPlan | None = None) -> TrackResult:
    """Run the tracker of ``args`` (inline or as processes) and gather its estimates from the run,
    whatever happened (:func:`pipeline.app.track`)."""
    from pipeline.app import track
    from pipeline.cli.commands.common import start_work

    tp = plan or track_plan(args)
    mark("cli plan checked")
    start_work()  # every check done: a bad value met from here on is the run failing (exit 1), not a mistake
    return track(tp)


def check_points_out(args) -> None:
    """``--points-out`` needs a tracker that reports face points: G-flow with a learned face model."""
    if not getattr(args, "points_out", None):
        return
    if args.tracker != "gflow":
        raise CliError(f"--points-out writes the face points of --tracker gflow, not of --tracker {args.tracker}")
    if getattr(args, "model", None) == "ellipsoid":
        raise CliError("--points-out needs a learned face model (`face`, the default, or one from `gflow learn "
                       "gflow`); the ellipsoid's vertices are no face landmarks")


def cmd_track(args) -> int:
    plan = track_plan(args)  # every check, the source's first frame too (a torn recording's error says it is torn)
    if args.source and str(args.source).lower().endswith(".mcap"):  # tracked only up to where a torn one ends
        from pipeline.cli.commands.common import warn_if_torn

        warn_if_torn(args.source)
    run = run_track(args, plan)
    # beside its name, moved there once complete: a write that fails leaves no part of the file to refuse a retry
    run.write_csv(args.out, new=True)
    pts = ""
    if getattr(args, "points_out", None):
        from pipeline.io.landmarks import write_points

        points = run.points()
        write_points(args.points_out, points, new=True)  # as the boxes: no part of it left by a failed write
        pts = f"; points: {args.points_out}" + ("" if points else " (empty: the model has no landmarks)")
    n, info = len(run.estimates), run.info
    rate = f"{n / max(run.seconds, 1e-9):.1f} fps"
    if run.live is not None and run.live.tracking_s > 0:  # not the waits for a lost stream, nor its end
        rate = f"{n / run.live.tracking_s:.1f} fps over the {run.live.tracking_s:.1f} s the stream was tracked"
    print(f"tracked {n} frames in {run.seconds:.2f} s ({rate}); boxes: {args.out}{pts}; recording: {run.kept}")
    for line in run.lines + _stop_past_the_end(args, run):
        print(f"  {line}")
    errs = info.get("errors")
    failures = info.get("failures")
    if errs:  # a count (processes) or {stage: count} (inline)
        n = sum(errs.values()) if isinstance(errs, dict) else errs
        per = (" (" + ", ".join(f"{k} {v}" for k, v in sorted(errs.items())) + ")") if isinstance(errs, dict) else ""
        where = f"see `gflow info {run.recording}`" if not run.temporary else "kept in no recording: --no-record"
        # the first reason, unless the last line says it (every frame failed)
        first = f"; the first: {failures.first}" if failures is not None and failures.first and not failures.every \
            else ""
        print(f"  errors reported: {n}{per}{first}; {where}")
    if info.get("interrupted"):
        return 130
    if failures is not None and failures.every and not run.estimates:  # the run made nothing: say why
        print(failures.line(), file=sys.stderr)
        return 3
    if run.incomplete:
        print(f"the run is incomplete: {run.incomplete}", file=sys.stderr)
        return 3
    return 0


def _stop_past_the_end(args, run: TrackResult) -> list[str]:
    """A line when a file's frames ended before ``--stop`` (the run tracked to the last one; nothing said so, and a
    --stop past the end reads as though that many frames were tracked)."""
    sent = run.info.get("last_sent", -1)  # not the last estimate: a run that failed midway stopped short of --stop too
    last = sent if sent >= 0 else max(run.estimates, default=-1)
    if args.stop is None or run.live is not None or last < 0 or last + 1 >= args.stop:
        return []
    return [f"--stop {args.stop} is past the end of {args.source}: its last frame is {last}"
            + (", tracked to it" if last in run.estimates else "")]


def reconnect_seconds(text: str) -> float:
    """``--reconnect``: a number of seconds >= 0, or inf (argparse type). A negative one or NaN was refused only by
    the source stage, naming the graph file's line and its parameters rather than the option."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not v >= 0:  # NaN fails this too
        raise argparse.ArgumentTypeError(f"must be a number >= 0 (or inf), got {text.strip()}")
    return v


def add_track_args(p: argparse.ArgumentParser) -> None:
    """The options of ``gflow track`` (also parsed by ``gflow benchmark`` to run a tracker the same way)."""
    p.add_argument("source", nargs="?",
                   help="image folder (or a dataset folder with frames/), video file, .mcap recording, or a live "
                        "source: a stream URL (rtsp://, http://, tcp://, udp://...) or a camera device /dev/videoN")
    p.add_argument("--init", type=parse_box, required=True, metavar="X,Y,W,H", help="initial box in frame --start")
    p.add_argument("--out", required=True, metavar="CSV", help="output boxes (frame,x,y,w,h,confidence,state)")
    p.add_argument("--points-out", metavar="CSV",
                   help="gflow with a face model: every vertex per frame (frame,landmark,x,y; landmark = the "
                        "reference landmark index it was learned from), for gflow eval --landmarks")
    p.add_argument("--tracker", default=DEFAULT_TRACKER, metavar="NAME",  # checked against the registry: plugins too
                   help=f"tracking method: {', '.join(TRACKERS)} (default dcf; README 'Which tracker')")
    p.add_argument("--seed", type=nonnegative_int, default=1, help="random seed (default 1, as gflow benchmark and the docs' figures)")
    add_record_args(p, "recordings/track-TIME-RUNID.mcap")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    p.add_argument("--fps", type=source_rate, default=25.0,
                   help="source frame rate, for time stamps and --realtime; of a live source, the nominal rate "
                        "the trackers measure time in (default 25)")
    p.add_argument("--realtime", action="store_true", help="play the source at --fps instead of as fast as possible")
    p.add_argument("--start", type=nonnegative_int, default=0, help="first frame index")
    p.add_argument("--stop", type=positive_int, help="stop before this frame index (live: after this many frames decoded)")
    g = p.add_argument_group("live sources (docs/live.md)")
    g.add_argument("--camera", type=nonnegative_int, metavar="N", help="track camera N (/dev/videoN) instead of a SOURCE")
    g.add_argument("--reconnect", type=reconnect_seconds, metavar="S",
                   help="seconds to keep reopening a lost stream before the run ends (default 5; 0: end at once; "
                        "inf: until it is back or Ctrl-C)")
    g.add_argument("--open-timeout", type=positive_float, metavar="S",
                   help="seconds opening the stream may take before it is an error (default 10)")
    p.add_argument("--graph", help="graph file to use instead of the tracker's built-in one")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="a parameter of the tracker, once for all its stages (tracker.particles=1000), or of one stage (source.stop=100); repeatable")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output (errors and damaged input are still said)")
    add_placement_args(p, hosts=False)
    add_zenoh_args(p)
    builtin = {s.name for s in BUILTIN}
    owners = {o: "gflow track" for a in p._actions for o in a.option_strings}
    _CLASHES.clear()
    # the built-in trackers' options first: another package's tracker never takes one of theirs
    for t in sorted(TRACKERS.values(), key=lambda t: (t.NAME not in builtin, t.NAME)):
        g = p.add_argument_group(f"--tracker {t.NAME}")
        try:
            t.add_args(g)
        except OptionClash as e:
            _CLASHES[t.NAME] = (f"tracker {t.NAME}: its option {e.option} ({e.where}) is already an option of "
                                f"{owners.get(e.option, 'gflow track')}; give it another name in its parameters")
            _OWN_OPTIONS[t.NAME] = {}
            continue
        _OWN_OPTIONS[t.NAME] = {a.dest: (a.option_strings[0], a.default) for a in g._group_actions}
        owners.update({o: f"--tracker {t.NAME}" for a in g._group_actions for o in a.option_strings})
    # added last so a clash with any option is caught, shown first: right after the general options
    groups = p._action_groups
    trackers = [g for g in groups if (g.title or "").startswith("--tracker ")]
    rest = [g for g in groups if g not in trackers]
    at = next((i + 1 for i, g in enumerate(rest) if g.title == "live sources (docs/live.md)"), len(rest))
    groups[:] = rest[:at] + trackers + rest[at:]


def track_args(argv: list[str]) -> argparse.Namespace:
    """``gflow track`` options parsed from ``argv`` (a bad option raises CliError, not SystemExit)."""
    p = _Parser(prog="gflow track", add_help=False)
    add_track_args(p)
    return p.parse_args(argv)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise CliError(message)


def register(sub) -> None:
    p = sub.add_parser("track", help="track one target through an image folder, a video or a recording",
                       description="Track one target from an initial box. Writes frame,x,y,w,h,confidence,state per "
                                   "frame (0-based pixels, top-left corner and size; the confidence in [0, 1] and "
                                   "the state, tracked / occluded / lost, are the tracker's judgement) and records every message to MCAP.",
                       epilog="example: gflow track ../shared/data/crossing --init 204,150,17,50 --out boxes.csv")
    add_track_args(p)
    p.set_defaults(func=cmd_track)
