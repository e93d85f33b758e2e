"""End-to-end frames/s of ``gflow track`` as processes over zenoh versus ``--inline``, and
the peak memory (RSS) of every stage process. One command: ``python bench/bench_pipeline.py``.

Runs the chamfer tracker on ../shared/data/caviar1 (or the synthetic scene when the data is
absent). Frames/s counts the frames tracked over the wall time from the first to the last
estimate (start-up excluded), from the recording's log times. RSS is what each stage's
heartbeat reports (sampled at up to 50 Hz), peak over the run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

from pipeline.runtime.build import apply_defaults  # noqa: E402
from pipeline.runtime.graph import load_graph  # noqa: E402
from pipeline.runtime.inline import run_inline  # noqa: E402
from pipeline.runtime.launcher import Launcher  # noqa: E402
from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.recording.results import read_boxes  # noqa: E402
from pipeline.runtime.transport import ZenohSettings, free_port  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def plan_for(particles: int):
    seq = DATA / "caviar1"
    if seq.is_dir():
        init = list(read_boxes(seq / "groundtruth.csv")[0])
        return "caviar1", load_graph("chamfer", overrides={
            "source": {"kind": "folder", "path": str(seq / "frames")},
            "filter": {"init": init, "particles": particles}, "preprocess": {"calibrate_box": init}})
    print(f"note: {seq} not found; using the synthetic scene", file=sys.stderr)
    return "synthetic", apply_defaults(load_graph("demo", overrides={"source": {"frames": 300},
                                                                     "filter": {"particles": particles}}))


def tracked_fps(path: str) -> tuple[int, float]:
    t = [r.log_ns for r in iter_records(path) if r.type == "Estimate"]
    return len(t), (len(t) - 1) / ((max(t) - min(t)) / 1e9)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--out", default=None, help="keep the recordings in this folder (default: a temporary one, deleted)")
    args = ap.parse_args()
    args.out = str(scratch("gflow-bench-", keep=args.out))
    name, plan = plan_for(args.particles)
    rec_i = f"{args.out}/inline.mcap"
    t0 = time.perf_counter()
    run_inline(plan, recording=rec_i)
    wall_i = time.perf_counter() - t0
    n_i, fps_i = tracked_fps(rec_i)
    name, plan = plan_for(args.particles)
    rec_p = f"{args.out}/processes.mcap"
    res = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=rec_p,
                   progress=False).run()
    assert res.ok, res.exits
    n_p, fps_p = tracked_fps(rec_p)
    print(f"chamfer tracker on {name}, {args.particles} particles")
    print(table([["inline (one process)", n_i, f"{fps_i:.1f}", f"{wall_i:.2f}"],
                 ["processes over zenoh", n_p, f"{fps_p:.1f}", f"{res.seconds:.2f} (incl. start-up)"]],
                ["mode", "frames", "fps", "wall s"]))
    print(f"multi-process / inline fps ratio: {fps_p / fps_i:.2f}")
    print()
    print(table([[n, f"{mb:.0f}"] for n, mb in sorted(res.peak_rss_mb.items())], ["stage process", "peak RSS MB"]))


if __name__ == "__main__":
    main()
