"""A peer outside a run on its zenoh network (no run key), as a process: it finds the running
pipeline as the tools do (``pipeline.runtime.running``), listens on ``gflow/**`` until it sees an
estimate, and publishes ``count`` Estimate messages of its own on that topic, one every
``interval`` seconds, for frames 0, 1, 2, ... with a box far from the target.

    python tests/outsider_peer.py COUNT [INTERVAL]

It prints ``ready`` once its imports are done and it is about to look for the run (so a test can start the
run only then, and the outsider's own start-up does not race the run's frames), then ``published N on TOPIC``
and exits 0, or exits 1 when no run or no estimate came within 60 s.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import zenoh  # noqa: E402

from pipeline.runtime.running import running  # noqa: E402
from pipeline.runtime.transport import pack_attachment  # noqa: E402
from gflow_msgs.messages import Estimate, Header, NDArray, decode, encode  # noqa: E402

#: the outsider's box: nowhere near caviar1's pedestrian
BOX = (5.0, 5.0, 30.0, 79.0)


def main(count: int, interval: float) -> int:
    print("ready", flush=True)
    deadline = time.monotonic() + 60
    while not (found := [r for r in running() if r.get("kind") == "pipeline"]):
        if time.monotonic() > deadline:
            print("no pipeline running", flush=True)
            return 1
        time.sleep(0.05)
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    c.insert_json5("connect/endpoints", json.dumps(found[0]["endpoints"]))
    s = zenoh.open(c)
    heard: list = []

    def on(sample: zenoh.Sample) -> None:
        if str(sample.key_expr).endswith("/estimate") and not heard:
            heard.append((str(sample.key_expr), decode(sample.payload.to_bytes()).header))

    s.declare_subscriber("gflow/**", on)
    while not heard:
        if time.monotonic() > deadline:
            print("no estimate heard", flush=True)
            return 1
        time.sleep(0.01)
    key, h = heard[0]
    pub = s.declare_publisher(key)
    for seq in range(count):
        e = Estimate(header=Header(stream=h.stream, seq=seq, stamp_ns=h.stamp_ns), box=BOX, alpha=(0.0, 0.0, 0.0, 1.0),
                     k=0, mean=(0.0, 0.0, 0.0, 1.0), std=(0.0, 0.0, 0.0, 0.0), ess=1.0, n=1, log_evidence=0.0,
                     contour=NDArray.of(np.zeros((0, 2), np.float32)))
        pub.put(encode(e), attachment=pack_attachment(time.time_ns(), seq, "Estimate"))
        time.sleep(interval)
    time.sleep(0.3)
    print(f"published {count} on {key}", flush=True)
    s.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]), float(sys.argv[2]) if len(sys.argv) > 2 else 0.005))
