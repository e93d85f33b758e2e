"""``gflow demo``: the synthetic scene through the full multi-process pipeline."""

from __future__ import annotations

ORDER = 10

import sys

from pipeline.cli.security_options import apply_security
from pipeline.cli.commands.common import (add_placement_args, add_record_args, add_zenoh_args, check_outputs,
                                          positive_int, run_plan, run_status, whole_number)


def cmd_demo(args) -> int:
    from gflow_core.evaluation.metrics import score

    from gflow_core.synthetic import SyntheticScene

    from pipeline.recording.results import estimates
    from pipeline.runtime.build import apply_defaults
    from pipeline.runtime.graph import load_graph
    from pipeline.cli.commands.common import Recording, check_stage_values

    check_outputs(record=args.record)
    apply_security(args)  # read when zenoh opens; --inline opens none, and a bad file is refused all the same
    overrides = {"source": {"frames": args.frames}, "filter": {"particles": args.particles, "seed": args.seed},
                 "proposal": {"seed": args.seed}}
    check_stage_values("demo", {f"--particles {args.particles}": ("filter", "particles", args.particles),
                                f"--seed {args.seed}": ("filter", "seed", args.seed)},
                       {k: v for k, v in overrides.items() if k != "filter"})  # each value named by its own option
    plan = apply_defaults(load_graph("demo", overrides=overrides))
    recording = Recording(plan, args, None, needed=("estimate",))  # named with the run id when it starts
    print(f"gflow demo: synthetic scene, {args.frames} frames, {args.particles} particles, "
          f"{'inline' if args.inline else 'one process per stage over zenoh'}", file=sys.stderr)
    try:
        path, secs, frames, info = run_plan(plan, args, recording.path, args.frames)
        recording.written(path)
        est = {k: v.box for k, v in estimates(path).items()}
    finally:
        recording.cleanup()
    sp = plan.stages["source"].params
    scene = SyntheticScene(width=sp.get("width", 320), height=sp.get("height", 240), n_frames=args.frames,
                           seed=sp.get("scene_seed", 0), noise=sp.get("noise", 4.0))
    # a run stopped early (a stop control, Ctrl-C) is scored over the frames it ran, up to its last
    # estimate: not charged with the frames it never ran, nor those the stop caught in flight (a
    # frame missing before the last estimate still counts as a failure)
    sent = min(frames, args.frames)
    ran = args.frames if sent >= args.frames else (max(est) + 1 if est else 0)
    truth = {t: scene.truth_box(t) for t in range(ran)}
    print(f"recording: {recording.kept}")
    print(f"frames: {frames}   wall time: {secs:.2f} s   end-to-end rate: {frames / secs:.1f} frames/s "
          f"(wall time, including start-up)")
    if info.get("fps"):
        print("per-stage rate while running (frames/s, last heartbeat): "
              + ", ".join(f"{n} {v:.1f}" for n, v in info["fps"].items() if v))
    if ran < args.frames:
        print(f"stopped after {sent} of {args.frames} frames" + (f" ({sent - ran} in flight when it stopped, not scored)"
                                                                  if sent > ran else ""))
    if not truth or not est:
        print("tracking error vs ground truth: no frame was tracked")
    else:
        s = score(truth, est)
        print(f"tracking error vs ground truth: CLE {s.cle:.2f} px, mean overlap {s.mean_overlap:.3f}, "
              f"success@0.5 {s.success:.3f} over {s.frames} frames"
              + (f" ({s.missing} without an estimate)" if s.missing else ""))
    return run_status(info)


def register(sub) -> None:
    p = sub.add_parser("demo", help="track the built-in synthetic scene through the multi-process pipeline",
                       description="Runs the synthetic scene (textured moving shapes with known ground truth) through "
                                   "source -> preprocess -> proposal -> filter -> render (the overlays Foxglove "
                                   "shows), each in its own process, records every message to "
                                   "recordings/demo-*.mcap, and prints the tracking error and throughput.")
    # checked as typed: the scene's own check names no option ("synthetic scene needs at least one frame")
    p.add_argument("--frames", type=positive_int, default=120, help="number of frames (default 120)")
    p.add_argument("--particles", type=whole_number, default=500, help="number of particles (default 500)")
    p.add_argument("--seed", type=whole_number, default=0,
                   help="random seed of the filter and proposal stages (default 0)")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    add_record_args(p, "recordings/demo-TIME-RUNID.mcap")
    add_placement_args(p, hosts=False)
    add_zenoh_args(p)
    p.set_defaults(func=cmd_demo)
