"""The paper's figure 3 on real video: G-flow (20 experts) against constrained optic flow, by
landmark error over time, from small random errors of the starting pose.

One command: ``python bench/bench_gflow_fig3.py [--runs 4] [--frames 669] [--plot docs/faces-fig3.png] [--yardsticks]``

Marks et al. (2004, sec. 5, fig. 3) tracked a face with G-flow (20 experts) and with the
deterministic constrained optic flow of Brand (2001) -- the special case of G-flow of sec. 4:
one expert, alpha -> 0, Psi_v -> inf (the template is the previous frame, eq. 20), an
uninformative pose prior -- "several times, introducing small errors in the starting pose", and
plotted the error of 6 labelled points over time. Here, on ../shared/data/david_indoor:

* both trackers run the default graph (``pipeline/graphs/gflow.yaml``, the built-in face model)
  inline from the first ground-truth box with a seeded error (centre N(0, 2 px) per axis, size
  N(0, 3 %)), the same errors for both; optic flow with the settings of the special case;
* the error of a frame is the landmark NME: the mean distance of the eye corners 33, 133, 362,
  263 and mouth corners 61, 291 from MediaPipe's (``landmarks.npz``) over the reference distance
  of the outer eye corners (frames without a reference are skipped);
* two yardsticks that need no tracking are computed too: the first frame's reference landmarks
  never moved (a tracker that stands still), and the same landmarks placed as a 2-D template
  into every frame's ground-truth box (a perfect box tracker that knows nothing about faces),
  each as NME and pixels over the sequence (``--yardsticks``: these alone, in a second).

Printed: each run's mean NME and box CLE; the mean NME over the runs every 20th frame; the
overall means; the yardsticks. The plot (the mean over runs, smoothed over 21 frames, with the
runs' range shaded) is written to ``--plot``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import every_nth, gflow_plan, scratch, table  # noqa: E402
from bench_gflow_david import OPTIC_FLOW, perturbed_box  # noqa: E402  (the special case, the same start errors)

from gflow_core.gflow.landmark_error import SCORED_LANDMARKS, LandmarkScore, landmark_score  # noqa: E402
from gflow_core.evaluation.metrics import score  # noqa: E402
from pipeline.io.landmarks import read_landmarks  # noqa: E402
from pipeline.recording.results import estimates, read_boxes  # noqa: E402
from pipeline.runtime.inline import run_inline  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "david_indoor"

TRACKERS = {"G-flow (20 experts)": {"n_experts": 20}, "constrained optic flow": OPTIC_FLOW}


def run(params: dict, box, seed: int, frames: int, tmp: Path):
    """One inline run: ({frame: box}, {frame: {landmark: (x, y)}})."""
    shared = dict(params, init=[float(v) for v in box], seed=seed)
    src = {"kind": "folder", "path": str(DATA / "frames"), "stop": frames}
    rec = tmp / f"run-{time.monotonic_ns()}.mcap"
    run_inline(gflow_plan(src, shared), recording=str(rec))
    est = estimates(rec)
    rec.unlink()
    boxes = {k: tuple(v.box) for k, v in est.items()}
    points = {k: {int(i): tuple(p) for i, p in zip(v.landmarks.array(), v.mean_points.array())}
              for k, v in est.items()}
    return boxes, points


def template_in_truth_boxes(ref: np.ndarray, gt: dict, frames: int) -> LandmarkScore:
    """Landmark score of the first reference frame's landmarks placed, as a 2-D template, into each
    frame's ground-truth box (relative to the box's corner, scaled by its width and height)."""
    t0 = next(t for t in range(frames) if np.isfinite(ref[t]).all() and t in gt)
    x0, y0, w0, h0 = gt[t0]
    pts0 = ref[t0, :, :2]
    points = {}
    for t in range(frames):
        if t not in gt:
            continue
        x, y, w, h = gt[t]
        p = np.array([x, y]) + np.array([w / w0, h / h0]) * (pts0 - [x0, y0])
        points[t] = {i: tuple(p[i]) for i in SCORED_LANDMARKS}
    return landmark_score(ref, points, frames=range(frames))


def first_landmarks_still(ref: np.ndarray, frames: int) -> LandmarkScore:
    """Landmark score of the first reference frame's landmarks left where they are in every frame
    (a tracker that never moves)."""
    t0 = next(t for t in range(frames) if np.isfinite(ref[t]).all())
    still = {i: tuple(ref[t0, i, :2]) for i in SCORED_LANDMARKS}
    return landmark_score(ref, {t: still for t in range(frames)}, frames=range(frames))


def print_yardsticks(still: LandmarkScore, templ: LandmarkScore) -> None:
    """The two yardsticks that need no tracking, as NME and pixels over their scored frames."""
    print(table([["first landmarks, never moved", f"{still.nme:.3f}", f"{still.px:.2f}", still.frames],
                 ["first landmarks in the true box", f"{templ.nme:.3f}", f"{templ.px:.2f}", templ.frames]],
                ["yardstick (no tracking)", "NME", "px", "frames scored"]))


def _per_frame(s, frames: int) -> np.ndarray:
    e = np.full(frames, np.nan)
    for t, (nme, _) in s.per_frame.items():
        e[t] = nme
    return e


def smooth(v: np.ndarray, width: int = 21) -> np.ndarray:
    """NaN-aware moving average over ``width`` frames (fewer, and odd, on a shorter series), of v's length."""
    width = min(width, v.size - (v.size + 1) % 2)
    ok = np.isfinite(v)
    k = np.ones(width)
    num = np.convolve(np.where(ok, v, 0.0), k, mode="same")
    den = np.convolve(ok.astype(float), k, mode="same")
    return np.where(den > 0, num / np.maximum(den, 1), np.nan)


