"""How much of its velocity each shared sequence's target carries on, read off its labels: per sequence,
the least-squares gain g of the displacement on the one before (d_t = g d_{t-1} + e, the fit
``gflow_core.dcf.motion_fit`` makes online from the track), and the mean distance from the next labelled
centre to three predictions: constant velocity (c + d), half the velocity (c + d / 2) and the last place (c).

The labels are taken every ``--every`` frames (3: as the `fast` variant sees them; the MIL sequences,
labelled every 5th frame, at every 5th). Writes nothing.

    python bench/bench_motion_gain.py [--every 3] [DATA]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import table  # noqa: E402

from pipeline.recording.results import read_boxes  # noqa: E402


def centres(gt: dict, every: int) -> np.ndarray:
    """(K, 2) the labelled centres every ``every`` frames from the first label (at the labels' own step if coarser)."""
    ks = sorted(gt)
    step = max(every, ks[1] - ks[0]) if len(ks) > 1 else every
    kept = [k for k in ks if (k - ks[0]) % step == 0]
    return np.array([[gt[k][0] + gt[k][2] / 2.0, gt[k][1] + gt[k][3] / 2.0] for k in kept]), step


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data"), help="folder of sequences")
    ap.add_argument("--every", type=int, default=3, help="take the labels every N frames (default 3)")
    args = ap.parse_args()
    if args.every < 1:
        ap.error(f"--every must be >= 1, got {args.every}")
    data = Path(args.data)
    seqs = sorted(p for p in data.iterdir() if (p / "groundtruth.csv").is_file()) if data.is_dir() else []
    if not seqs:
        print(f"bench_motion_gain: no sequence folders (with groundtruth.csv) in {data}", file=sys.stderr)
        return 2
    rows = []
    for seq in seqs:
        c, step = centres(read_boxes(seq / "groundtruth.csv"), args.every)
        d = np.diff(c, axis=0)
        prev, nxt = d[:-1], d[1:]
        # g = sum d_t . d_{t-1} / sum |d_{t-1}|^2: least squares of d_t = g d_{t-1} + e
        g = float((prev * nxt).sum() / max((prev * prev).sum(), 1e-12))
        err = [float(np.hypot(*(nxt - a * prev).T).mean()) for a in (1.0, 0.5, 0.0)]
        rows.append([seq.name, step, len(c), f"{float(np.hypot(*d.T).mean()):.1f}", f"{g:.2f}",
                     *(f"{e:.1f}" for e in err)])
    print(table(rows, ["sequence", "every", "labels", "mean |d| px", "gain g", "err c + d px", "err c + d/2 px",
                       "err c px"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
