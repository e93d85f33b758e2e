"""G-flow's points after something covers the face: david_indoor's stress cases scored with the
landmark metric (README "Faces") on the frames after the disturbance.

One command: ``python bench/bench_gflow_stress_points.py [--cases occlude-25,occlude-60,...] [--compare DIR]``

The stress benchmark (``gflow benchmark ../shared/data --stress``, docs/recovery.md) derives each
case from the frames of a shared sequence: an image patch hides the target, sweeps or slides across
it, the target leaves the frame, ... and scores the box. Its derived frames of david_indoor are
frames of the original video (or those frames with a patch pasted), so the original's reference
landmarks score the face's points too. For each case this runs ``gflow track DERIVED --tracker gflow
--points-out P.csv --inline --seed 1`` from the derived ground truth's first box (as the stress
benchmark does) and prints the landmark NME over the frames from 10 after the case's window to the
end (the target in view again), over the frames before the window, and the box's success after
it. ``--compare DIR`` runs the same on the code of another checkout (an older commit's worktree),
alternately. The derived frames are made as the stress benchmark makes them (the same cache folder
layout, in a temporary folder unless ``--cache DIR``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import checkout, scratch, table  # noqa: E402

from gflow_core.gflow.landmark_error import landmark_score  # noqa: E402
from gflow_core.evaluation.metrics import iou  # noqa: E402
from gflow_core.evaluation.stress import CASES  # noqa: E402
from pipeline.evaluation.sequence_benchmark import find_sequences  # noqa: E402
from pipeline.evaluation.stress_benchmark import derive  # noqa: E402
from pipeline.io.landmarks import read_landmarks, read_points  # noqa: E402
from pipeline.recording.results import read_boxes  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
DEFAULT_CASES = "none,occlude-10,occlude-25,occlude-60,occlude-150,sweep-40,slide-60,leave-40"
AFTER = 10  # frames after the window before the points are scored (as the stress benchmark's "back")


def score(d, points_csv: Path, boxes_csv: Path, reference: np.ndarray) -> tuple[float, float, float]:
    """(NME before the window, NME from AFTER frames after it, box success from then on)."""
    src = d.plan.source
    w0, w1 = d.plan.window
    pts = read_points(points_csv)
    # derived frame i shows original frame src[i]: score its points against that frame's landmarks
    by_orig = {int(src[i]): p for i, p in pts.items()}

    def nme(frames) -> float:
        s = landmark_score(reference, {int(src[i]): by_orig[int(src[i])] for i in frames if int(src[i]) in by_orig},
                           frames=[int(src[i]) for i in frames])
        return s.nme

    after = range(w1 + AFTER, len(src))
    gt, pred = d.seq.groundtruth, read_boxes(boxes_csv)
    both = [i for i in after if i in gt and i in pred]
    success = float(np.mean(iou(np.array([gt[i] for i in both]), np.array([pred[i] for i in both])) > 0.5)) \
        if both else float("nan")
    return nme(range(w0)), nme(after), success


def run_code(code: Path, derived: list, reference: np.ndarray, out: Path, seed: int) -> list[tuple]:
    env = dict(os.environ, PYTHONPATH=str(code))
    rows = []
    for d in derived:
        first = d.seq.groundtruth[0]
        tag = f"{code.name}-{d.case.name}"
        pts, boxes = out / f"{tag}-p.csv", out / f"{tag}-b.csv"
        cmd = [sys.executable, "-m", "pipeline.cli", "track", str(d.seq.path), "--tracker", "gflow", "--init",
               ",".join(f"{v:g}" for v in first), "--seed", str(seed), "--out", str(boxes), "--points-out", str(pts),
               "--no-record", "--inline", "-q"]
        r = subprocess.run(cmd, cwd=code, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed in {code}:\n{r.stderr}")
        rows.append((d.case.name, *score(d, pts, boxes, reference)))
        print(f"  {code}: {d.case.name}: NME after {rows[-1][2]:.3f}", file=sys.stderr)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default=DEFAULT_CASES, help=f"stress cases (default {DEFAULT_CASES})")
    ap.add_argument("--seed", type=int, default=1, help="seed of the runs and of the derived frames (default 1)")
    ap.add_argument("--compare", metavar="DIR", help="another checkout to run alternately with this one")
    ap.add_argument("--cache", metavar="DIR", help="keep the derived frames here (the stress benchmark's layout)")
    args = ap.parse_args()
    codes = [ROOT] + ([checkout(ap, args.compare)] if args.compare else [])
    seqs, _ = find_sequences([str(DATA)])
    names = [s.name for s in seqs]
    if "david_indoor" not in names:
        raise SystemExit(f"{DATA}/david_indoor not found: this benchmark needs it")
    david = seqs[names.index("david_indoor")]
    donor = seqs[(names.index("david_indoor") + 1) % len(seqs)]  # as the stress benchmark picks it
    cases = {c.name: c for c in CASES}
    unknown = [c for c in args.cases.split(",") if c not in cases]
    if unknown:
        raise SystemExit(f"unknown stress case(s) {', '.join(unknown)} (gflow benchmark --stress --list-cases)")
    tmp = scratch("gflow-stress-points-")
    root = Path(args.cache) if args.cache else tmp / "derived"
    derived = [derive(david, cases[c], donor, root, args.seed, 30, 60) for c in args.cases.split(",")]
    reference = read_landmarks(DATA / "david_indoor" / "landmarks.npz")
    results = {str(c): run_code(c, derived, reference, tmp, args.seed) for c in codes}
    head = ["case", "NME before the window", f"NME from {AFTER} frames after", "box success after"]
    for code in codes:
        print(f"\n{'this code' if code == ROOT else code}: david_indoor stress cases, seed {args.seed}, inline")
        print(table([[n, f"{b:.3f}", f"{a:.3f}", f"{s:.2f}"] for n, b, a, s in results[str(code)]], head))


if __name__ == "__main__":
    main()
