"""The paper's occlusion test on caviar1 (Toyama & Blake 2002, sec. 5.1.2, fig. 7).

One command:  python bench/bench_m2_occlusion.py [--blank 2 --every 10] [-K 20]

"We simulated occlusions by rendering black two adjacent frames out of every ten frames
in the test sequence, and so tracking was forced to rely on the prior in these frames."

Learns M2 from caviar1 frames 0-149 (as bench_m2_caviar1.py), then tracks frames 150-381
with the source blanking ``--blank`` of every ``--every`` frames
(``--set source.blank_every=10 --set source.blank_count=2``). On a blank frame the edge
map is empty and the filter coasts on the learned dynamics (state "coast"). Reports, from
the recording's estimates:

* CLE and success on the non-blank frames, and on the blank frames (bridged by the prior);
* recovery: the centre error on the 1st, 2nd and 3rd frame after each blank run, and the
  number of blank runs after which the error stays above 10 px (lost);
* the same run without blanking, and the K = 1 chamfer tracker with the same blanking.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _m2cli import DATA, box_arg, gflow  # noqa: E402
from _util import scratch, table  # noqa: E402


def analyse(rec: Path, gt: dict) -> dict:
    from gflow_core.evaluation.metrics import centre_error, iou
    from pipeline.recording.results import estimates

    est = estimates(rec)
    fr = [f for f in sorted(est) if f in gt]
    g = np.array([gt[f] for f in fr])
    p = np.array([est[f].box for f in fr])
    err, ov = centre_error(g, p), iou(g, p)
    coast = np.array([est[f].state == "coast" for f in fr])
    after: list[list[float]] = [[], [], []]
    lost = runs = 0
    i = 0
    while i < len(fr):
        if coast[i]:
            j = i
            while j < len(fr) and coast[j]:
                j += 1
            runs += 1
            for m in range(3):
                if j + m < len(fr) and not coast[j + m]:
                    after[m].append(float(err[j + m]))
            if j + 2 < len(fr) and err[j + 2] > 10.0:
                lost += 1
            i = j
        else:
            i += 1
    out = {"frames": len(fr), "blank": int(coast.sum()), "runs": runs, "lost": lost,
           "cle_seen": float(err[~coast].mean()), "succ_seen": float((ov[~coast] > 0.5).mean()),
           "after": [float(np.mean(a)) if a else float("nan") for a in after],
           "after_max": [float(np.max(a)) if a else float("nan") for a in after]}
    if coast.any():
        out.update(cle_blank=float(err[coast].mean()), succ_blank=float((ov[coast] > 0.5).mean()))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DATA / "caviar1"))
    ap.add_argument("--train", default="0:150")
    ap.add_argument("-K", type=int, default=20)
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--blank", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    data = Path(args.data)
    if not (data / "frames").is_dir():
        print(f"SKIP: caviar1 not found at {data}")
        return 0
    from pipeline.recording.results import read_boxes

    gt = read_boxes(data / "groundtruth.csv")
    b = int(args.train.split(":")[1])
    tmp = scratch("m2-occlusion-")
    model = tmp / "m2.npz"
    gflow("learn", "m2", str(data), "--boxes", str(data / "groundtruth.csv"), "--frames", args.train, "-K", str(args.K),
          "--out", str(model), "-q")
    blank = ["--set", f"source.blank_every={args.every}", "--set", f"source.blank_count={args.blank}"]
    common = ["--init", box_arg(gt[b]), "--start", str(b), "--seed", str(args.seed), "-q"]
    runs = {
        f"M2 K={args.K}, {args.blank} of {args.every} frames blank": ["--tracker", "m2", "--model", str(model), *blank],
        f"M2 K={args.K}, no blanking": ["--tracker", "m2", "--model", str(model)],
        f"chamfer K=1, {args.blank} of {args.every} frames blank": [*blank],
    }
    rows = []
    for i, (name, extra) in enumerate(runs.items()):
        rec = tmp / f"run{i}.mcap"
        gflow("track", str(data), *common, "--out", str(tmp / f"run{i}.csv"), "--record", str(rec), *extra)
        r = analyse(rec, gt)
        rows.append([name, r["frames"], r["blank"], f"{r['cle_seen']:.2f}", f"{r['succ_seen']:.3f}",
                     f"{r['cle_blank']:.2f}" if "cle_blank" in r else "-",
                     f"{r['succ_blank']:.3f}" if "succ_blank" in r else "-",
                     " / ".join(f"{v:.1f}" for v in r["after"]) if r["runs"] else "-",
                     " / ".join(f"{v:.1f}" for v in r["after_max"]) if r["runs"] else "-",
                     f"{r['lost']}/{r['runs']}" if r["runs"] else "-"])
    print("\n" + table(rows, ["run", "frames", "blank", "CLE seen", "succ seen", "CLE blank", "succ blank",
                              "err 1st/2nd/3rd after (mean)", "(max)", "lost"]))
    print(f"\n(frames {b}-{max(gt)}; 'seen' = frames with an image, 'blank' = frames bridged by the dynamics; "
          f"'lost' = blank runs after which the centre error is still > 10 px on the 3rd frame; outputs in {tmp}, deleted at exit unless GFLOW_BENCH_KEEP=1)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
