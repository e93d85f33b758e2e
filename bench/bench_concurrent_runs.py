"""Runs started together keep a recording each: N ``gflow track`` and M ``gflow demo`` runs
started in the same second in one folder (the default recordings/), then each recording read to
its end and re-run bit for bit (``gflow rerun --stage filter --check``).

    python bench/bench_concurrent_runs.py                  # 8 tracks and 4 demos, 30 frames each
    python bench/bench_concurrent_runs.py --tracks 2 --demos 2 --frames 10

Prints how many runs exited 0, how many recordings there are, how many were readable and how
many re-ran identically, and the wall time of the runs and of the checks. Exits 1 unless every
run kept a readable recording that re-runs bit for bit. Needs ../shared/data/crossing for the
tracks (without it, demos only).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import scratch  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("GFLOW_DATA", ROOT.parent / "shared" / "data"))
GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tracks", type=int, default=8, help="gflow track runs (default 8)")
    ap.add_argument("--demos", type=int, default=4, help="gflow demo runs (default 4)")
    ap.add_argument("--frames", type=int, default=30, help="frames of each run (default 30)")
    ap.add_argument("--out", help="keep the runs' folder here")
    args = ap.parse_args()
    seq = DATA / "crossing"
    tracks = args.tracks if seq.is_dir() else 0
    if tracks < args.tracks:
        print(f"{seq} is missing: demos only", file=sys.stderr)
    tmp = scratch("gflow-concurrent-", args.out)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               GFLOW_RUNTIME_DIR=str(tmp / "rt"))
    cmds = [[*GFLOW, "track", str(seq), "--init", "204,150,17,50", "--out", f"t{i}.csv", "--stop", str(args.frames),
             "-q"] for i in range(tracks)]
    cmds += [[*GFLOW, "demo", "--frames", str(args.frames), "--particles", "200"] for _ in range(args.demos)]
    t0 = time.monotonic()
    procs = [subprocess.Popen(c, cwd=tmp, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for c in cmds]  # all in the same second
    started = time.monotonic() - t0
    errs = [p.communicate()[1] for p in procs]
    t_runs = time.monotonic() - t0
    ok = sum(p.returncode == 0 for p in procs)
    for p, e in zip(procs, errs):
        if p.returncode != 0:
            print(f"a run exited {p.returncode}: {e.strip()[-300:]}", file=sys.stderr)
    recs = sorted((tmp / "recordings").glob("*.mcap"))
    t1 = time.monotonic()
    readable = same = 0
    for r in recs:
        info = subprocess.run([*GFLOW, "info", str(r)], cwd=tmp, env=env, capture_output=True, text=True)
        readable += info.returncode == 0
        chk = subprocess.run([*GFLOW, "rerun", str(r), "--stage", "filter", "--check"], cwd=tmp, env=env,
                             capture_output=True, text=True)
        same += chk.returncode == 0 and "all identical bit for bit" in chk.stdout
        if chk.returncode != 0:
            print(f"{r.name}: {chk.stdout.strip()[-300:]} {chk.stderr.strip()[-300:]}", file=sys.stderr)
    t_checks = time.monotonic() - t1
    n = len(cmds)
    print(f"{tracks} gflow track + {args.demos} gflow demo runs of {args.frames} frames, all started within "
          f"{started:.2f} s: {ok} of {n} exited 0 in {t_runs:.1f} s; {len(recs)} recordings, {readable} readable, "
          f"{same} re-ran bit for bit (checks {t_checks:.1f} s)")
    return 0 if ok == n and len(recs) == n and readable == n and same == n else 1


if __name__ == "__main__":
    sys.exit(main())
