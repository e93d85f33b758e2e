"""Bytes on the wire of the demo graph placed on three hosts (network namespaces cam, edge, ops
and a zenoh router; tests/netns.py), in the default mode (each host's launcher is the host's
zenoh router: what arrives from another host comes once per host) against ``--mode client``
(every stage process a client of the central router: one copy per process).

    sudo python bench/bench_deployment.py [--frames 60]

Prints, per mode, the bytes each host received and sent on its link to the router (the veth's
counters), the wall time, and whether the boxes equal a one-host run's. Needs root and
``ip netns``.
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
from netns import Net, available  # noqa: E402

from pipeline.io.mcap_io import iter_records  # noqa: E402
from gflow_msgs.messages import decode  # noqa: E402

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


def _link_bytes(net: Net, host: str) -> tuple[int, int]:
    """(received, sent) by ``host`` on its link: the router side's tx and rx counters."""
    side = net.veth_router_side(host)
    vals = []
    for what in ("tx_bytes", "rx_bytes"):
        r = subprocess.run(["ip", "netns", "exec", net.router_ns, "cat", f"/sys/class/net/{side}/statistics/{what}"],
                           capture_output=True, text=True, check=True)
        vals.append(int(r.stdout))
    return vals[0], vals[1]


def _boxes(path: Path) -> dict:
    return {r.seq: decode(r.data).box for r in iter_records(path) if r.type == "Estimate"}


def run_mode(net: Net, tmp: Path, mode: str, frames: int, stream: str) -> tuple[dict, float, Path]:
    before = {h: _link_bytes(net, h) for h in net.hosts}
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    procs = {}
    t0 = time.monotonic()
    for host in ("ops", "edge", "cam"):
        d = tmp / f"{stream}-{host}"
        d.mkdir()
        args = [*GFLOW, "run", "demo_hosts", "--host", host, "--connect", net.router_endpoint(host), "--stream", stream,
                "--set", f"source.frames={frames}", "--set", "filter.particles=100", "--mode", mode]
        if host == "ops":
            args += ["--record", str(tmp / f"{stream}.mcap")]
        procs[host] = net.popen(host, args, env=dict(env, GFLOW_RUNTIME_DIR=str(d / "rt")), cwd=d,
                                stdout=subprocess.DEVNULL, stderr=open(d / "stderr.txt", "w"))
    for host, p in procs.items():
        if p.wait(300) != 0:
            raise SystemExit(f"{mode}: host {host} failed: {(tmp / f'{stream}-{host}' / 'stderr.txt').read_text()[-800:]}")
    secs = time.monotonic() - t0
    after = {h: _link_bytes(net, h) for h in net.hosts}
    return {h: (after[h][0] - before[h][0], after[h][1] - before[h][1]) for h in net.hosts}, secs, tmp / f"{stream}.mcap"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()
    why = available()
    if why:
        print(f"cannot run: {why}", file=sys.stderr)
        return 2
    tmp = scratch("gflow-bench-deploy-")
    base = tmp / "base.mcap"
    subprocess.run([*GFLOW, "run", "demo_hosts", "--inline", "--stream", "demo", "--set", f"source.frames={args.frames}",
                    "--set", "filter.particles=100", "--record", str(base)], check=True, capture_output=True,
                   env=dict(os.environ, PYTHONPATH=str(ROOT)), cwd=tmp)
    want = _boxes(base)
    net = Net(tag=f"{os.getpid() % 10000}b")
    rows = []
    try:
        net.up()
        net.start_router(env=dict(os.environ, PYTHONPATH=str(ROOT)))
        for mode, stream in (("peer", "demo"), ("client", "demo")):
            stream_dir = tmp / mode
            stream_dir.mkdir()
            moved, secs, rec = run_mode(net, stream_dir, mode, args.frames, stream)
            same = _boxes(rec) == want
            for h in net.hosts:
                rows.append([mode, h, f"{moved[h][0] / 1e6:.2f}", f"{moved[h][1] / 1e6:.2f}", f"{secs:.1f}",
                             "yes" if same else "NO"])
    finally:
        net.close()
    print(f"demo_hosts, {args.frames} frames of 320x240, 100 particles; bytes on each host's link to the router")
    print(table(rows, ["mode", "host", "received MB", "sent MB", "wall s", "boxes = one host"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
