"""``gflow track``: one target through an image folder, a video, a recording, or a live stream or
camera (``docs/live.md``).

Each tracker is a module in ``pipeline/cli/trackers/`` with ``NAME``, ``add_args(parser)``
(its own options) and ``overrides(args) -> (graph name, {stage: {param: value}})``; it may
also have ``make_plan(graph, overrides) -> Plan`` when its graph is generated (gflow shards).
"""

from __future__ import annotations

ORDER = 20

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

import msgspec

from stages.source import SourceParams

from pipeline.runtime.graph import Plan, load_graph
from pipeline.recording.results import estimate_columns, renumber, run_outcome, write_boxes
from pipeline.io.frame_readers import count_frames
from pipeline.cli.trackers import TRACKERS
from pipeline.runtime.live_plan import listen_early, live_source, prepare_live
from pipeline.runtime.preflight import check_source
from pipeline.recording.live_record import LiveSummary, live_summary
from pipeline.runtime.trace import mark
from pipeline.runtime.zygote import preload
from pipeline.cli.commands.common import (CliError, Recording, add_placement_args, add_record_args, add_zenoh_args,
                                          check_outputs, check_stage_values, parse_box, parse_sets, run_plan,
                                          sets_as_given)

#: tracker name -> {dest: (option, default)} of the options its ``add_args`` adds (filled by register)
_OWN_OPTIONS: dict[str, dict[str, tuple[str, object]]] = {}
#: options one tracker adds that others read too (chamfer, dcf and m2 read appearance's --particles, gflow m2's --model)
_ALSO_USED_BY = {"particles": ("chamfer", "dcf", "m2"), "model": ("gflow",)}


def check_whole_frame_model(model: str, source: str, shape: tuple) -> None:
    """A whole-frame patch model (crop: frame, e.g. AVLetters mouths) sees the frame itself as the
    patch: on video not cropped like its training frames it cannot track anything."""
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
                       f"frames: learn one on this video (gflow learn m2 ... --boxes GT.csv)")
    print(f"note: {model} is a whole-frame patch model: the state is the exemplar, the box is the whole frame and "
          f"does not move" + ("" if trained else " (the model does not record its training frame size)"),
          file=sys.stderr)


def check_tracker_options(args) -> None:
    """An option of another tracker (``--particles`` with gflow, ``--model`` with chamfer) is an error,
    not silently ignored; a value the tracker refuses (``--particles 0``) is one line naming the option."""
    for owner, opts in _OWN_OPTIONS.items():
        for dest, (opt, default) in opts.items():
            if owner == args.tracker or args.tracker in _ALSO_USED_BY.get(dest, ()):
                continue
            if getattr(args, dest, default) != default:
                users = sorted({owner, *_ALSO_USED_BY.get(dest, ())})
                raise CliError(f"{opt} is an option of --tracker {' / '.join(users)}, not of --tracker "
                               f"{args.tracker}")
    from pipeline.cli.tracker_options import check_param_values

    cls = getattr(TRACKERS[args.tracker], "PARAMS", None)
    if cls is not None:
        try:
            check_param_values(args, [c for t in TRACKERS.values() if (c := getattr(t, "PARAMS", None))], cls)
        except ValueError as e:
            raise CliError(str(e)) from None


#: options that only a live source takes: {dest: option}
_LIVE_OPTIONS = {"reconnect": "--reconnect", "open_timeout": "--open-timeout"}


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


def live_params(source: str, args) -> dict:
    """Source parameters for a stream URL or a camera device."""
    for opt, given in (("--start", args.start), ("--realtime", args.realtime)):
        if given:
            raise CliError(f"{opt} applies to files; a live source starts at its first frame and runs at its own "
                           f"pace")
    params: dict = {"kind": "live", "path": source, "fps": args.fps}
    for dest in _LIVE_OPTIONS:
        if getattr(args, dest, None) is not None:
            params[dest] = getattr(args, dest)
    if args.stop is not None:
        params["stop"] = args.stop
    return params


