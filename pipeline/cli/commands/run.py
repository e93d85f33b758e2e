"""``gflow run GRAPH``: any graph file, as processes over zenoh or ``--inline``."""

from __future__ import annotations

ORDER = 40

import sys

from pipeline.cli.security_options import apply_security
from pipeline.cli.commands.common import (CliError, add_placement_args, add_record_args, add_zenoh_args,
                                          check_outputs, run_plan, run_status)


def cmd_run(args) -> int:
    from pipeline.runtime.build import apply_defaults, check_stages
    from pipeline.runtime.graph import load_graph
    from pipeline.runtime.live_plan import listen_early, prepare_live
    from pipeline.runtime.placement import local_stages
    from pipeline.cli.commands.common import Recording, check_stage_values, parse_sets, sets_as_given

    check_outputs(record=args.record)
    apply_security(args)  # read when zenoh opens; --inline opens none, and a bad file is refused all the same
    check_stage_values(args.graph, sets_as_given(args.set))
    plan = apply_defaults(load_graph(args.graph, overrides=parse_sets(args.set)))
    held = plan.recorder()
    local = local_stages(plan, args.hosts)  # an unknown --host label is the first thing to say
    check_stages(plan, local)  # a stage that cannot start (no initial box, say): before any process or recording
    _check_initial_boxes(plan, local)
    if args.record and args.hosts and held is not None and held.host not in args.hosts:
        raise CliError(f"--record: the recorder runs on host {held.host}, not on {', '.join(args.hosts)}; "
                       f"give --record to the command of host {held.host}")
    recording = Recording(plan, args, None)
    prepare_live(plan)  # a live source: timed proposals, skipped frames if recorded (docs/live.md)
    listeners = listen_early(plan, local, say=lambda line: print(line, file=sys.stderr))
    try:
        path, secs, frames, info = run_plan(plan, args, recording.path, None)
    finally:
        for relay in listeners:
            relay.close()
    recording.written(path)
    hosts = f" (host {', '.join(args.hosts)})" if args.hosts else ""
    rec = path or recording.kept
    if args.hosts and held is not None and held.host not in args.hosts:
        rec = f"on host {held.host}"
    print(f"{plan.name}{hosts}: {frames} frames in {secs:.2f} s; stream {plan.stream}; recording: {rec}")
    return run_status(info)


def _check_initial_boxes(plan, local) -> None:
    """The initial boxes of the stages run here against the first frame of a source run here that
    is not live (a folder, a video, a recording, the synthetic scene), as gflow track checks
    --init, before any process starts: a box outside the frame ran, warned on every frame and exited 0.
    A live source's stage checks them when it opens the stream."""
    import msgspec
    from stages.source import SourceParams

    from pipeline.runtime.preflight import box_needs, check_box_in_image, first_frame

    src = next((s for s in plan.stages.values() if s.is_source()), None)
    if src is None or src.name not in local:
        return
    params = msgspec.convert(src.params, SourceParams)
    boxes = {n: plan.stage_params(n).get("init") for n in local if n != src.name and plan.stages[n].kind != "recorder"}
    boxes = {n: b for n, b in boxes.items() if b is not None and len(b) == 4}
    if params.host_clock or not boxes:
        return
    frame = first_frame(params, plan.base_dir)
    assert frame.image is not None  # first_frame refuses a frame without an image
    h, w = frame.image.shape[:2]
    needs = box_needs(plan)  # what the stages ask of the box (chamfer's preprocess: 2x2 pixels to calibrate on)
    for name, box in boxes.items():
        check_box_in_image(box, w, h, what=f"stage {name!r} init:", needs=needs)


def register(sub) -> None:
    from pipeline.runtime.graph import builtin_graphs  # the graph files' names, in the description

    p = sub.add_parser("run", help="run a graph file (every stage its own process, or --inline)",
                       description=f"Run a YAML graph. Built-in graphs: {', '.join(builtin_graphs())}.")
    p.add_argument("graph", help="graph file, or the name of a built-in graph")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="a parameter of the graph's tracker, once for all its stages (tracker.particles=1000), or of one stage (source.frames=40); repeatable")
    add_record_args(p, "the recorder's path pattern")
    p.add_argument("--inline", action="store_true", help="run all stages in this process, without zenoh")
    add_placement_args(p)
    add_zenoh_args(p)
    p.set_defaults(func=cmd_run)
