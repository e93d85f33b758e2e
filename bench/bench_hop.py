"""One hop of a frame between two processes, by every way gflow could move it, side by
side in one run. One command: ``python bench/bench_hop.py``.

For 320x240 and 640x480 grey frames, each way is measured paced at 25 frames/s (a camera)
and in a burst (as fast as the sender can go, reliable delivery):

* ``in-process``: a bytes object handed between two threads through a queue (no copy).
* ``mp shm + pipe``: the floor for two processes: the sender copies the frame into a
  ``multiprocessing.shared_memory`` ring of 16 slots and writes (slot, seq, time) to a pipe;
  the receiver wakes on the pipe and copies the frame out (no flow control: the burst
  trusts the ring to be deep enough, which it is as long as the receiver keeps up).
* ``zenoh bytes``: raw zenoh, ``put`` of the frame bytes with an 8-byte time attachment;
  the receiver's callback copies the payload out.
* ``zenoh shm provider``: as above, but the sender writes the frame into a buffer from
  zenoh's ``ShmProvider`` and publishes that (zenoh's Python shared-memory API).
* ``gflow``: gflow's full path: encode a ``Frame`` message, ``Bus.publish`` (reliable,
  BLOCK), ``Bus.subscribe`` on the receiver, the hand-over to its main thread and
  ``decode`` back to an ndarray; both ends tune malloc as stage processes do
  (``pipeline/runtime/memory.py``).

Latency is receive time - send time (one host, one clock): p50 and p99 in microseconds.
Burst throughput is frames/s at the receiver, first to last frame. CPU is the receiver
process's run time (every thread, from /proc schedstat) per frame over the paced run,
from its "ready" to its last frame: wake-ups and zenoh's own threads included.
Prints the load average next to the figures: the machine may be shared.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import pct, table  # noqa: E402

MODES = ("in-process", "mp shm + pipe", "zenoh bytes", "zenoh shm provider", "gflow")
SLOTS = 16
_REC = struct.Struct("<qqq")  # slot, seq, send time ns


def image(w: int, h: int) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 255, (h, w), dtype=np.uint8)


# -- receiver (a child process: ``bench_hop.py --receiver MODE N ...``) --------------------------
def receiver(mode: str, n: int, arg: str, nbytes: int) -> None:
    """Receive ``n`` frames by ``mode``, then print the receive-minus-send latencies (us),
    the first and last receive times and this process's CPU seconds as one JSON line."""
    lat: list[float] = []
    times: list[int] = []

    def cpu() -> float:  # every thread's run time from the scheduler, in ns resolution
        total = 0
        for tid in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{tid}/schedstat") as f:
                    total += int(f.read().split()[0])
            except OSError:
                pass
        return total / 1e9

    def report(c0: float) -> None:
        print(json.dumps({"lat": lat, "t0": times[0] if times else 0, "t1": times[-1] if times else 0,
                          "cpu": cpu() - c0}), flush=True)

    if mode == "mp shm + pipe":
        from multiprocessing import shared_memory

        from multiprocessing import resource_tracker

        shm = shared_memory.SharedMemory(name=arg)
        resource_tracker.unregister(shm._name, "shared_memory")  # the sender owns (and unlinks) it
        fd = int(os.environ["BENCH_HOP_FD"])
        buf = np.ndarray((SLOTS, nbytes), np.uint8, shm.buf)
        print("ready", flush=True)
        c0 = cpu()
        pending = b""
        while len(lat) < n:
            pending += os.read(fd, 4096)
            while len(pending) >= _REC.size:
                slot, seq, sent = _REC.unpack_from(pending)
                pending = pending[_REC.size:]
                frame = buf[slot].copy()  # noqa: F841  (the frame, out of the shared ring)
                t = time.time_ns()
                lat.append((t - sent) / 1e3)
                times.append(t)
        del buf
        shm.close()
        report(c0)
        return

    import zenoh

    from pipeline.runtime.transport import Bus, ZenohSettings, open_session
    from gflow_msgs.messages import decode

    if mode == "gflow":  # as every stage process does (pipeline/runtime/node.py)
        from pipeline.runtime.memory import keep_freed_memory

        keep_freed_memory()
    s = open_session(ZenohSettings(listen=(arg,)))
    if mode == "gflow":
        q: queue.SimpleQueue = queue.SimpleQueue()
        Bus(s).subscribe("bench/hop", lambda k, p, ns, seq: q.put(p))
        print("ready", flush=True)
        c0 = cpu()
        while len(lat) < n:
            msg = decode(q.get())
            img = msg.image.array()  # noqa: F841
            t = time.time_ns()
            if msg.header.stamp_ns == 0:
                continue  # warm-up
            lat.append((t - msg.header.stamp_ns) / 1e3)
            times.append(t)
    else:
        done = threading.Event()

        def cb(sample: zenoh.Sample) -> None:
            data = sample.payload.to_bytes()  # noqa: F841
            t = time.time_ns()
            sent = struct.unpack("<q", sample.attachment.to_bytes())[0]
            if sent == 0:
                return
            lat.append((t - sent) / 1e3)
            times.append(t)
            if len(lat) >= n:
                done.set()

        sub = s.declare_subscriber("bench/hop", cb)  # noqa: F841
        print("ready", flush=True)
        c0 = cpu()
        done.wait()
    report(c0)
    s.close()


# -- sender ---------------------------------------------------------------------------------------
def _pace(i: int, t0: float, period: float) -> None:
    if period <= 0:
        return
    due = t0 + i * period
    while True:
        d = due - time.perf_counter()
        if d <= 0:
            return
        time.sleep(d if d > 0.002 else 0)