def source_params(source: str, args) -> dict:
    """Source stage parameters for a path: image folder (or dataset folder with frames/), video, .mcap,
    or a live source (stream URL, camera device)."""
    from pipeline.io.live_capture import is_live_source

    if is_live_source(source):
        return live_params(source, args)
    for dest, opt in _LIVE_OPTIONS.items():
        if getattr(args, dest, None) is not None:
            raise CliError(f"{opt} is an option of live sources (stream URLs, cameras), not of {source}")
    p = Path(source)
    params: dict = {"fps": args.fps, "realtime": args.realtime, "start": args.start}
    if args.stop is not None:
        params["stop"] = args.stop
    if p.is_dir():
        if (p / "frames").is_dir() and not any(q.suffix.lower() in (".jpg", ".png", ".jpeg", ".bmp") for q in p.iterdir()):
            p = p / "frames"  # a dataset folder like ../shared/data/caviar1
        params.update(kind="folder", path=str(p.resolve()))
    elif p.is_file():
        params.update(kind="mcap" if p.suffix == ".mcap" else "video", path=str(p.resolve()))
    else:
        raise CliError(f"source not found: {source} (give an image folder, a video file or an .mcap recording)")
    return params


@dataclass
class TrackRun:
    """What one ``gflow track`` run produced: boxes by frame and how the run went."""

    boxes: dict[int, tuple[float, float, float, float]]
    states: list[str]
    recording: str
    seconds: float
    frames: int
    info: dict
    kept: str = ""  # what the user is told about the recording
    temporary: bool = False  # --no-record: the recording was removed
    lines: list[str] = field(default_factory=list)  # what is missing, coasted, restarted
    incomplete: str = ""  # why the run is incomplete, or ""
    live: LiveSummary | None = None  # a live source's figures: skipped, gaps, latency
    confidence: dict[int, float] = field(default_factory=dict)  # the estimates' confidence by frame
    target_states: dict[int, str] = field(default_factory=dict)  # tracked / occluded / lost by frame
    points: dict = field(default_factory=dict)  # G-flow face: {frame: (landmark ids (n,), points (n, 2))}

    def write_csv(self, path: str | Path) -> None:
        """The boxes CSV: frame,x,y,w,h,confidence,state (and a live source's input: ok / damaged)."""
        write_boxes(path, self.boxes, self.confidence, self.target_states,
                    self.live.inputs(self.boxes) if self.live is not None else None)


def track_plan(args) -> tuple[Plan, int | None]:
    """The plan ``gflow track`` runs for ``args`` and its number of frames (None if unknown).

    Bad options or model files raise here, before anything starts.
    """
    tracker = TRACKERS[args.tracker]
    check_tracker_options(args)
    check_outputs(out=args.out, record=args.record, points_out=getattr(args, "points_out", None))
    check_points_out(args)
    graph, overrides = tracker.overrides(args)
    source = source_of(args)
    overrides.setdefault("source", {}).update(source_params(source, args))
    check_stage_values(args.graph or graph, sets_as_given(args.set), overrides)
    for stage, kv in parse_sets(args.set).items():
        overrides.setdefault(stage, {}).update(kv)
    make_plan = getattr(tracker, "make_plan", None)
    if make_plan is not None:  # a tracker that generates its graph (gflow: K proposal shards)
        plan = make_plan(args.graph or graph, overrides)
    else:
        plan = load_graph(args.graph or graph, overrides=overrides)
    if not getattr(args, "inline", False):  # the stage processes' zygote imports their modules meanwhile
        preload(s.kind for s in plan.stages.values())
    sp = msgspec.convert(plan.stages["source"].params, SourceParams)
    if sp.kind == "live":  # opened once, by the source stage (a camera or a listen=1 server serves one client)
        return plan, None
    first = check_source(sp, args.init)  # readable, --start inside it, --init on the image: before anything starts
    if args.tracker == "m2":
        assert first.image is not None  # check_source refuses a first frame without an image
        check_whole_frame_model(args.model, args.source, first.image.shape)
    return plan, count_frames(sp)


