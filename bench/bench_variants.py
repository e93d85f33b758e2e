"""The trackers on other kinds of footage: the nine shared sequences as they are and as a variant.

    python bench/bench_variants.py                           # grey, dcf and appearance, seed 1, --inline
    python bench/bench_variants.py --variant fast --trackers dcf
    python bench/bench_variants.py --trackers dcf --seed 2 --sequences caviar1,skating1

A tracker tuned on some footage loses on other kinds: grey video (the colour cue has nothing to
say), a blurring camera, a target faster than the frames come, a small target. This runs ``gflow
benchmark`` on the originals and with ``--variant NAME`` (``grey``, ``blur``, ``fast``, ``small``:
docs/accuracy.md; the variant's frames are written losslessly to a temporary folder the benchmark
removes) with the same trackers and seed, and prints the two side by side. Where OpenCV's contrib
trackers are installed (CSRT, KCF), they are run on both too.

Prints, per sequence, each tracker's AUC on the originals and on the variant and a box that never
moves, then the means, to the four decimals of the benchmark's JSON. On ``grey``, sequences that are grey already (all channels equal) give the
same figures twice.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import table  # noqa: E402
from gflow_core.evaluation.variants import VARIANTS  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
SEQUENCES = "caviar1,crossing,david_indoor,dollar,jumping,skating1,surfer,tiger1,twinnings"


def benchmark(data: Path, sequences: str, trackers: str, seed: int, opencv: bool, variant: str | None = None) \
        -> dict[tuple[str, str], float]:
    """AUC by (tracker, sequence) from one ``gflow benchmark --json`` run (means under sequence "mean")."""
    argv = [sys.executable, "-m", "pipeline.cli", "benchmark", str(data), "--sequences", sequences,
            "--trackers", trackers, "--inline", "--seed", str(seed), "--no-fps", "--json", "-q"]
    if variant:
        argv += ["--variant", variant]
    if opencv:
        argv += ["--opencv", "csrt,kcf"]
    r = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"gflow benchmark on {data} failed: {r.stderr.strip()[-500:]}")
    out = json.loads(r.stdout)
    auc = {(row["tracker"], row["sequence"]): row["auc"] for row in out["rows"] if row.get("auc") is not None}
    auc.update({(name, "mean"): m["auc"] for name, m in out["means"].items()})
    return auc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trackers", default="dcf,appearance", help="trackers to run (default dcf,appearance)")
    ap.add_argument("--sequences", default=SEQUENCES, help="shared sequences (default: all nine)")
    ap.add_argument("--seed", type=int, default=1, help="seed (default 1)")
    ap.add_argument("--variant", default="grey", choices=sorted(VARIANTS),
                    help="the variant beside the originals (default grey; docs/accuracy.md)")
    args = ap.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"no shared data at {DATA}")
    names = [s.strip() for s in args.sequences.split(",") if s.strip()]
    missing = [s for s in names if not (DATA / s / "groundtruth.csv").is_file()]
    if missing:
        raise SystemExit(f"--sequences: no sequence {missing[0]!r} in {DATA}")
    opencv = hasattr(cv2, "TrackerCSRT_create") or hasattr(getattr(cv2, "legacy", None), "TrackerCSRT_create")
    print("running gflow benchmark on the originals", file=sys.stderr)
    original_auc = benchmark(DATA, ",".join(names), args.trackers, args.seed, opencv)
    print(f"running gflow benchmark --variant {args.variant} (its frames in a temporary folder it removes)",
          file=sys.stderr)
    variant_auc = benchmark(DATA, ",".join(names), args.trackers, args.seed, opencv, variant=args.variant)

    runs = args.trackers.split(",") + (["opencv csrt", "opencv kcf"] if opencv else []) + ["static box"]
    header = ["sequence"] + [f"{t} original / {args.variant}" for t in runs]
    rows = []
    for seq in names + ["mean"]:
        cells = []
        for t in runs:
            c, g = original_auc.get((t, seq)), variant_auc.get((t, seq))
            # the JSON's four decimals as they are: rounded again to three, 0.6005 (0.60048) would print 0.601
            # where gflow benchmark's own tables print 0.600
            cells.append("-" if c is None or g is None else f"{c:.4f} / {g:.4f}")
        rows.append([seq] + cells)
    print(f"AUC on the originals / on the {args.variant} variant (seed {args.seed}, --inline"
          f"{'' if opencv else '; OpenCV contrib not installed: no CSRT/KCF'})")
    print(table(rows, header))
    return 0


if __name__ == "__main__":
    sys.exit(main())
