"""M2 that transfers: a model learned on one pedestrian video tracking a pedestrian in another.

    python bench/bench_m2_transfer.py                 # seeds 1-6, --inline
    python bench/bench_m2_transfer.py --seeds 1,2,3
    python bench/bench_m2_transfer.py --root ../main   # the code of another checkout, to compare
    python bench/bench_m2_transfer.py --set preprocess.match_resolution=true   # a parameter for every run
    python bench/bench_m2_transfer.py --learn-args="--kernel-floor 0"           # options of both learnings

Learns two models with `gflow learn m2` (K = 20, from the ground-truth boxes): one on caviar1
frames 0-149 (a 28x73 px walker), one on all of crossing (a 16x42 px walker), and runs `gflow
benchmark --trackers m2 --inline` with each seed on:

* crossing with the caviar1 model (a target 0.6 times the model's size);
* caviar1 with the crossing model (1.9 times it);
* caviar1 frames 150-381 with the caviar1 model (the frames it was not trained on), and all of
  caviar1 with it (its training frames included), the figures the transfer must not worsen.

Prints CLE, AUC and success per seed and their means, each computed from the runs' boxes and rounded
once, as printed (the benchmark JSON's figures are rounded already). The models and the runs' boxes go to
a temporary folder, removed at the end (``GFLOW_BENCH_KEEP=1`` keeps it).
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
#: the checkout whose gflow runs (--root)
CODE = ROOT


def gflow(*argv: str) -> str:
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", *argv], cwd=CODE, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"gflow {' '.join(argv)} failed: {r.stderr.strip()[-500:]}")
    return r.stdout


def run(model: Path, seq: str, frames: str | None, seed: int, sets: list[str], out_dir: Path
        ) -> tuple[float, float, float]:
    """(CLE px, AUC, success at IoU 0.5) of one run, unrounded: the benchmark's boxes (kept in ``out_dir``)
    scored as it scores them (:func:`score`); its JSON's figures are rounded (4 decimals), and a mean of
    rounded figures rounded again at print could differ from the mean of the figures in the last digit."""
    argv = ["benchmark", str(DATA), "--sequences", seq, "--trackers", "m2", "--m2-model", str(model), "--inline",
            "--seed", str(seed), "--json", "-q", "--out-dir", str(out_dir)] + (["--frames", frames] if frames else [])
    argv += [a for kv in sets for a in ("--set", kv)]
    result = json.loads(gflow(*argv))
    row = next(r for r in result["rows"] if r["tracker"] == "m2")
    return score(row, DATA / seq, result["frames"])


def score(row: dict, folder: Path, frames: list) -> tuple[float, float, float]:
    """(CLE px, AUC, success at IoU 0.5), unrounded, of the boxes of the benchmark's JSON ``row`` (its
    ``boxes``, kept by --out-dir) on the sequence ``folder``'s ground truth of ``frames`` ([A or None, B or
    None], the JSON's): what ``gflow benchmark`` scored, before its JSON rounded it. A figure that disagrees
    with the JSON's beyond its rounding (another scoring, other frames) stops the benchmark."""
    from pipeline.evaluation.sequence_benchmark import Row, find_sequences, score_row

    (seq,), _ = find_sequences([str(folder)])
    start = min(seq.groundtruth) if frames[0] is None else frames[0]
    scored = score_row(Row(seq.name, "m2", "tracker"), seq.truth(start, frames[1]), Path(row["boxes"]))
    assert scored.score is not None and scored.auc is not None
    out = (float(scored.score.cle), float(scored.auc), float(scored.score.success))
    for name, mine, theirs in zip(("cle_px", "auc", "success_rate_0.5"), out, (row["cle_px"], row["auc"],
                                                                            row["success_rate_0.5"])):
        if not abs(mine - theirs) <= 1e-3:
            raise SystemExit(f"{folder.name}: {name} {mine} rescored from {row['boxes']}, but the benchmark says "
                             f"{theirs}")
    return out


def figures(res: np.ndarray) -> list[str]:
    """The table's cells of one case from its unrounded (seeds, 3) figures (CLE, AUC, success): each figure,
    mean and range rounded once, as it is printed."""
    return [" / ".join(f"{v:.2f}" for v in res[:, 0]), f"{res[:, 0].mean():.2f}",
            " / ".join(f"{v:.3f}" for v in res[:, 1]), f"{res[:, 1].mean():.3f}",
            f"{res[:, 2].min():.3f}-{res[:, 2].max():.3f}"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="1-6", help="seeds to run: 1,2,3 or 1-6 (default 1-6)")
    ap.add_argument("--root", metavar="DIR", help="run the gflow of this checkout (its pipeline/ is imported from "
                                                  "there), e.g. the code before a change")
    ap.add_argument("--set", action="append", default=[], metavar="STAGE.PARAM=VALUE",
                    help="a parameter of every tracking run, as gflow benchmark --set takes it; repeatable")
    ap.add_argument("--learn-args", default="", metavar="ARGS",
                    help="options added to both `gflow learn m2` commands, e.g. --learn-args=\"--kernel-floor 0\"")
    args = ap.parse_args()
    global CODE
    if args.root:
        CODE = Path(args.root).resolve()
        if not (CODE / "pipeline" / "cli").is_dir():
            raise SystemExit(f"--root {args.root}: not a gflow checkout (no pipeline/cli)")
    if not (DATA / "caviar1").is_dir() or not (DATA / "crossing").is_dir():
        raise SystemExit(f"needs caviar1 and crossing in {DATA}")
    from pipeline.evaluation.seed_means import parse_seeds

    try:
        seeds = parse_seeds(args.seeds)  # 1,2,3 or 1-6, as gflow benchmark --seeds reads them
    except ValueError as e:
        raise SystemExit(f"bench_m2_transfer.py: error: {e}") from None
    tmp = scratch("gflow-bench-m2-transfer-")
    cav, cross = tmp / "caviar1-0-149.npz", tmp / "crossing.npz"
    more = shlex.split(args.learn_args)
    gflow("learn", "m2", str(DATA / "caviar1"), "--boxes", str(DATA / "caviar1" / "groundtruth.csv"), "--frames",
          "0:150", "-K", "20", "--out", str(cav), "-q", *more)
    gflow("learn", "m2", str(DATA / "crossing"), "--boxes", str(DATA / "crossing" / "groundtruth.csv"), "-K", "20",
          "--out", str(cross), "-q", *more)
    cases = [("caviar1 0-149 -> crossing", cav, "crossing", None),
             ("crossing -> caviar1", cross, "caviar1", None),
             ("caviar1 0-149 -> caviar1 150-381", cav, "caviar1", "150:"),
             ("caviar1 0-149 -> caviar1 (all)", cav, "caviar1", None)]
    rows = []
    for i, (name, model, seq, frames) in enumerate(cases):
        res = np.array([run(model, seq, frames, s, args.set, tmp / f"runs-{i}-seed-{s}") for s in seeds])
        rows.append([name, *figures(res)])
        print(f"{name}: done", file=sys.stderr, flush=True)
    extra = "".join(f", --set {kv}" for kv in args.set) + (f", learned with {args.learn_args}" if more else "")
    print(f"M2 transfer, seeds {args.seeds}, --inline{extra} (CLE px, AUC of the success plot, success at IoU 0.5)")
    print(table(rows, ["model -> sequence", "CLE per seed", "mean", "AUC per seed", "mean", "success"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
