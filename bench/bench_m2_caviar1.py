"""M2 on real video: learn exemplars from the first part of caviar1, track the rest.

One command:  python bench/bench_m2_caviar1.py [--train 0:150] [-K 20] [--seeds 0 1 2]

1. ``gflow learn m2 caviar1 --boxes groundtruth.csv --frames 0:150 -K 20`` (the supervised
   training path: Canny edges inside the ground-truth boxes, masked by background
   subtraction, sec. 4.1), then ``gflow info`` on the model;
2. ``gflow track caviar1 --tracker m2 --model ... --init <box of frame 150> --start 150``,
   one multi-process run per seed;
3. the same frames with the K = 1 chamfer tracker (``--tracker chamfer``), same start box;
4. the paper's unsupervised training path (``gflow learn m2`` without ``--boxes``:
   median background, background subtraction, edges of the largest foreground blob);
5. ``gflow eval`` on frames 150-381, and the published trackers' boxes
   (``caviar1/results/*.csv``) scored on the same frames by the same function.

The published table (``../shared/data/README.md``) scores all 382 frames, tracking from
frame 0 with no training; the M2 rows are on the 232 frames not used for training.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _m2cli import DATA, box_arg, evaluate, gflow, write_gt  # noqa: E402
from _util import scratch, table  # noqa: E402

PUBLISHED = {"srpca": ("SRPCA", 1.7, 1.00), "vtd": ("VTD", 3.9, 0.96), "pn": ("TLD", 5.6, 0.95),
             "frag": ("Frag", 5.7, 0.91), "pca": ("IVT", 45.2, 0.30), "mil": ("MIL", 48.5, 0.28),
             "l1": ("L1", 119.9, 0.30)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DATA / "caviar1"))
    ap.add_argument("--train", default="0:150", help="training frames A:B; tracking starts at B")
    ap.add_argument("-K", type=int, default=20)
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--inline", action="store_true", help="run the trackers in one process (same results)")
    ap.add_argument("--skip-unsupervised", action="store_true")
    args = ap.parse_args()
    data = Path(args.data)
    if not (data / "frames").is_dir():
        print(f"SKIP: caviar1 not found at {data}")
        return 0
    from pipeline.recording.results import read_boxes

    gt_all = read_boxes(data / "groundtruth.csv")
    a, b = (int(v) for v in args.train.split(":"))
    n = max(gt_all) + 1
    test = range(b, n)
    tmp = scratch("m2-caviar1-")
    gt_test = write_gt(tmp / "gt_test.csv", gt_all, test)
    init = box_arg(gt_all[b])
    mode = ["--inline"] if args.inline else []
    rows = []

    print(f"== learn from caviar1 frames {a}:{b} (ground-truth boxes), K = {args.K}")
    model = tmp / "caviar1-m2.npz"
    _, t_learn = gflow("learn", "m2", str(data), "--boxes", str(data / "groundtruth.csv"), "--frames", args.train,
                       "-K", str(args.K), "--out", str(model), "-q")
    print(f"  (learning took {t_learn:.1f} s wall, including start-up)")
    gflow("info", str(model))

    print(f"\n== track frames {b}..{n - 1} with the learned model, {args.particles} particles")
    res_m2 = []
    for seed in args.seeds:
        pred = tmp / f"m2-seed{seed}.csv"
        gflow("track", str(data), "--tracker", "m2", "--model", str(model), "--init", init, "--start", str(b),
              "--out", str(pred), "--record", str(tmp / f"m2-seed{seed}.mcap"), "--particles", str(args.particles),
              "--seed", str(seed), "-q", *mode)
        r = evaluate(gt_test, pred)
        res_m2.append(r)
        rows.append([f"M2 learned K={args.K}, seed {seed}", f"{b}-{n - 1}", f"{r['cle_px']:.2f}",
                     f"{r['success_rate_0.5']:.3f}", f"{r['mean_overlap']:.3f}"])

    print(f"\n== the K = 1 chamfer tracker on the same frames")
    for seed in args.seeds:
        pred = tmp / f"chamfer-seed{seed}.csv"
        gflow("track", str(data), "--init", init, "--start", str(b), "--out", str(pred),
              "--record", str(tmp / f"chamfer-seed{seed}.mcap"), "--seed", str(seed), "-q", *mode)
        r = evaluate(gt_test, pred)
        rows.append([f"chamfer K=1, seed {seed}", f"{b}-{n - 1}", f"{r['cle_px']:.2f}", f"{r['success_rate_0.5']:.3f}",
                     f"{r['mean_overlap']:.3f}"])

    if not args.skip_unsupervised:
        print(f"\n== the paper's unsupervised training path (background subtraction, no boxes), frames {args.train}")
        model_u = tmp / "caviar1-m2-unsupervised.npz"
        gflow("learn", "m2", str(data), "--frames", args.train, "-K", str(args.K), "--out", str(model_u), "-q")
        pred = tmp / "m2u.csv"
        gflow("track", str(data), "--tracker", "m2", "--model", str(model_u), "--init", init, "--start", str(b),
              "--out", str(pred), "--record", str(tmp / "m2u.mcap"), "--seed", "0", "-q", *mode)
        r = evaluate(gt_test, pred)
        rows.append([f"M2 unsupervised K={args.K}, seed 0", f"{b}-{n - 1}", f"{r['cle_px']:.2f}",
                     f"{r['success_rate_0.5']:.3f}", f"{r['mean_overlap']:.3f}"])

    from gflow_core.evaluation.metrics import score

    for key, (name, cle, succ) in PUBLISHED.items():
        f = data / "results" / f"{key}.csv"
        if not f.is_file():
            continue
        pub = read_boxes(f)
        s = score({k: gt_all[k] for k in test if k in gt_all}, pub)
        rows.append([f"{name} (published boxes, rescored)", f"{b}-{n - 1}", f"{s.cle:.2f}", f"{s.success:.3f}",
                     f"{s.mean_overlap:.3f}"])
        rows.append([f"{name} (published table)", "0-381", f"{cle:.1f}", f"{succ:.2f}", ""])

    print("\n" + table(rows, ["tracker", "frames", "CLE px", "success (IoU>0.5)", "mean IoU"]))
    cles = np.array([r["cle_px"] for r in res_m2])
    print(f"\nM2 over {len(cles)} seeds: CLE mean {cles.mean():.2f} px (min {cles.min():.2f}, max {cles.max():.2f}); "
          f"outputs in {tmp}, deleted at exit unless GFLOW_BENCH_KEEP=1")
    return 0


if __name__ == "__main__":
    sys.exit(main())
