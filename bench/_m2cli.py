"""Helpers of the M2 real-video benchmarks: run ``gflow`` commands as a user would, score boxes."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


def gflow(*args: str, quiet: bool = False) -> tuple[str, float]:
    """Run ``gflow ARGS`` from the repository root; print the command; return (stdout, seconds)."""
    cmd = [*GFLOW, *args]
    print("$ gflow " + " ".join(shlex.quote(a) for a in args), flush=True)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        sys.stderr.write(r.stdout + r.stderr)
        raise SystemExit(f"command failed with status {r.returncode}")
    if not quiet and r.stdout.strip():
        print("  " + r.stdout.strip().replace("\n", "\n  "), flush=True)
    return r.stdout, dt


def write_gt(path: Path, gt: dict[int, tuple], frames: range) -> Path:
    """Ground truth restricted to ``frames`` (so ``gflow eval`` scores only those)."""
    from pipeline.recording.results import write_boxes

    write_boxes(path, {f: gt[f] for f in frames if f in gt})
    return path


def evaluate(gt_csv: Path, pred_csv: Path) -> dict:
    """``gflow eval --json``: frames, cle_px, mean_overlap, success_rate_0.5, missing_predictions."""
    out, _ = gflow("eval", "--gt", str(gt_csv), "--pred", str(pred_csv), "--json", quiet=True)
    return json.loads(out)


def box_arg(box: tuple) -> str:
    return ",".join(f"{v:g}" for v in box)