def plot(path: Path, curves: dict[str, np.ndarray], template: np.ndarray, runs: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.6), dpi=110)
    colours = {"G-flow (20 experts)": "tab:green", "constrained optic flow": "tab:blue"}
    x = np.arange(template.size)
    for name, e in curves.items():
        with np.errstate(all="ignore"):
            m = smooth(np.nanmean(e, axis=0))
            lo, hi = smooth(np.nanmin(e, axis=0)), smooth(np.nanmax(e, axis=0))
        ax.plot(x, m, color=colours[name], label=f"{name}, mean of {runs} runs")
        ax.fill_between(x, lo, hi, color=colours[name], alpha=0.15, linewidth=0)
    ax.plot(x, smooth(template), color="0.4", linestyle="--", linewidth=1,
            label="first landmarks placed in the true box")
    ax.set_xlabel("frame (david_indoor)")
    ax.set_ylabel("landmark NME (6 points)")
    ax.set_ylim(0, min(1.0, max(0.4, float(np.nanmax([np.nanmean(e, axis=0) for e in curves.values()])) * 1.1)))
    ax.set_xlim(0, template.size - 1)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("G-flow vs constrained optic flow from perturbed starts (smoothed over 21 frames)", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def track_all(ref: np.ndarray, gt: dict, runs: int, frames: int) -> dict[str, list[np.ndarray]]:
    """Every tracker from the same perturbed starts, ``runs`` times; prints each run's row and
    returns the per-frame NME of every run ({tracker: [(frames,) array per run]})."""
    tmp = scratch("gflow-fig3-")
    errs: dict[str, list[np.ndarray]] = {k: [] for k in TRACKERS}
    rows = []
    for r in range(runs):
        box = perturbed_box(gt[0], r)
        for name, params in TRACKERS.items():
            t0 = time.perf_counter()
            boxes, points = run(params, box, r, frames, tmp)
            dt = time.perf_counter() - t0
            s = landmark_score(ref, points, frames=range(frames))
            errs[name].append(_per_frame(s, frames))
            b = score(gt, boxes)
            rows.append([name, r, " ".join(f"{v:.1f}" for v in box), f"{s.nme:.3f}", f"{s.px:.2f}", f"{b.cle:.2f}",
                         f"{len(boxes) / dt:.1f}"])
            print(f"  {name}, run {r}: NME {s.nme:.3f} ({s.px:.2f} px), box CLE {b.cle:.2f} px", file=sys.stderr)
    print(f"Figure 3 on david_indoor, {frames} frames, {runs} runs per tracker")
    print(table(rows, ["tracker", "run", "start box", "NME", "px", "box CLE", "fps inline"]))
    return errs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=4, help="runs per tracker (default 4)")
    ap.add_argument("--frames", type=int, default=669, help="frames to track (default all 669)")
    ap.add_argument("--plot", default=str(Path(__file__).resolve().parent.parent / "docs" / "faces-fig3.png"),
                    help="where to write the plot (default docs/faces-fig3.png)")
    ap.add_argument("--yardsticks", action="store_true",
                    help="print only the two yardsticks that need no tracking (no runs, no plot)")
    args = ap.parse_args()
    if not (DATA / "landmarks.npz").is_file():
        raise SystemExit(f"{DATA} (frames, groundtruth.csv, landmarks.npz) not found: this benchmark needs "
                         f"../shared/data/david_indoor")
    ref = read_landmarks(DATA)
    gt = {k: v for k, v in read_boxes(DATA / "groundtruth.csv").items() if k < args.frames}
    still = first_landmarks_still(ref, args.frames)
    templ_score = template_in_truth_boxes(ref, gt, args.frames)
    if args.yardsticks:
        print(f"Yardsticks on david_indoor, {args.frames} frames")
        print_yardsticks(still, templ_score)
        return
    errs = track_all(ref, gt, args.runs, args.frames)
    templ = _per_frame(templ_score, args.frames)
    names = list(TRACKERS)
    out = every_nth({**errs, "template": [templ]}, args.frames,
                    lambda v: "-" if not np.isfinite(v).any() else
                    f"{np.nanmean(v):.3f}" + (f" [{np.nanmin(v):.3f}..{np.nanmax(v):.3f}]" if v.size > 1 else ""))
    print("\nlandmark NME every 20th frame, mean over runs [min..max]")
    print(table(out, ["frame", *names, "template in true box"]))
    for n in names:
        a = np.array(errs[n])
        print(f"{n}: mean NME {np.nanmean(a):.3f}; first 100 frames {np.nanmean(a[:, :100]):.3f}, last 100 "
              f"{np.nanmean(a[:, -100:]):.3f}; worst run {np.nanmax(np.nanmean(a, axis=1)):.3f}")
    print()
    print_yardsticks(still, templ_score)
    plot(Path(args.plot), {n: np.array(errs[n]) for n in names}, templ, args.runs)
    print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
