"""The ``gflow`` command line.

    gflow demo                         synthetic scene through the multi-process pipeline
    gflow track SOURCE --init X,Y,W,H  track one target through an image folder or video
    gflow eval --gt GT.csv --pred P.csv
    gflow run GRAPH.yaml               any graph, as processes over zenoh (or --inline)
    gflow info FILE.mcap               what a recording holds
    gflow replay FILE.mcap             republish a recording on zenoh
    gflow topics | echo TOPIC | hz TOPIC   inspect a live pipeline
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

from .graph import GraphError, Plan, builtin_graphs, load_graph
from .transport import ZenohSettings, free_port

__all__ = ["main", "build_parser"]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
EPILOG = "Run 'gflow COMMAND --help' for the options of one command. Docs: README.md."


class CliError(Exception):
    """A user error: printed as one line, exit status 2."""


# ----------------------------------------------------------------------------------------------
# helpers


def _parse_box(text: str) -> tuple[float, float, float, float]:
    try:
        vals = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,W,H numbers, got {text!r}") from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"expected 4 numbers X,Y,W,H, got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise argparse.ArgumentTypeError("box has NaN or inf")
    if vals[2] <= 0 or vals[3] <= 0:
        raise argparse.ArgumentTypeError(f"box width and height must be positive, got W={vals[2]}, H={vals[3]}")
    return vals  # type: ignore[return-value]


def _parse_sets(items: list[str]) -> dict[str, dict]:
    """``stage.param=value`` (value parsed as YAML: numbers, lists, true/false) -> overrides."""
    import yaml

    out: dict[str, dict] = {}
    for it in items or []:
        if "=" not in it or "." not in it.split("=", 1)[0]:
            raise CliError(f"--set expects stage.param=value, got {it!r}")
        key, val = it.split("=", 1)
        stage, param = key.split(".", 1)
        out.setdefault(stage, {})[param] = yaml.safe_load(val)
    return out


def _zenoh_from_args(args, default_connect: bool) -> ZenohSettings:
    listen = tuple(args.listen or ())
    connect = tuple(args.connect or ())
    if default_connect and not connect and args.mode != "router":
        connect = (DEFAULT_ENDPOINT,)
    if not listen:
        listen = ("tcp/127.0.0.1:0",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=connect, multicast=args.multicast)


def _launcher_zenoh(args) -> ZenohSettings:
    """The launcher listens on 7447 (so `gflow topics` finds it) unless busy or told otherwise."""
    if args.listen:
        listen = tuple(args.listen)
    else:
        import socket

        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", 7447))
                listen = (DEFAULT_ENDPOINT,)
            except OSError:
                listen = (f"tcp/127.0.0.1:{free_port()}",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=tuple(args.connect or ()), multicast=args.multicast)


def _add_zenoh_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh network (default: peer mode on loopback, multicast scouting off)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer", help="zenoh session mode")
    g.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/10.0.0.5:7447 for a zenoh router (repeatable)")
    g.add_argument("--multicast", action="store_true", help="enable multicast scouting (off by default)")


def _run_plan(plan: Plan, args, recording: str | None, total: int | None, quiet: bool = False):
    """Run a plan inline or as processes; return (recording path, seconds, frames, per-stage info)."""
    if getattr(args, "inline", False):
        from .inline import run_inline

        last = [0.0]

        def progress(n: int) -> None:
            now = time.monotonic()
            if not quiet and now - last[0] > 1.0:
                last[0] = now
                print(f"  {n}" + (f"/{total}" if total else "") + " frames", file=sys.stderr)

        md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
              "gflow.config": plan.config_metadata()}
        r = run_inline(plan, progress=progress, recording=recording, metadata=md)
        bad = {n: e for n, e in r.errors.items() if e}
        return r.recording, r.seconds, r.frames, {"mode": "inline", "steps": r.steps, "errors": bad}
    from .launcher import Launcher

    res = Launcher(plan, zenoh=_launcher_zenoh(args), recording=recording, progress=not quiet,
                   total_frames=total).run()
    if res.interrupted:
        print("interrupted: stages stopped, recording closed", file=sys.stderr)
    for n, e in res.exits.items():
        if e.returncode != 0:
            print(f"stage {n} exited with status {e.returncode}: {e.last_error}", file=sys.stderr)
    src = next(n for n, s in plan.stages.items() if s.is_source())
    frames = res.status[src].steps if src in res.status else 0
    info = {"mode": "processes", "ok": res.ok, "pids": res.pids, "peak_rss_mb": res.peak_rss_mb,
            "errors": len(res.errors), "fps": {n: s.fps for n, s in res.status.items()}}
    if not res.ok and not res.interrupted:
        raise CliError("the pipeline did not finish cleanly (see the messages above)")
    return res.recording, res.seconds, frames, info


# ----------------------------------------------------------------------------------------------
# commands


def cmd_demo(args) -> int:
    from .build import apply_defaults
    from .results import estimates, truth_boxes
    from gflow_core.metrics import score

    overrides = {"source": {"frames": args.frames}, "filter": {"particles": args.particles, "seed": args.seed},
                 "proposal": {"seed": args.seed}}
    plan = apply_defaults(load_graph("demo", overrides=overrides))
    rec = args.record or plan.recording_path()
    print(f"gflow demo: synthetic scene, {args.frames} frames, {args.particles} particles, "
          f"{'inline' if args.inline else 'one process per stage over zenoh'}", file=sys.stderr)
    path, secs, frames, info = _run_plan(plan, args, rec, args.frames)
    truth = truth_boxes(path)
    est = {k: v.box for k, v in estimates(path).items()}
    s = score(truth, est)
    print(f"recording: {path}")
    print(f"frames: {frames}   wall time: {secs:.2f} s   throughput: {frames / secs:.1f} fps (including start-up)")
    if info.get("fps"):
        print("stage fps: " + ", ".join(f"{n} {v:.1f}" for n, v in info["fps"].items() if v))
    print(f"tracking error vs ground truth: CLE {s.cle:.2f} px, mean overlap {s.mean_overlap:.3f}, "
          f"success@0.5 {s.success:.3f} over {s.frames} frames")
    return 0


def _source_params(source: str, args) -> dict:
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
    from .results import estimates, write_boxes

    if args.tracker != "chamfer":
        raise CliError(f"tracker {args.tracker!r} is not available yet (available: chamfer)")
    overrides = {
        "source": _source_params(args.source, args),
        "filter": {"init": list(args.init), "particles": args.particles, "seed": args.seed},
        "proposal": {"seed": args.seed},
        "preprocess": {"calibrate_box": list(args.init)},
    }
    for stage, kv in _parse_sets(args.set).items():
        overrides.setdefault(stage, {}).update(kv)
    plan = load_graph(args.graph or "chamfer", overrides=overrides)
    from .sources import count_frames
    from stages.source import SourceParams
    import msgspec

    total = count_frames(msgspec.convert(plan.stages["source"].params, SourceParams))
    rec = args.record or str(Path("recordings") / f"track-{time.strftime('%Y%m%d-%H%M%S')}.mcap")
    path, secs, frames, info = _run_plan(plan, args, rec, total, quiet=args.quiet)
    est = estimates(path)
    write_boxes(args.out, {k: v.box for k, v in est.items()})
    states = [v.state for v in est.values()]
    print(f"tracked {len(est)} frames in {secs:.2f} s ({len(est) / max(secs, 1e-9):.1f} fps); "
          f"boxes: {args.out}; recording: {path}")
    if states.count("coast"):
        print(f"  {states.count('coast')} frame(s) coasted on the dynamics (no usable image)")
    if info.get("errors"):
        print(f"  errors reported: {info['errors']} (see `gflow info {path}`)")
    return 0


def cmd_eval(args) -> int:
    from .results import read_boxes
    from gflow_core.metrics import score

    gt, pred = read_boxes(args.gt), read_boxes(args.pred)
    s = score(gt, pred, threshold=args.threshold)
    if args.json:
        print(json.dumps(s.to_json()))
    else:
        print(f"frames with ground truth: {s.frames} (missing predictions: {s.missing})")
        print(f"centre location error (CLE): {s.cle:.2f} px")
        print(f"mean overlap (IoU):          {s.mean_overlap:.3f}")
        print(f"success rate (IoU > {args.threshold}):   {s.success:.3f}")
    return 0


def cmd_run(args) -> int:
    from .build import apply_defaults

    plan = apply_defaults(load_graph(args.graph, overrides=_parse_sets(args.set)))
    path, secs, frames, info = _run_plan(plan, args, args.record, None)
    print(f"{plan.name}: {frames} frames in {secs:.2f} s; recording: {path}")
    return 0


def cmd_info(args) -> int:
    from .mcap_io import summarize

    s = summarize(args.file)
    if args.json:
        print(json.dumps(s.to_json(), indent=1))
        return 0
    print(f"file:      {s.path}")
    print(f"messages:  {s.messages}   duration: {s.duration_s:.3f} s")
    if s.truncated:
        print(f"WARNING:   {s.truncated}")
    print("topics:")
    for t, ts in sorted(s.topics.items()):
        seqs = f"seq {ts.first_seq}..{ts.last_seq}" if ts.first_seq >= 0 else ""
        print(f"  {t:42s} {ts.type:20s} {ts.count:7d} msgs {ts.rate_hz:8.1f} Hz {ts.bytes / 2**20:9.2f} MiB  {seqs}")
    print("schemas:  " + ", ".join(f"{n} ({e})" for n, e in sorted(s.schemas.items())))
    for name, md in s.metadata.items():
        print(f"metadata {name}:")
        for k, v in md.items():
            v1 = v if len(v) < 200 else v[:200] + f"... ({len(v)} chars)"
            print(f"  {k}: {v1}" if "\n" not in v1 else f"  {k}: |\n    " + v1.replace("\n", "\n    "))
    return 0


def cmd_replay(args) -> int:
    from .live import replay

    speed = None if args.max else args.speed
    n = replay(_zenoh_from_args(args, default_connect=True), args.file, speed, args.topics)
    print(f"replayed {n} messages from {args.file}", file=sys.stderr)
    return 0


def cmd_topics(args) -> int:
    from .live import list_topics

    list_topics(_zenoh_from_args(args, default_connect=True), args.duration)
    return 0


def cmd_echo(args) -> int:
    from .live import echo

    key = args.topic if args.topic.startswith("gflow/") else f"gflow/{args.topic}"
    echo(_zenoh_from_args(args, default_connect=True), key, args.count, args.timeout)
    return 0


def cmd_hz(args) -> int:
    from .live import hz

    key = args.topic if args.topic.startswith("gflow/") else f"gflow/{args.topic}"
    hz(_zenoh_from_args(args, default_connect=True), key, args.duration)
    return 0


# ----------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="gflow",
        description="gflow: a streaming dataflow tracker for video. Every stage is its own process, "
                    "stages talk over Eclipse Zenoh, and every message is recorded to MCAP.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("demo", help="track the built-in synthetic scene through the multi-process pipeline",
                       description="Runs the synthetic scene (textured moving shapes with known ground truth) through "
                                   "source -> preprocess -> proposal -> filter, each in its own process, records every "
                                   "message to recordings/demo-*.mcap, and prints the tracking error and throughput.")
    p.add_argument("--frames", type=int, default=120, help="number of frames (default 120)")
    p.add_argument("--particles", type=int, default=500, help="number of particles (default 500)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the filter and proposal stages")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    p.add_argument("--record", metavar="FILE", help="recording path (default recordings/demo-TIME.mcap)")
    _add_zenoh_args(p)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("track", help="track one target through an image folder, a video or a recording",
                       description="Track one target from an initial box. Writes frame,x,y,w,h per frame (0-based "
                                   "pixels, top-left corner and size) and records every message to MCAP.",
                       epilog="example: gflow track ../shared/data/crossing --init 200,100,20,50 --out boxes.csv")
    p.add_argument("source", help="image folder (or a dataset folder with frames/), video file, or .mcap recording")
    p.add_argument("--init", type=_parse_box, required=True, metavar="X,Y,W,H", help="initial box in frame --start")
    p.add_argument("--out", required=True, metavar="CSV", help="output boxes (frame,x,y,w,h)")
    p.add_argument("--tracker", default="chamfer", choices=["chamfer", "m2", "gflow"], help="tracking method")
    p.add_argument("--particles", type=int, default=500, help="number of particles (default 500)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--record", metavar="FILE", help="recording path (default recordings/track-TIME.mcap)")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    p.add_argument("--fps", type=float, default=25.0, help="source frame rate, for time stamps and --realtime")
    p.add_argument("--realtime", action="store_true", help="play the source at --fps instead of as fast as possible")
    p.add_argument("--start", type=int, default=0, help="first frame index")
    p.add_argument("--stop", type=int, help="stop before this frame index")
    p.add_argument("--graph", help="graph file to use instead of the built-in one for --tracker")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="override a stage parameter")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    _add_zenoh_args(p)
    p.set_defaults(func=cmd_track)

    p = sub.add_parser("eval", help="score predicted boxes against ground truth",
                       description="Centre location error (px), mean overlap (IoU) and success rate (IoU > 0.5).")
    p.add_argument("--gt", required=True, help="ground truth CSV (frame,x,y,w,h)")
    p.add_argument("--pred", required=True, help="predicted CSV (frame,x,y,w,h)")
    p.add_argument("--threshold", type=float, default=0.5, help="overlap threshold of the success rate")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("run", help="run a graph file (every stage its own process, or --inline)",
                       description=f"Run a YAML graph. Built-in graphs: {', '.join(builtin_graphs())}.")
    p.add_argument("graph", help="graph file, or the name of a built-in graph")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="override a stage parameter")
    p.add_argument("--record", metavar="FILE", help="recording path (default: the recorder's path pattern)")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    _add_zenoh_args(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("info", help="topics, counts, rates, duration, schemas and metadata of a recording")
    p.add_argument("file", help="MCAP recording")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="republish a recording on zenoh",
                       description="Republishes every recorded message byte for byte on its topic, so live stages "
                                   "or a viewer can consume it. Heartbeats and control messages are not replayed.")
    p.add_argument("file", help="MCAP recording")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--speed", type=float, default=1.0, help="timing factor (2 = twice as fast; default 1)")
    g.add_argument("--max", action="store_true", help="as fast as possible")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics (full names)")
    _add_zenoh_args(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("topics", help="list the topics of a live pipeline")
    p.add_argument("--duration", type=float, default=2.0, help="seconds to listen (default 2)")
    _add_zenoh_args(p)
    p.set_defaults(func=cmd_topics)

    p = sub.add_parser("echo", help="print the messages on a live topic")
    p.add_argument("topic", help="key expression, e.g. gflow/cam0/estimate or cam0/**")
    p.add_argument("-n", "--count", type=int, help="stop after N messages")
    p.add_argument("--timeout", type=float, help="stop after this many seconds")
    _add_zenoh_args(p)
    p.set_defaults(func=cmd_echo)

    p = sub.add_parser("hz", help="measure the rate of a live topic")
    p.add_argument("topic", help="key expression, e.g. gflow/cam0/frames")
    p.add_argument("--duration", type=float, default=3.0, help="seconds to measure (default 3)")
    _add_zenoh_args(p)
    p.set_defaults(func=cmd_hz)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    logging.basicConfig(level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)],
                        format="%(levelname)s %(name)s: %(message)s")
    if args.command is None:
        ap.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (CliError, GraphError, FileNotFoundError, ValueError) as e:
        print(f"gflow {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"gflow {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
