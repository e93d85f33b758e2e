"""Recorder throughput: MB/s and messages/s, with none lost, and memory. One command:
``python bench/bench_recorder.py``.

Two kinds of 640x480 grey Frame messages (307 KB each): ``random`` pixels (a different image
per message, seeded; they do not compress) and ``caviar1`` (real frames of
../shared/data/caviar1, grey, resized to 640x480; lz4 makes them about 1.16x smaller).

1. in-process: McapRecorder.write of the messages (chunks of 4 MiB, flushed every 0.5 s),
   then the file is read back and every message counted. Like the recorder process, this
   process first tunes malloc (``pipeline/runtime/memory.py``);
2. over zenoh: a publisher process sends the messages as fast as congestion control BLOCK
   allows to a process running the recorder node's loop (zenoh callback -> the recorder's
   bounded inbox, 32 MiB -> McapRecorder), the recording is read back and counted. Printed
   besides: CPU per message of the recorder and the publisher process, and the peak RSS of
   both (sampled every 20 ms) next to the 250 MB budget;
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
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.io.recorder import McapRecorder  # noqa: E402
from pipeline.runtime.memory import keep_freed_memory  # noqa: E402
from gflow_msgs.messages import Frame, Header, NDArray, encode  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CAVIAR = Path(os.environ.get("GFLOW_DATA") or ROOT.parent / "shared" / "data") / "caviar1" / "frames"
KINDS = 50  # distinct images per kind, cycled

PUB = r"""
import sys, time
sys.path.insert(0, sys.argv[4])
sys.path.insert(0, sys.argv[4] + "/bench")
from pipeline.runtime.transport import Bus, ZenohSettings, open_session
from bench_recorder import images
from gflow_msgs.messages import Frame, Header, encode
n, ep, kind = int(sys.argv[1]), sys.argv[2], sys.argv[3]
imgs = images(kind)
s = open_session(ZenohSettings(connect=(ep,)))
bus = Bus(s)
time.sleep(1.0)
c0 = time.process_time()
for i in range(n):
    bus.publish("gflow/bench/frames", encode(Frame(Header("bench", i, i), imgs[i % len(imgs)])), i)
cpu = time.process_time() - c0
time.sleep(0.5)
s.close()
print('{"cpu": %f}' % cpu, flush=True)
"""


def images(kind: str) -> list[NDArray]:
    """``KINDS`` 640x480 grey images: seeded random pixels, or caviar1 frames ([] if absent)."""
    if kind == "random":
        rng = np.random.default_rng(0)
        return [NDArray.of(rng.integers(0, 255, (480, 640), dtype=np.uint8)) for _ in range(KINDS)]
    import cv2

    files = sorted(p for p in CAVIAR.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))[:KINDS] \
        if CAVIAR.is_dir() else []
    return [NDArray.of(cv2.resize(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), (640, 480))) for f in files]


def payloads(kind: str) -> list[bytes]:
    """One encoded Frame per image of :func:`images` (cycled by the in-process run)."""
    return [encode(Frame(Header("bench", i, i), img)) for i, img in enumerate(images(kind))]


def count(path: str) -> int:
    return sum(1 for r in iter_records(path) if r.topic == "gflow/bench/frames")


class PeakRss:
    """Peak RSS (MiB) of some processes, sampled every 20 ms on a thread."""

    def __init__(self, pids: list[int]) -> None:
        import psutil

        self.procs = [psutil.Process(p) for p in pids]
        self.peak = [0.0] * len(pids)
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def _run(self) -> None:
        import psutil

        while not self._stop.is_set():
            for i, p in enumerate(self.procs):
                try:
                    self.peak[i] = max(self.peak[i], p.memory_info().rss / 2**20)
                except psutil.Error:
                    pass
            self._stop.wait(0.02)

    def stop(self) -> list[float]:
        self._stop.set()
        self._th.join()
        return self.peak


def in_process(tmp: str, kind: str, msgs: list[bytes], n: int, compression: str) -> list:
    path = os.path.join(tmp, f"inproc-{kind}.mcap")
    size = sum(len(msgs[i % len(msgs)]) for i in range(n))
    c0, t0 = time.process_time(), time.perf_counter()
    with McapRecorder(path, compression=compression) as rec:
        for i in range(n):
            rec.write("gflow/bench/frames", msgs[i % len(msgs)], i)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    got = count(path)
    row = [f"in-process write, {kind}", n, f"{size / dt / 1e6:.0f}", f"{n / dt:.0f}",
           f"{got}/{n}", f"{size / os.path.getsize(path):.2f}", f"{dc / n * 1e6:.0f}", "", "", ""]
    os.unlink(path)
    return row


REC = r"""
import json, os, queue, sys, time
sys.path.insert(0, sys.argv[5])
from pipeline.runtime.memory import keep_freed_memory
keep_freed_memory()
from pipeline.io.recorder import McapRecorder
from pipeline.runtime.inbox import BoundedInbox
from pipeline.runtime.recorder_node import RECORDER_INBOX_BYTES
from pipeline.runtime.transport import Bus, ZenohSettings, open_session
n, ep, path, compression = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
s = open_session(ZenohSettings(listen=(ep,)))
q = BoundedInbox(RECORDER_INBOX_BYTES)
Bus(s).subscribe("gflow/bench/**", lambda k, p, ns, seq, t: q.put((k, p, ns, seq, t)), with_type=True)
print("ready", flush=True)
got, first, last, c0, c1 = 0, 0.0, 0.0, 0.0, 0.0
try:
    with McapRecorder(path, compression=compression) as rec:
        while got < n:
            try:
                k, p, ns, seq, t = q.get(timeout=30)
            except queue.Empty:
                break
            if got == 0:
                first, c0 = time.perf_counter(), time.process_time()
            rec.write(k, p, seq, publish_ns=ns, type_name=t)
            got += 1
            if got == n:
                last, c1 = time.perf_counter(), time.process_time()
    print(json.dumps({"got": got, "s": last - first, "cpu": c1 - c0}), flush=True)
