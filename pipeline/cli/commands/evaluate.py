"""``gflow eval``: score predicted boxes against ground truth."""

from __future__ import annotations

ORDER = 30

import json

from pipeline.cli.commands.common import CliError


def cmd_eval(args) -> int:
    from gflow_core.metrics import score

    from pipeline.recording.results import read_boxes

    gt, pred = read_boxes(args.gt), read_boxes(args.pred)
    if args.frames:
        a, sep, b = args.frames.partition(":")
        try:
            lo, hi = int(a) if a else 0, int(b) if b else None
        except ValueError:
            raise CliError(f"--frames expects A:B (frame numbers, either may be left out), got {args.frames!r}") from None
        gt = {k: v for k, v in gt.items() if k >= lo and (hi is None or k < hi)}
        if not gt:
            raise CliError(f"no ground-truth frame in --frames {args.frames}")
    s = score(gt, pred, threshold=args.threshold)
    if args.json:
        print(json.dumps(s.to_json()))
    else:
        print(f"frames with ground truth: {s.frames} (missing predictions: {s.missing})")
        print(f"centre location error (CLE): {s.cle:.2f} px")
        print(f"mean overlap (IoU):          {s.mean_overlap:.3f}")
        print(f"success rate (IoU > {args.threshold}):   {s.success:.3f}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("eval", help="score predicted boxes against ground truth",
                       description="Centre location error (px), mean overlap (IoU) and success rate (IoU > 0.5).")
    p.add_argument("--gt", required=True, help="ground truth CSV (frame,x,y,w,h)")
    p.add_argument("--pred", required=True, help="predicted CSV (frame,x,y,w,h)")
    p.add_argument("--frames", metavar="A:B",
                   help="score only frames A <= frame < B (e.g. 150: after a run with --start 150); by default every "
                        "ground-truth frame counts and a frame with no prediction is a failure")
    p.add_argument("--threshold", type=float, default=0.5, help="overlap threshold of the success rate")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_eval)
