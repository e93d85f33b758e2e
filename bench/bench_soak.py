"""Soak: several pipelines at once, at a multiple of real time, for a long stretch; prints the
RSS of every stage process over time and the messages lost on reliable topics.

One command: ``python bench/bench_soak.py`` (defaults: 30 minutes of 25 frames/s video per
stream, played at 4x real time, 4 streams at once: 7.5 minutes of wall time). Use
``--minutes 2`` for a short check.

Each stream is the demo tracker (synthetic 320x240 scene, source -> preprocess -> proposal
<-> filter) launched as its own processes, with its own stream id. No recorder: half an hour
of four streams would be tens of GB on disk (the recorder's own throughput is measured by
bench_recorder.py). Instead this process subscribes to every stream's ``estimate`` topic and
counts, per stream, the frames with no estimate (lost), the repeated ones, the estimates that
coasted after the first (the scene has no blank frames: a coast means the filter gave up an
input that came late), and the stages' own counts of sequence gaps (``dropped``) and
rejected messages. Every topic of the graph is reliable, so every lost count should be 0.
RSS comes from each stage's heartbeat, sampled every ``--every`` seconds; the table shows,
per stage kind, the largest RSS over the streams.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import msgspec  # noqa: E402
from _util import table  # noqa: E402

from pipeline.runtime.build import apply_defaults  # noqa: E402
from pipeline.runtime.graph import load_graph  # noqa: E402
from pipeline.runtime.launcher import Launcher  # noqa: E402
from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session  # noqa: E402

STAGES = ("source", "preprocess", "proposal", "filter")


class _State(msgspec.Struct):
    state: str = "track"


_state = msgspec.msgpack.Decoder(_State)


def peek_state(payload: bytes) -> str:
    """An Estimate's state (init, track, coast) without decoding the rest."""
    try:
        return _state.decode(payload).state
    except msgspec.DecodeError:
        return "?"


def plan_for(i: int, frames: int, fps: float):
    plan = apply_defaults(load_graph("demo", overrides={
        "source": {"frames": frames, "realtime": True, "fps": fps, "scene_seed": i},
        "filter": {"particles": 300}}))
    for name in [n for n in plan.stages if n not in STAGES]:  # no render, no recorder
        del plan.stages[name]
    plan.stream = f"soak{i}"
    for s in plan.stages.values():  # topics follow the stream id
        s.inputs = {p: t.replace("gflow/demo/", f"gflow/{plan.stream}/") for p, t in s.inputs.items()}
        s.outputs = {p: t.replace("gflow/demo/", f"gflow/{plan.stream}/") for p, t in s.outputs.items()}
    return plan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0, help="minutes of video per stream (default 30)")
    ap.add_argument("--speed", type=float, default=4.0, help="multiple of real time (default 4)")
    ap.add_argument("--streams", type=int, default=4, help="pipelines at once (default 4)")
    ap.add_argument("--fps", type=float, default=25.0, help="frame rate of the video (default 25)")
    ap.add_argument("--every", type=float, default=30.0, help="seconds between RSS samples (default 30)")
    args = ap.parse_args()
    frames = int(args.minutes * 60 * args.fps)
    play_fps = args.fps * args.speed
    print(f"{args.streams} streams x {frames} frames at {play_fps:g} frames/s "
          f"(about {frames / play_fps / 60:.1f} min of wall time)")

    seen: list[dict[int, int]] = [dict() for _ in range(args.streams)]
    coasted = [0] * args.streams  # the synthetic scene has no blank frames: a coast means an input was given up
    launchers, results, threads = [], [None] * args.streams, []
    for i in range(args.streams):
        plan = plan_for(i, frames, play_fps)
        port = free_port()
        la = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)), recording=None, progress=False,
                      stall_timeout=60.0)
        launchers.append((la, port))

        def run(i=i, la=la) -> None:
            results[i] = la.run()

        threads.append(threading.Thread(target=run, daemon=True))
    sessions = []
    for i, (la, port) in enumerate(launchers):
        s = open_session(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",)))
        sessions.append(s)

        def count(key, payload, pub_ns, seq, type_name, i=i) -> None:
            if type_name == "Estimate":  # not the end of stream
                seen[i][seq] = seen[i].get(seq, 0) + 1
                if peek_state(payload) != "track":
                    coasted[i] += 1

        Bus(s).subscribe(f"gflow/soak{i}/estimate", count, with_type=True)
    for th in threads:
        th.start()
    t0 = time.monotonic()
    rows = []
    next_sample = t0 + min(args.every, 5.0)
    while any(th.is_alive() for th in threads):
        time.sleep(0.2)
        now = time.monotonic()
        if now >= next_sample:
            next_sample = now + args.every
            rss = {k: max((la.status[k].rss_mb for la, _ in launchers if k in la.status), default=0.0)
                   for k in STAGES}
            done = sum(len(x) for x in seen)
            rows.append([f"{now - t0:.0f}", done, *(f"{rss[k]:.0f}" for k in STAGES)])
            print(f"  t={now - t0:6.0f} s  estimates {done:7d}  max RSS MB " +
                  "  ".join(f"{k} {rss[k]:.0f}" for k in STAGES), flush=True)
    wall = time.monotonic() - t0
    time.sleep(0.5)  # the last estimates
    for s in sessions:
        s.close()
    print()
    print("RSS over time (MB, the largest over the streams):")
    print(table(rows, ["t (s)", "estimates", *STAGES]))
    print()
    out = []
    for i, r in enumerate(results):
        got = seen[i]
        lost = sum(1 for f in range(frames) if f not in got)
        repeated = sum(n - 1 for n in got.values() if n > 1)
        dropped = sum(sum(st.dropped.values()) for st in r.status.values()) if r else -1
        rejected = sum(sum(st.rejected.values()) for st in r.status.values()) if r else -1
        peak = max(r.peak_rss_mb.values()) if r and r.peak_rss_mb else 0.0
        out.append([f"soak{i}", "yes" if r and r.ok else "NO", frames, len(got), lost, repeated, max(0, coasted[i] - 1),
                    dropped, rejected, f"{peak:.0f}"])
    print(table(out, ["stream", "ok", "frames", "estimates", "lost", "repeated", "coasted", "seq gaps", "rejected",
                      "peak RSS MB"]))
    achieved = sum(len(x) for x in seen) / args.streams / wall
    print(f"\nwall time {wall:.0f} s; {achieved:.1f} frames/s per stream achieved (asked: {play_fps:g}); "
          f"lost estimates in total: {sum(r[4] for r in out)}")


if __name__ == "__main__":
    main()
