"""Live tracking: caviar1 served on loopback as an H.264 MPEG-TS stream over TCP (FFmpeg,
``-re``) at 25 and 30 frames/s into every tracker, as processes and ``--inline``.

For each run it prints the frames the source captured, tracked and skipped (the newest frame
wins), the tracking rate, and the latency from capture (the host clock when the source read the
frame) to the estimate (as the recorder logged it): p50, p99 and max over the whole run.

    python bench/bench_live.py                         # every tracker, 25 and 30 frames/s, both modes
    python bench/bench_live.py --trackers gflow --rates 30 --modes processes --frames 200

The m2 tracker needs a model: one is learned first on caviar1 frames 0-59 (K = 8). Servers,
recordings and the model live in a scratch folder removed at the end (GFLOW_BENCH_KEEP=1 keeps
it); every FFmpeg server is killed when its run ends, also on an error or Ctrl-C.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from _util import scratch, table  # noqa: E402
from stream_server import StreamServer, ffmpeg_exe  # noqa: E402

from pipeline.recording.live_record import latency_percentiles, live_summary  # noqa: E402

DATA = Path(os.environ.get("GFLOW_DATA", ROOT.parent / "shared" / "data"))
INIT = "129,71,30,79"
TRACKERS = ("appearance", "chamfer", "m2", "gflow")


def gflow(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "pipeline.cli.main", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)


def learn_m2(work: Path, seq: Path) -> Path:
    model = work / "m2.npz"
    r = gflow("learn", "m2", str(seq), "--boxes", str(seq / "groundtruth.csv"), "--frames", "0:60", "-K", "8",
              "--out", str(model), cwd=work)
    if r.returncode != 0:
        raise SystemExit(f"learning the m2 model failed: {r.stderr.strip().splitlines()[-1:]}")
    return model


def run_one(work: Path, seq: Path, tracker: str, rate: float, mode: str, frames: int, model: Path | None) -> list:
    tag = f"{tracker}-{rate:g}-{mode}"
    rec, out = work / f"{tag}.mcap", work / f"{tag}.csv"
    extra = ["--model", str(model)] if tracker == "m2" and model else []
    extra += ["--inline"] if mode == "inline" else []
    t0 = time.monotonic()
    with StreamServer(seq / "frames", "tcp", fps=rate, count=frames) as srv:
        r = gflow("track", srv.url, "--tracker", tracker, "--init", INIT, "--out", str(out), "--record", str(rec),
                  "--fps", f"{rate:g}", "--reconnect", "0.5", "-q", *extra, cwd=work)
    wall = time.monotonic() - t0
    if r.returncode != 0:
        why = (r.stderr.strip().splitlines() or ["?"])[-1]
        return [tracker, f"{rate:g}", mode, "-", "-", "-", "-", "-", "-", "-", f"failed: {why[:80]}"]
    s = live_summary(rec)
    if s is None:
        return [tracker, f"{rate:g}", mode, "-", "-", "-", "-", "-", "-", "-", "no live summary"]
    p50, p99, worst = latency_percentiles(s.latency_ms)
    span = frames / rate
    return [tracker, f"{rate:g}", mode, s.captured, s.sent, s.skipped, f"{s.sent / span:.1f}",
            f"{p50:.0f}", f"{p99:.0f}", f"{worst:.0f}", f"{wall:.0f} s wall"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trackers", default=",".join(TRACKERS), help="comma-separated (default: all four)")
    ap.add_argument("--rates", default="25,30", help="stream frame rates (default 25,30)")
    ap.add_argument("--modes", default="processes,inline", help="processes and/or inline")
    ap.add_argument("--frames", type=int, default=382, help="frames served per run (default: all 382 of caviar1)")
    ap.add_argument("--keep", metavar="DIR", help="keep recordings and boxes in DIR")
    args = ap.parse_args()
    seq = DATA / "caviar1"
    if not (seq / "frames").is_dir():
        raise SystemExit(f"caviar1 not found at {seq} (set GFLOW_DATA)")
    if ffmpeg_exe() is None:
        raise SystemExit("no FFmpeg: pip install imageio-ffmpeg, or install ffmpeg")
    work = scratch("gflow-bench-live-", args.keep)
    trackers = [t for t in args.trackers.split(",") if t]
    model = learn_m2(work, seq) if "m2" in trackers else None
    print(f"caviar1, {args.frames} frames served as H.264 MPEG-TS over TCP on loopback; load average "
          f"{', '.join(f'{x:.2f}' for x in os.getloadavg())} at the start", flush=True)
    rows = []
    for tracker in trackers:
        for rate in (float(r) for r in args.rates.split(",")):
            for mode in args.modes.split(","):
                rows.append(run_one(work, seq, tracker, rate, mode, args.frames, model))
                print("  " + " ".join(str(c) for c in rows[-1]), flush=True)
    print()
    print(table(rows, ["tracker", "stream fps", "mode", "captured", "tracked", "skipped", "tracked/s",
                       "latency p50 ms", "p99 ms", "max ms", "note"]))
    print(f"\nload average {', '.join(f'{x:.2f}' for x in os.getloadavg())} at the end; latency: capture (host clock "
          f"at read) to the estimate as the recorder logged it")
    return 0


if __name__ == "__main__":
    sys.exit(main())