finally:  # zenoh's callback thread may wait for room in the inbox for good: do not wait for it
    sys.stdout.flush()
    os._exit(0)
"""


def over_zenoh(tmp: str, kind: str, n: int, size: int, compression: str) -> list:
    """A publisher process -> zenoh -> a recorder loop process (the recorder node's: zenoh's
    callback -> the bounded inbox, 32 MiB -> McapRecorder)."""
    import json

    from pipeline.runtime.transport import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    path = os.path.join(tmp, f"zenoh-{kind}.mcap")
    # one BLAS thread per process, as the launcher gives each stage (pipeline/runtime/launcher.py)
    env = dict(os.environ, **{v: os.environ.get(v, "1") for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
    rec = subprocess.Popen([sys.executable, "-c", REC, str(n), ep, path, compression, str(ROOT)],
                           stdout=subprocess.PIPE, text=True, env=env)
    assert rec.stdout is not None and rec.stdout.readline().strip() == "ready"
    pub = subprocess.Popen([sys.executable, "-c", PUB, str(n), ep, kind, str(ROOT)], stdout=subprocess.PIPE, text=True,
                           env=env)
    rss = PeakRss([rec.pid, pub.pid])
    out = json.loads(rec.stdout.readline() or "{}")
    pub_cpu = json.loads(pub.communicate(timeout=60)[0].strip().splitlines()[-1])["cpu"]
    rec.wait(30)
    peak_rec, peak_pub = rss.stop()
    got = count(path)
    m = max(out.get("got", 0) - 1, 1)  # the rate is taken from the first message received to the last
    dt = out.get("s") or float("nan")
    row = [f"zenoh -> recorder loop, {kind}", n, f"{size * m / n / dt / 1e6:.0f}", f"{m / dt:.0f}", f"{got}/{n}",
           f"{size / os.path.getsize(path):.2f}", f"{out.get('cpu', 0) / m * 1e6:.0f}", f"{pub_cpu / n * 1e6:.0f}",
           f"{peak_rec:.0f} / {peak_pub:.0f}", BUDGET_MB]
    os.unlink(path)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--compression", default="lz4", choices=["lz4", "zstd", "none"])
    ap.add_argument("--kinds", default="random,caviar1", help="message kinds, comma separated: random, caviar1")
    ap.add_argument("--repeat", type=int, default=1, help="runs of the burst into a recorder process")
    args = ap.parse_args()
    keep_freed_memory()  # as the recorder process does (pipeline/runtime/node.py: run_node)
    tmp = str(scratch("gflow-bench-rec-"))
    rows = []
    for kind in args.kinds.split(","):
        msgs = payloads(kind)
        if not msgs:
            print(f"note: {CAVIAR} not found; the {kind} messages are skipped")
            continue
        rows.append(in_process(tmp, kind, msgs, args.n, args.compression))
        rows.append(over_zenoh(tmp, kind, args.n, sum(len(msgs[i % len(msgs)]) for i in range(args.n)),
                               args.compression))
    print(f"640x480 grey Frame messages (307 KB each), compression {args.compression}, chunks of 4 MiB")
    print(table(rows, ["path", "messages", "MB/s", "msgs/s", "recorded", "ratio", "recorder CPU us/msg",
                       "publisher CPU us/msg", "peak RSS MB recorder / publisher", "budget MB"]))
    burst(tmp, args.compression, args.repeat)


BUDGET_MB = 250


def burst(tmp: str, compression: str, repeat: int) -> None:
    """Frames as fast as the source reads them into a recorder process; peak RSS per process."""
    import psutil

    from pipeline.runtime.graph import parse_graph
    from pipeline.runtime.launcher import Launcher

    seq = CAVIAR
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
