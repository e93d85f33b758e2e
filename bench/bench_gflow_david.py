"""G-flow on real video (../shared/data/david_indoor, 669 frames of 320x240, a face moving,
turning and changing lighting), and the paper's figure 3 comparison with constrained optic flow.

One command: ``python bench/bench_gflow_david.py [--seeds 4] [--frames 669]``

1. ``gflow track`` from the first ground-truth box with the defaults (multi-process, as a user
   runs it), scored by ``gflow eval``: centre location error (CLE) and success (IoU > 0.5).
   The box is the bounding box of the projected vertices of the posterior mean pose.
2. Figure 3 of Marks et al. (2004): the deterministic special case (one expert, alpha -> 0,
   Psi_v -> inf, uninformative pose prior and background: constrained optic flow, eq. 21)
   against G-flow with 20 experts, each run ``--seeds`` times from a starting box with a
   small seeded error (translation N(0, 2 px) per axis, size N(0, 3 %)), the same errors for
   both trackers. Runs are inline (the same numbers as the processes, as the tests check).
   The error is the centre location error against the ground truth, printed every 20th
   frame (as the paper's hand labels) averaged over the runs, so drift can be seen, with
   each run's CLE, success and mean error over its first and last 100 frames.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import every_nth, gflow_plan, scratch, table  # noqa: E402

from gflow_core.evaluation.metrics import centre_error, score  # noqa: E402
from pipeline.runtime.inline import run_inline  # noqa: E402
from pipeline.recording.results import estimates, read_boxes  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "david_indoor"

#: G-flow settings under which it is constrained optic flow (sec. 4; gflow_core.gflow.special_cases),
#: with the parts of the pose prior and texture model the special case has no place for switched off
OPTIC_FLOW = {"n_experts": 1, "n_samples": 1, "alpha": 0.0, "psi_v": 1e6, "v_init_var": 1e-3, "background": False,
              "prior_std_rotation": math.inf, "prior_std_translation": math.inf, "prior_std_coefficients": math.inf,
              "prior_rotation_decay": 1.0, "texture_decay": 1.0, "reset_rate": 0.0, "morph_prior": math.inf}


def perturbed_box(box, seed: int) -> list[float]:
    """The first box with a small seeded error: centre + N(0, 2 px), size * (1 + N(0, 0.03))."""
    rng = np.random.default_rng([seed, 0xF163])
    x, y, w, h = box
    dx, dy = rng.normal(0.0, 2.0, 2)
    s = 1.0 + rng.normal(0.0, 0.03)
    cx, cy = x + w / 2 + dx, y + h / 2 + dy
    return [cx - s * w / 2, cy - s * h / 2, s * w, s * h]


def run(params: dict, box, seed: int, frames: int, tmp: Path) -> dict[int, tuple]:
    shared = dict(params, init=[float(v) for v in box], seed=seed)
    src = {"kind": "folder", "path": str(DATA / "frames"), "stop": frames}
    plan = gflow_plan(src, shared)
    rec = tmp / f"run-{time.monotonic_ns()}.mcap"
    run_inline(plan, recording=str(rec))
    out = {k: tuple(v.box) for k, v in estimates(rec).items()}
    rec.unlink()
    return out


def errors_by_frame(gt: dict, pred: dict, frames: int) -> np.ndarray:
    """(frames,) centre error; NaN where a frame has no prediction."""
    e = np.full(frames, np.nan)
    both = [f for f in range(frames) if f in pred and f in gt]
    e[both] = centre_error(np.array([gt[f] for f in both]), np.array([pred[f] for f in both]))
    return e


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=4, help="runs per tracker in the comparison (default 4)")
    ap.add_argument("--frames", type=int, default=669, help="frames to track (default all 669)")
    ap.add_argument("--skip-track", action="store_true", help="skip part 1 (gflow track + gflow eval)")
    args = ap.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} not found: this benchmark needs ../shared/data/david_indoor")
    gt = read_boxes(DATA / "groundtruth.csv")
    gt = {k: v for k, v in gt.items() if k < args.frames}
    box0 = gt[0]
    tmp = scratch("gflow-david-")
    if not args.skip_track:
        init = ",".join(f"{v:g}" for v in box0)
        cmd = ["gflow", "track", str(DATA), "--tracker", "gflow", "--init", init, "--out", str(tmp / "david.csv"),
               "--record", str(tmp / "david.mcap"), "--stop", str(args.frames), "--seed", "0", "-q"]
        print("$ " + " ".join(cmd).replace(str(DATA), "../shared/data/david_indoor").replace(str(tmp), "OUT"))
        subprocess.run(cmd, check=True)
        ev = ["gflow", "eval", "--gt", str(DATA / "groundtruth.csv"), "--pred", str(tmp / "david.csv")]
        print("$ " + " ".join(ev).replace(str(DATA), "../shared/data/david_indoor").replace(str(tmp), "OUT"))
        subprocess.run(ev, check=True)
        (tmp / "david.mcap").unlink()
    print(f"\nFigure 3 comparison on david_indoor, {args.frames} frames, {args.seeds} runs each")
    trackers = {"optic flow (1 expert, alpha 0)": OPTIC_FLOW, "G-flow (20 experts)": {"n_experts": 20}}
    errs: dict[str, list[np.ndarray]] = {k: [] for k in trackers}
    rows = []
    for seed in range(args.seeds):
        box = perturbed_box(box0, seed)
        for name, params in trackers.items():
            t0 = time.perf_counter()
            pred = run(params, box, seed, args.frames, tmp)
            dt = time.perf_counter() - t0
            e = errors_by_frame(gt, pred, args.frames)
            errs[name].append(e)
            s = score(gt, pred)
            rows.append([name, seed, " ".join(f"{v:.1f}" for v in box), f"{s.cle:.1f}", f"{s.success:.2f}",
                         f"{np.nanmean(e[:100]):.1f}", f"{np.nanmean(e[-100:]):.1f}", f"{len(pred) / dt:.0f}"])
            print(f"  {name}, seed {seed}: CLE {s.cle:.1f} px, success {s.success:.2f}", file=sys.stderr)
    print(table(rows, ["tracker", "seed", "start box", "CLE px", "success", "err 1st 100", "err last 100",
                       "fps inline"]))
    print("\ncentre error (px) every 20th frame, mean over runs [min..max]")
    names = list(trackers)
    out = every_nth(errs, args.frames, lambda v: f"{np.nanmean(v):6.1f} [{np.nanmin(v):.0f}..{np.nanmax(v):.0f}]")
    print(table(out, ["frame", *names]))
    for n in names:
        allv = np.array(errs[n])
        print(f"{n}: mean CLE over runs {np.nanmean(allv):.1f} px; runs whose error exceeds 50 px at some "
              f"frame: {int(np.sum(np.nanmax(allv, axis=1) > 50))}/{len(allv)}; mean error frames 0-99 "
              f"{np.nanmean(allv[:, :100]):.1f} px, last 100 {np.nanmean(allv[:, -100:]):.1f} px")


if __name__ == "__main__":
    main()