def run_track(args, plan: tuple[Plan, int | None] | None = None) -> TrackRun:
    """Run the tracker of ``args`` (inline or as processes) and gather its boxes from the recording
    (a temporary one with ``--no-record``, removed here) and the live stream, whatever happened."""
    plan_, total = plan or track_plan(args)
    mark("cli plan checked")
    rec = plan_.recorder()
    if rec is not None:  # recordings/track-TIME-RUNID.mcap, named when the run starts (Plan.recording_path)
        rec.params["path"] = "recordings/track-{time}.mcap"
    recording = Recording(plan_, args, None, needed=("estimate",))
    prepare_live(plan_)  # after Recording: --record-topics may ask for the skipped frames
    live = None
    # a UDP source's port, bound before anything starts (what a sender sends first is kept)
    listeners = listen_early(plan_, say=None if args.quiet else lambda line: print(line, file=sys.stderr))
    try:
        path, secs, frames, info = run_plan(plan_, args, recording.path, total, quiet=args.quiet, strict=False)
        recording.written(path)
        out = run_outcome(path, plan_, info, args.start)  # every frame that was tracked, and what is missing
        if live_source(plan_) is not None and path:
            live = live_summary(path)
    finally:
        recording.cleanup()
        for relay in listeners:
            relay.close()
    est = out.estimates
    frame_of = live.frames if live is not None else {}  # a live run's rows are the camera's frames
    by_seq = estimate_columns(est)
    boxes, confidence, target_states = (renumber(by_seq[0], frame_of), renumber(by_seq[1], frame_of),
                                        renumber(by_seq[2], frame_of))
    # a learned face's points, by the reference landmark each vertex came from
    points = {frame_of.get(k, k): (v.landmarks.array(), v.mean_points.array()) for k, v in est.items()
              if getattr(v, "landmarks", None) is not None}
    return TrackRun(boxes=boxes, states=[v.state for v in est.values()], confidence=confidence,
                    target_states=target_states,
                    recording=path, seconds=secs, frames=frames, info=info, kept=recording.kept,
                    temporary=recording.temporary,
                    lines=list(out.lines) + (live.lines() if live else []) + [x for r in listeners for x in r.lines()],
                    incomplete=out.why if out.incomplete else "", live=live, points=points)


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
    run = run_track(args)
    run.write_csv(args.out)
    pts = ""
    if getattr(args, "points_out", None):
        from pipeline.io.landmarks import write_points

        write_points(args.points_out, run.points)
        pts = f"; points: {args.points_out}" + ("" if run.points else " (empty: the model has no landmarks)")
    n, info = len(run.boxes), run.info
    rate = f"{n / max(run.seconds, 1e-9):.1f} fps"
    if run.live is not None and run.live.tracking_s > 0:  # not the waits for a lost stream, nor its end
        rate = f"{n / run.live.tracking_s:.1f} fps over the {run.live.tracking_s:.1f} s the stream was tracked"
    print(f"tracked {n} frames in {run.seconds:.2f} s ({rate}); boxes: {args.out}{pts}; recording: {run.kept}")
    for line in run.lines:
        print(f"  {line}")
    errs = info.get("errors")
    if errs:  # a count (processes) or {stage: count} (inline)
        n = sum(errs.values()) if isinstance(errs, dict) else errs
        per = (" (" + ", ".join(f"{k} {v}" for k, v in sorted(errs.items())) + ")") if isinstance(errs, dict) else ""
        where = f"see `gflow info {run.recording}`" if not run.temporary else "kept in no recording: --no-record"
        print(f"  errors reported: {n}{per}; {where}")
    if info.get("interrupted"):
        return 130
    if run.incomplete:
        print(f"the run is incomplete: {run.incomplete}", file=sys.stderr)
        return 3
    return 0


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
    p.add_argument("--tracker", default="dcf", metavar="NAME",  # checked against the registry: plugins too
                   help=f"tracking method: {', '.join(TRACKERS)} (default dcf; README 'Which tracker')")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1, as gflow benchmark and the docs' figures)")
    add_record_args(p, "recordings/track-TIME-RUNID.mcap")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    p.add_argument("--fps", type=float, default=25.0,
                   help="source frame rate, for time stamps and --realtime; of a live source, the nominal rate "
                        "the trackers measure time in (default 25)")
    p.add_argument("--realtime", action="store_true", help="play the source at --fps instead of as fast as possible")
    p.add_argument("--start", type=int, default=0, help="first frame index")
    p.add_argument("--stop", type=int, help="stop before this frame index (live: after this many frames decoded)")
    g = p.add_argument_group("live sources (docs/live.md)")
    g.add_argument("--camera", type=int, metavar="N", help="track camera N (/dev/videoN) instead of a SOURCE")
    g.add_argument("--reconnect", type=float, metavar="S",
                   help="seconds to keep reopening a lost stream before the run ends (default 5; 0: end at once)")
    g.add_argument("--open-timeout", type=float, metavar="S",
                   help="seconds opening the stream may take before it is an error (default 10)")
    p.add_argument("--graph", help="graph file to use instead of the tracker's built-in one")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="override a stage parameter")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    for t in TRACKERS.values():
        g = p.add_argument_group(f"--tracker {t.NAME}")
        t.add_args(g)
        _OWN_OPTIONS[t.NAME] = {a.dest: (a.option_strings[0], a.default) for a in g._group_actions}
    add_placement_args(p, hosts=False)
    add_zenoh_args(p)


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
