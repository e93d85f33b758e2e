"""Re-execution speed against live speed, per stage. One command: ``python bench/bench_rerun.py``.

Records a real multi-process run of the chamfer tracker (caviar1, or the synthetic scene
when the data is absent), then re-runs every stage from the recording with
``pipeline.recording.rerun.rerun_stage`` and checks the outputs are identical.

* live rate: frames the stage handled / time between its first and last output in the
  recording (publish times) - the rate the live pipeline sustained;
* re-run rate: frames / wall time of the re-run, which includes reading and decoding the
  recording.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

from pipeline.runtime.launcher import Launcher  # noqa: E402
from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.recording.rerun import check_outputs, recorded_outputs, rerun_stage  # noqa: E402
from pipeline.runtime.transport import ZenohSettings, free_port  # noqa: E402

from bench_pipeline import plan_for  # noqa: E402


def live_rate(path: str, topic: str) -> tuple[int, float]:
    t = sorted(r.publish_ns for r in iter_records(path, topics=[topic]) if r.type not in ("EndOfStream",))
    return len(t), (len(t) - 1) / ((t[-1] - t[0]) / 1e9) if len(t) > 1 else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=500)
    args = ap.parse_args()
    name, plan = plan_for(args.particles)
    rec = str(scratch("gflow-bench-rerun-") / "live.mcap")
    res = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=rec,
                   progress=False).run()
    assert res.ok, res.exits
    rows = []
    for stage, sp in plan.stages.items():
        if sp.kind == "recorder":
            continue
        topic = next(iter(sp.outputs.values()))
        n, live = live_rate(rec, topic)
        r = rerun_stage(rec, stage)
        topics = set(sp.outputs.values()) | ({plan.snapshot_topic(stage)} if sp.snapshot_every else set())
        same = not check_outputs(recorded_outputs(rec, topics), r.outputs)
        rerun = r.steps / r.seconds if r.seconds > 0 else float("inf")
        rows.append([stage, n, f"{live:.1f}", f"{rerun:.1f}", f"{rerun / live:.1f}x", "yes" if same else "NO"])
    print(f"chamfer tracker on {name}, {args.particles} particles; recording {rec}")
    print(table(rows, ["stage", "frames", "live fps", "re-run fps", "re-run / live", "bit-identical"]))


if __name__ == "__main__":
    main()