def hop(mode: str, img: np.ndarray, n: int, fps: float) -> dict:
    """Send ``n`` frames by ``mode`` at ``fps`` (0: as fast as possible); the receiver's figures."""
    period = 1.0 / fps if fps > 0 else 0.0
    if mode == "in-process":
        q: queue.SimpleQueue = queue.SimpleQueue()
        lat: list[float] = []
        times: list[int] = []

        def consumer() -> None:
            for _ in range(n):
                sent, p = q.get()
                t = time.time_ns()
                lat.append((t - sent) / 1e3)
                times.append(t)

        th = threading.Thread(target=consumer)
        th.start()
        payload = img.tobytes()
        t0 = time.perf_counter()
        for i in range(n):
            _pace(i, t0, period)
            q.put((time.time_ns(), payload))
        th.join()
        return {"lat": lat, "t0": times[0], "t1": times[-1], "cpu": float("nan")}

    cmd = [sys.executable, str(Path(__file__).resolve()), "--receiver", mode, str(n)]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if mode == "mp shm + pipe":
        from multiprocessing import shared_memory

        shm = shared_memory.SharedMemory(create=True, size=SLOTS * img.nbytes)
        r, w = os.pipe()
        env["BENCH_HOP_FD"] = str(r)
        sub = subprocess.Popen(cmd + [shm.name, str(img.nbytes)], stdout=subprocess.PIPE, text=True, env=env,
                               pass_fds=(r,))
        os.close(r)
        try:
            assert sub.stdout.readline().strip() == "ready"
            ring = np.ndarray((SLOTS, img.nbytes), np.uint8, shm.buf)
            flat = img.reshape(-1)
            t0 = time.perf_counter()
            for i in range(n):
                _pace(i, t0, period)
                sent = time.time_ns()
                ring[i % SLOTS] = flat
                os.write(w, _REC.pack(i % SLOTS, i, sent))
            out = json.loads(sub.stdout.readline())
            sub.wait(30)
            del ring
        finally:
            os.close(w)
            shm.close()
            shm.unlink()
        return out

    from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session
    from gflow_msgs.messages import Frame, Header, NDArray, encode

    ep = f"tcp/127.0.0.1:{free_port()}"
    sub = subprocess.Popen(cmd + [ep, str(img.nbytes)], stdout=subprocess.PIPE, text=True, env=env)
    s = None
    try:
        assert sub.stdout.readline().strip() == "ready"
        s = open_session(ZenohSettings(connect=(ep,)))
        pub = s.declare_publisher("bench/hop", congestion_control=__import__("zenoh").CongestionControl.BLOCK)
        bus = Bus(s)
        provider = None
        if mode == "zenoh shm provider":
            from zenoh.shm import BlockOn, GarbageCollect, ShmProvider

            provider = ShmProvider.default_backend(32 * 2**20)
            policy = BlockOn(GarbageCollect())
        if mode == "gflow":
            from pipeline.runtime.memory import keep_freed_memory

            keep_freed_memory()
        payload = img.tobytes()
        matched = time.monotonic() + 10
        while not pub.matching_status.matching and time.monotonic() < matched:
            time.sleep(0.01)

        def send(sent: int) -> None:
            if mode == "gflow":
                bus.publish("bench/hop", encode(Frame(Header("bench", 0, sent), NDArray.of(img))), 0)
            elif provider is not None:
                buf = provider.alloc(len(payload), policy)
                buf[:] = payload
                pub.put(buf, attachment=struct.pack("<q", sent))
            else:
                pub.put(payload, attachment=struct.pack("<q", sent))

        for _ in range(5):  # warm-up (routes, shared-memory pools): stamped 0, not counted
            send(0)
        time.sleep(0.2)
        t0 = time.perf_counter()
        for i in range(n):
            _pace(i, t0, period)
            send(time.time_ns())
        out = json.loads(sub.stdout.readline())
        sub.wait(30)
        return out
    finally:
        if sub.poll() is None:
            sub.kill()
        if s is not None:
            s.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--paced", type=int, default=125, help="frames sent at 25 fps per way and size (default 125: 5 s)")
    ap.add_argument("--burst", type=int, default=1000, help="frames in the burst (default 1000)")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--sizes", default="320x240,640x480")
    ap.add_argument("--receiver", nargs=4, metavar=("MODE", "N", "ARG", "NBYTES"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.receiver:
        mode, n, arg, nb = args.receiver
        receiver(mode, int(n), arg, int(nb))
        return
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    print(f"load before: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())} on {psutil.cpu_count()} cores")
    rows = []
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.split("x"))
        img = image(w, h)
        for mode in modes:
            a = hop(mode, img, args.paced, 25.0)
            b = hop(mode, img, args.burst, 0.0)
            fps = (len(b["lat"]) - 1) / ((b["t1"] - b["t0"]) / 1e9) if len(b["lat"]) > 1 else float("nan")
            cpu = a["cpu"] / len(a["lat"]) * 1e6 if a["lat"] else float("nan")
            rows.append([f"{w}x{h} grey", mode, f"{pct(a['lat'], 50):.0f}", f"{pct(a['lat'], 99):.0f}",
                         f"{len(a['lat'])}/{args.paced}", f"{pct(b['lat'], 50):.0f}", f"{pct(b['lat'], 99):.0f}",
                         f"{fps:.0f}", f"{len(b['lat'])}/{args.burst}", "-" if cpu != cpu else f"{cpu:.0f}"])
    print("one hop, sender -> receiver process on one host (zenoh: peer mode, loopback, reliable, BLOCK)")
    print(table(rows, ["frame", "way", "25 fps p50 us", "25 fps p99 us", "received", "burst p50 us", "burst p99 us",
                       "burst fps", "received", "receiver CPU us/frame (25 fps)"]))
    print(f"load after: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())}")


if __name__ == "__main__":
    main()
