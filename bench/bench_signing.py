"""What a run key costs: signing and checking one sample (HMAC-SHA256 over key, sequence number,
time and payload) for the payload sizes of gflow's topics, and the synthetic demo end to end with
and without ``--run-key auto``.

    python bench/bench_signing.py [--demo-frames 120]

Prints microseconds per sample and the demo's wall times; writes nothing outside a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pipeline.runtime.security import Signer, load_run_key  # noqa: E402


def per_sample(size: int, repeat: int) -> tuple[float, float]:
    s = Signer(load_run_key("auto"))
    payload = os.urandom(size)
    t0 = time.perf_counter()
    for i in range(repeat):
        tag = s.tag("gflow/cam0/frames", i, 123, payload)
    t1 = time.perf_counter()
    for i in range(repeat):
        s.valid("gflow/cam0/frames", repeat - 1, 123, payload, tag)
    t2 = time.perf_counter()
    return (t1 - t0) / repeat * 1e6, (t2 - t1) / repeat * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo-frames", type=int, default=120, help="frames of the demo runs (0: skip them)")
    args = ap.parse_args()
    for name, size in (("control / estimate (200 B)", 200), ("particles 500x4 float64 (16 KB)", 16_000),
                       ("grey 320x240 frame (77 KB)", 76_800), ("colour 640x480 frame (922 KB)", 921_600)):
        sign, check = per_sample(size, 2000 if size < 100_000 else 300)
        print(f"{name:34s} sign {sign:8.1f} us   check {check:8.1f} us")
    if args.demo_frames:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from _m2cli import gflow  # noqa: E402

        with tempfile.TemporaryDirectory() as d:
            for extra in ([], ["--run-key", "auto"]):
                _, secs = gflow("demo", "--frames", str(args.demo_frames), "--record", str(Path(d) / "demo.mcap"),
                                *extra, quiet=True)
                print(f"demo {args.demo_frames} frames {' '.join(extra) or '(unsigned)':18s} {secs:6.2f} s wall")


if __name__ == "__main__":
    main()
