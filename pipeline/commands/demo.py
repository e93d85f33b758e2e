"""``gflow demo``: the synthetic scene through the full multi-process pipeline."""

from __future__ import annotations

ORDER = 10

import sys

from ..build import apply_defaults
from ..graph import load_graph
from .common import add_zenoh_args, check_outputs, run_plan


def cmd_demo(args) -> int:
    from gflow_core.metrics import score

    from ..results import estimates, truth_boxes

    check_outputs(record=args.record)
    overrides = {"source": {"frames": args.frames}, "filter": {"particles": args.particles, "seed": args.seed},
                 "proposal": {"seed": args.seed}}
    plan = apply_defaults(load_graph("demo", overrides=overrides))
    rec = args.record or plan.recording_path()
    print(f"gflow demo: synthetic scene, {args.frames} frames, {args.particles} particles, "
          f"{'inline' if args.inline else 'one process per stage over zenoh'}", file=sys.stderr)
    path, secs, frames, info = run_plan(plan, args, rec, args.frames)
    truth = truth_boxes(path)
    est = {k: v.box for k, v in estimates(path).items()}
    s = score(truth, est)
    print(f"recording: {path}")
    print(f"frames: {frames}   wall time: {secs:.2f} s   throughput: {frames / secs:.1f} fps (including start-up)")
    if info.get("fps"):
        print("stage fps: " + ", ".join(f"{n} {v:.1f}" for n, v in info["fps"].items() if v))
    print(f"tracking error vs ground truth: CLE {s.cle:.2f} px, mean overlap {s.mean_overlap:.3f}, "
          f"success@0.5 {s.success:.3f} over {s.frames} frames")
    return 130 if info.get("interrupted") else 0


def register(sub) -> None:
    p = sub.add_parser("demo", help="track the built-in synthetic scene through the multi-process pipeline",
                       description="Runs the synthetic scene (textured moving shapes with known ground truth) through "
                                   "source -> preprocess -> proposal -> filter, each in its own process, records every "
                                   "message to recordings/demo-*.mcap, and prints the tracking error and throughput.")
    p.add_argument("--frames", type=int, default=120, help="number of frames (default 120)")
    p.add_argument("--particles", type=int, default=500, help="number of particles (default 500)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the filter and proposal stages")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    p.add_argument("--record", metavar="FILE", help="recording path (default recordings/demo-TIME.mcap)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_demo)
