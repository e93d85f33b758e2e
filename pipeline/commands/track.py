"""``gflow track``: one target through an image folder, a video or a recording.

Each tracker is a module in ``pipeline/trackers/`` with ``NAME``, ``add_args(parser)``
(its own options) and ``overrides(args) -> (graph name, {stage: {param: value}})``; it may
also have ``make_plan(graph, overrides) -> Plan`` when its graph is generated (gflow shards).
"""

from __future__ import annotations

ORDER = 20

import sys
import time
from pathlib import Path

import msgspec

from stages.source import SourceParams

from ..graph import load_graph
from ..results import run_outcome, write_boxes
from ..sources import count_frames
from ..trackers import TRACKERS
from .common import CliError, add_zenoh_args, parse_box, parse_sets, run_plan


def source_params(source: str, args) -> dict:
    """Source stage parameters for a path: image folder (or dataset folder with frames/), video, or .mcap."""
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


def cmd_track(args) -> int:
    tracker = TRACKERS[args.tracker]
    graph, overrides = tracker.overrides(args)
    overrides.setdefault("source", {}).update(source_params(args.source, args))
    for stage, kv in parse_sets(args.set).items():
        overrides.setdefault(stage, {}).update(kv)
    make_plan = getattr(tracker, "make_plan", None)
    if make_plan is not None:  # a tracker that generates its graph (gflow: K proposal shards)
        plan = make_plan(args.graph or graph, overrides)
    else:
        plan = load_graph(args.graph or graph, overrides=overrides)
    total = count_frames(msgspec.convert(plan.stages["source"].params, SourceParams))
    rec = args.record or str(Path("recordings") / f"track-{time.strftime('%Y%m%d-%H%M%S')}.mcap")
    path, secs, frames, info = run_plan(plan, args, rec, total, quiet=args.quiet, strict=False)
    out = run_outcome(path, plan, info, args.start)  # whatever happened, every frame that was tracked
    est = out.estimates
    write_boxes(args.out, {k: v.box for k, v in est.items()})
    print(f"tracked {len(est)} frames in {secs:.2f} s ({len(est) / max(secs, 1e-9):.1f} fps); "
          f"boxes: {args.out}; recording: {path}")
    for line in out.lines:
        print(f"  {line}")
    if info.get("errors"):
        print(f"  errors reported: {info['errors']} (see `gflow info {path}`)")
    if info.get("interrupted"):
        return 130
    if out.incomplete:
        print(f"the run is incomplete: {out.why}", file=sys.stderr)
        return 3
    return 0


def register(sub) -> None:
    p = sub.add_parser("track", help="track one target through an image folder, a video or a recording",
                       description="Track one target from an initial box. Writes frame,x,y,w,h per frame (0-based "
                                   "pixels, top-left corner and size) and records every message to MCAP.",
                       epilog="example: gflow track ../shared/data/crossing --init 204,150,17,50 --out boxes.csv")
    p.add_argument("source", help="image folder (or a dataset folder with frames/), video file, or .mcap recording")
    p.add_argument("--init", type=parse_box, required=True, metavar="X,Y,W,H", help="initial box in frame --start")
    p.add_argument("--out", required=True, metavar="CSV", help="output boxes (frame,x,y,w,h)")
    p.add_argument("--tracker", default="chamfer", choices=sorted(TRACKERS), help="tracking method (default chamfer)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--record", metavar="FILE", help="recording path (default recordings/track-TIME.mcap)")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    p.add_argument("--fps", type=float, default=25.0, help="source frame rate, for time stamps and --realtime")
    p.add_argument("--realtime", action="store_true", help="play the source at --fps instead of as fast as possible")
    p.add_argument("--start", type=int, default=0, help="first frame index")
    p.add_argument("--stop", type=int, help="stop before this frame index")
    p.add_argument("--graph", help="graph file to use instead of the tracker's built-in one")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="override a stage parameter")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    for t in TRACKERS.values():
        g = p.add_argument_group(f"--tracker {t.NAME}")
        t.add_args(g)
    add_zenoh_args(p)
    p.set_defaults(func=cmd_track)
