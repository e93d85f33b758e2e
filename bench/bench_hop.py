"""Per-hop latency and throughput between two processes over zenoh, next to an
in-process hand-off. One command: ``python bench/bench_hop.py``.

For 320x240 and 640x480 grey frames (as gflow Frame messages, msgpack-encoded):

* latency: the publisher sends N frames at a steady rate; the subscriber (another
  process) takes ``receive time - publish time`` from the sample's attachment (same host,
  same clock). Reported: p50 and p99, and the count received (loss).
* throughput: the publisher sends as fast as congestion control BLOCK lets it; reported:
  frames/s and MB/s at the subscriber, and the count received.
* in-process: the same payload handed between two threads through a queue.
* each zenoh row is repeated with zenoh's shared-memory transport on and off.

On an idle machine the hop is slower than on a busy one (measured here: about 450 us
against about 200 us p50 for 640x480); waking an idle core is the likely cost, not shown.
"""

from __future__ import annotations

import argparse
import json
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import pct, table  # noqa: E402

SUB = r"""
import sys, json, time, queue
sys.path.insert(0, sys.argv[3])
from pipeline.runtime.transport import Bus, ZenohSettings, open_session
from stages.messages import decode
n_expect, endpoint = int(sys.argv[1]), sys.argv[2]
s = open_session(ZenohSettings(listen=(endpoint,), shm=sys.argv[4] == "1"))
q = queue.SimpleQueue()
Bus(s).subscribe("gflow/bench/**", lambda k, p, ns, seq: q.put((time.time_ns(), ns, len(p), k, p)))
print("ready", flush=True)
lat, n, nbytes, t_first, t_last, decoded = [], 0, 0, None, None, 0
while True:
    try:
        t, ns, size, k, p = q.get(timeout=10)
    except queue.Empty:
        break
    if k.endswith("/stop"):
        break
    if k.endswith("/lat"):
        lat.append((t - ns) / 1e3)
        decode(p); decoded += 1
    elif k.endswith("/thr"):
        n += 1; nbytes += size
        t_first = t if t_first is None else t_first; t_last = t
print(json.dumps({"lat_us": lat, "thr_n": n, "thr_bytes": nbytes, "thr_s": (t_last - t_first) / 1e9 if n > 1 else 0}), flush=True)
s.close()
"""


def frame_payload(w: int, h: int) -> bytes:
    from stages.messages import Frame, Header, NDArray, encode

    img = np.random.default_rng(0).integers(0, 255, (h, w), dtype=np.uint8)
    return encode(Frame(Header("bench", 0, 0), NDArray.of(img)))


def zenoh_hop(w: int, h: int, n_lat: int, n_thr: int, rate: float, shm: bool = True) -> dict:
    from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session

    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    root = str(Path(__file__).resolve().parent.parent)
    sub = subprocess.Popen([sys.executable, "-c", SUB, str(n_lat + n_thr), ep, root, "1" if shm else "0"],
                           stdout=subprocess.PIPE, text=True)
    assert sub.stdout.readline().strip() == "ready"
    s = open_session(ZenohSettings(connect=(ep,), shm=shm))
    bus = Bus(s)
    payload = frame_payload(w, h)
    time.sleep(1.0)  # let the subscriber's declaration arrive
    for i in range(20):  # warm-up (shared-memory pool, routes)
        bus.publish("gflow/bench/warm", payload, i)
    time.sleep(0.2)
    period = 1.0 / rate
    t0 = time.perf_counter()
    for i in range(n_lat):
        due = t0 + i * period
        while time.perf_counter() < due:
            time.sleep(max(0.0, due - time.perf_counter() - 0.0005))
        bus.publish("gflow/bench/lat", payload, i)
    time.sleep(0.3)
    for i in range(n_thr):
        bus.publish("gflow/bench/thr", payload, i)
    bus.publish("gflow/bench/stop", b"", 0)
    out = json.loads(sub.stdout.readline())
    sub.wait(30)
    s.close()
    return {"payload": len(payload), **out}


def inproc_hop(w: int, h: int, n: int) -> list[float]:
    payload = frame_payload(w, h)
    q: queue.SimpleQueue = queue.SimpleQueue()
    lat: list[float] = []

    def consumer() -> None:
        for _ in range(n):
            t_pub, p = q.get()
            lat.append((time.perf_counter_ns() - t_pub) / 1e3)

    th = threading.Thread(target=consumer)
    th.start()
    for _ in range(n):
        q.put((time.perf_counter_ns(), payload))
        time.sleep(0.002)
    th.join()
    return lat


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1000, help="latency samples per size (default 1000)")
    ap.add_argument("--throughput", type=int, default=2000, help="frames in the throughput burst (default 2000)")
    ap.add_argument("--rate", type=float, default=200.0, help="latency send rate, Hz (default 200)")
    args = ap.parse_args()
    rows = []
    for (w, h), shm in (((320, 240), True), ((640, 480), True), ((320, 240), False), ((640, 480), False)):
        z = zenoh_hop(w, h, args.n, args.throughput, args.rate, shm)
        ip = inproc_hop(w, h, args.n)
        lat = z["lat_us"]
        rows.append([f"{w}x{h} grey", "on" if shm else "off", z["payload"], f"{pct(lat, 50):.0f}", f"{pct(lat, 99):.0f}",
                     f"{len(lat)}/{args.n}", f"{z['thr_n'] / z['thr_s']:.0f}" if z["thr_s"] else "-",
                     f"{z['thr_bytes'] / z['thr_s'] / 1e6:.0f}" if z["thr_s"] else "-",
                     f"{z['thr_n']}/{args.throughput}", f"{pct(ip, 50):.0f}", f"{pct(ip, 99):.0f}"])
    print("zenoh hop between two processes (peer mode, loopback; reliable, BLOCK); shm = zenoh shared memory")
    print(table(rows, ["frame", "shm", "bytes", "p50 us", "p99 us", "latency recv", "thr fps", "thr MB/s", "thr recv",
                       "in-proc p50 us", "in-proc p99 us"]))


if __name__ == "__main__":
    main()
