"""Recorder throughput: MB/s and messages/s, with none lost. One command:
``python bench/bench_recorder.py``.

1. in-process: McapRecorder.write of 640x480 grey Frame messages (lz4 chunks, flushed
   every 0.5 s), then the file is read back and every message counted;
2. over zenoh: a publisher process sends the same messages as fast as congestion control
   BLOCK allows to a recorder loop in this process (zenoh callback -> queue -> MCAP), and
   the recording is read back and counted;
3. a burst into a real recorder process: a graph of a folder source (caviar1, 384x288
   colour, read as fast as it goes, no flow control) and the recorder node, run by the
   launcher. The source outruns the recorder; its inbox is bounded (32 MiB), so zenoh's
   BLOCK holds the source back. Printed: frames recorded (none may be lost) and the peak
   RSS of each process (sampled every 20 ms) next to the 250 MB budget.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.io.recorder import McapRecorder  # noqa: E402
from stages.messages import Frame, Header, NDArray, encode  # noqa: E402

PUB = r"""
import sys, time
sys.path.insert(0, sys.argv[3])
import numpy as np
from pipeline.runtime.transport import Bus, ZenohSettings, open_session
from stages.messages import Frame, Header, NDArray, encode
n, ep = int(sys.argv[1]), sys.argv[2]
s = open_session(ZenohSettings(connect=(ep,)))
bus = Bus(s)
rng = np.random.default_rng(0)
img = NDArray.of(rng.integers(0, 255, (480, 640), dtype=np.uint8))
time.sleep(1.0)
t0 = time.perf_counter()
for i in range(n):
    bus.publish("gflow/bench/frames", encode(Frame(Header("bench", i, i), img)), i)
print(time.perf_counter() - t0, flush=True)
time.sleep(0.5)
s.close()
"""


def payloads(n: int) -> list[bytes]:
    rng = np.random.default_rng(0)
    img = NDArray.of(rng.integers(0, 255, (480, 640), dtype=np.uint8))
    return [encode(Frame(Header("bench", i, i), img)) for i in range(n)]


def count(path: str) -> int:
    return sum(1 for r in iter_records(path) if r.topic == "gflow/bench/frames")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--compression", default="lz4", choices=["lz4", "zstd", "none"])
    ap.add_argument("--repeat", type=int, default=1, help="runs of the burst into a recorder process")
    args = ap.parse_args()
    tmp = str(scratch("gflow-bench-rec-"))
    msgs = payloads(args.n)
    size = sum(len(m) for m in msgs)
    path = os.path.join(tmp, "inproc.mcap")
    t0 = time.perf_counter()
    with McapRecorder(path, compression=args.compression) as rec:
        for i, m in enumerate(msgs):
            rec.write("gflow/bench/frames", m, i)
    dt = time.perf_counter() - t0
    got = count(path)
    rows = [["in-process write", args.n, f"{size / dt / 1e6:.0f}", f"{args.n / dt:.0f}", f"{got}/{args.n}",
             f"{os.path.getsize(path) / 1e6:.0f}"]]

    # over zenoh, into the recorder's own loop
    from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session
    import queue

    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    s = open_session(ZenohSettings(listen=(ep,)))
    q: queue.SimpleQueue = queue.SimpleQueue()
    Bus(s).subscribe("gflow/bench/**", lambda k, p, ns, seq: q.put((k, p, ns, seq)))
    path2 = os.path.join(tmp, "zenoh.mcap")
    pub = subprocess.Popen([sys.executable, "-c", PUB, str(args.n), ep, str(Path(__file__).resolve().parent.parent)],
                           stdout=subprocess.PIPE, text=True)
    n = 0
    first = last = None
    with McapRecorder(path2, compression=args.compression) as rec:
        while n < args.n:
            try:
                k, p, ns, seq = q.get(timeout=30)
            except queue.Empty:
                break
            now = time.perf_counter()
            first = now if first is None else first
            last = now
            rec.write(k, p, seq, publish_ns=ns)
            n += 1
    pub.wait(30)
    s.close()
    got2 = count(path2)
    dt2 = (last - first) if first and last and last > first else float("nan")
    rows.append(["zenoh -> recorder process", args.n, f"{size / dt2 / 1e6:.0f}", f"{args.n / dt2:.0f}",
                 f"{got2}/{args.n}", f"{os.path.getsize(path2) / 1e6:.0f}"])
    print(f"640x480 grey Frame messages ({len(msgs[0])} bytes each), compression {args.compression}")
    print(table(rows, ["path", "messages", "MB/s", "msgs/s", "recorded", "file MB"]))
    burst(tmp, args.compression, args.repeat)


BUDGET_MB = 250


def burst(tmp: str, compression: str, repeat: int) -> None:
    """Frames as fast as the source reads them into a recorder process; peak RSS per process."""
    import threading

    import psutil

    from pipeline.runtime.graph import parse_graph
    from pipeline.runtime.launcher import Launcher

    seq = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "caviar1" / "frames"
    if not seq.is_dir():
        print(f"note: {seq} not found; the burst into a recorder process is skipped")
        return
    frames = len([p for p in seq.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png")])
    text = (f"name: burst\nstream: burst\nstages:\n  source:\n    kind: source\n"
            f"    params: {{kind: folder, path: {str(seq)!r}, fps: 25}}\n"
            f"  recorder:\n    kind: recorder\n    params: {{path: rec.mcap, compression: {compression}}}\n")
    rows = []
    for k in range(repeat):
        plan = parse_graph(text, "burst.yaml", tmp)
        path = os.path.join(tmp, f"burst-{k}.mcap")
        peak: dict[int, float] = {}
        stop = threading.Event()

        def sample() -> None:
            me = psutil.Process()
            while not stop.is_set():
                for c in me.children():
                    try:
                        peak[c.pid] = max(peak.get(c.pid, 0.0), c.memory_info().rss / 2**20)
                    except psutil.Error:
                        pass
                stop.wait(0.02)

        th = threading.Thread(target=sample, daemon=True)
        th.start()
        t0 = time.perf_counter()
        res = Launcher(plan, recording=path, progress=False).run()
        wall = time.perf_counter() - t0
        stop.set()
        th.join()
        got = sum(1 for r in iter_records(path) if r.topic.endswith("/frames") and r.type == "Frame")
        mb = sum(len(r.data) for r in iter_records(path) if r.topic.endswith("/frames")) / 1e6
        by_stage = {n: max(peak.get(pid, 0.0) for pid in pids) for n, pids in res.pids.items()}
        rows.append([k, f"{got}/{frames}", f"{mb:.0f}", f"{wall:.2f}", f"{mb / wall:.0f}",
                     f"{by_stage.get('source', 0):.0f}", f"{by_stage.get('recorder', 0):.0f}", BUDGET_MB,
                     "yes" if res.ok else f"no: {res.exits}"])
    print()
    print("burst: caviar1 frames read as fast as they come into a recorder process (launcher, zenoh, BLOCK)")
    print(table(rows, ["run", "frames recorded", "MB", "wall s (incl. start)", "MB/s", "source peak RSS MB",
                       "recorder peak RSS MB", "budget MB", "ok"]))


if __name__ == "__main__":
    main()
