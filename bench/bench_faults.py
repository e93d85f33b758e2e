"""What faults cost: the checkpoint a restartable stage writes after every step, and the time a
SIGKILLed stage of the chamfer tracker takes to be back at work, with the boxes compared to an
undisturbed run. One command: ``python bench/bench_faults.py``.

* checkpoint: mean time of ``snapshot()`` + an atomic file write per step, per stage kind, on
  caviar1-sized frames with 500 particles (what ``pipeline/runtime/stage_node.py`` does after each step of a
  stage whose graph says ``restart: on-failure``);
* resume: the chamfer graph on caviar1 (frames 0-149) as processes; at frame ~60 one stage is
  SIGKILLed; "back after" is the time from the kill to the restarted process's first
  heartbeat showing progress past the frame it resumed from; "boxes differ" counts the frames
  whose box differs from an undisturbed run.
"""

from __future__ import annotations

import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import msgspec  # noqa: E402
import numpy as np  # noqa: E402
from _util import table  # noqa: E402

from gflow_core.features import chamfer_image  # noqa: E402
from pipeline.runtime.graph import load_graph  # noqa: E402
from pipeline.runtime.launcher import Launcher  # noqa: E402
from pipeline.runtime.checkpoint import Checkpoint  # noqa: E402
from pipeline.recording.results import estimates, read_boxes  # noqa: E402
from pipeline.runtime.transport import ZenohSettings, free_port  # noqa: E402
from stages.base import StageContext  # noqa: E402
from gflow_msgs.messages import Features, Header, NDArray, decode  # noqa: E402
from stages.particle_filter import FilterParams, FilterStage  # noqa: E402
from stages.particle_proposal import ProposalParams, ProposalStage  # noqa: E402
from stages.preprocess import PreprocessParams, PreprocessStage  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
STOP = 150


def checkpoint_costs(tmp: Path, n: int = 200) -> list[list]:
    e = np.zeros((288, 384), np.uint8)
    e[70:150, 129] = 255
    e[70, 129:160] = 255
    feat = Features(Header("s", 0, 0), NDArray.of(e), NDArray.of(e), NDArray.of(chamfer_image(e).astype(np.float32)),
                    "truncated", 100.0)
    filt = FilterStage(FilterParams(init=(129, 71, 30, 79), particles=500), StageContext("filter", "s"))
    filt.step(0, {"features": feat, "proposals": None})
    stages = {"particle.filter (500 particles)": filt,
              "particle.proposal": ProposalStage(ProposalParams(), StageContext("proposal", "s")),
              "preprocess": PreprocessStage(PreprocessParams(), StageContext("preprocess", "s"))}
    rows = []
    for name, st in stages.items():
        path = tmp / "x.ckpt"
        t0 = time.perf_counter()
        for i in range(n):
            ck = Checkpoint(seq=i, data=st.snapshot(), max_out={"out": i})
            part = path.with_suffix(".tmp")
            part.write_bytes(msgspec.msgpack.encode(ck))
            os.replace(part, path)
        rows.append([name, f"{(time.perf_counter() - t0) / n * 1e3:.3f}", path.stat().st_size])
    return rows


def run(tmp: Path, victim: str | None) -> tuple[dict, float | None, bool]:
    seq = DATA / "caviar1"
    init = list(read_boxes(seq / "groundtruth.csv")[0])
    plan = load_graph("chamfer", overrides={"source": {"kind": "folder", "path": str(seq / "frames"), "stop": STOP},
                                            "filter": {"init": init}, "preprocess": {"calibrate_box": init}})
    rec = tmp / f"{victim or 'base'}.mcap"
    la = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=str(rec),
                  progress=False)
    out: dict = {}
    th = threading.Thread(target=lambda: out.setdefault("r", la.run()), daemon=True)
    th.start()
    back = None
    if victim is not None:
        key = "filter" if victim == "recorder" else victim
        while not (la.status.get(key) and la.status[key].last_seq >= 60):
            time.sleep(0.005)
        pid = la.pids[victim][0]
        at = la.status[victim].last_seq if victim != "recorder" else -1
        t0 = time.monotonic()
        os.kill(pid, signal.SIGKILL)
        while th.is_alive():
            st = la.status.get(victim)
            if st is not None and st.pid != pid and (st.last_seq > at or victim == "recorder") and st.state == "running":
                back = time.monotonic() - t0
                break
            time.sleep(0.005)
    th.join()
    r = out["r"]
    boxes = {k: e.box for k, e in estimates(rec).items()}
    for seq, payload in r.estimates.items():  # what the recording lost while its recorder restarted
        if seq not in boxes:
            boxes[seq] = decode(payload).box
    return boxes, back, r.ok


def main() -> None:
    import argparse

    argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    with tempfile.TemporaryDirectory(prefix="gflow-bench-faults-") as d:
        tmp = Path(d)
        print("checkpoint per step (snapshot + atomic write):")
        print(table(checkpoint_costs(tmp), ["stage", "ms", "bytes"]))
        if not (DATA / "caviar1").is_dir():
            print(f"\n{DATA / 'caviar1'} not found: the resume measurements need it")
            return
        base, _, ok = run(tmp, None)
        rows = []
        for victim in ("source", "preprocess", "proposal", "filter", "recorder"):
            boxes, back, ok = run(tmp, victim)
            differ = sum(1 for f in base if boxes.get(f) != base[f])
            rows.append([victim, "yes" if ok else "NO", f"{back:.2f}" if back is not None else "-",
                         f"{len(boxes)}/{len(base)}", differ])
        print(f"\nSIGKILL one stage at frame ~60 of caviar1 frames 0-{STOP - 1} (chamfer graph, processes):")
        print(table(rows, ["killed", "run ok", "back after (s)", "frames with a box", "boxes differ"]))


if __name__ == "__main__":
    main()
