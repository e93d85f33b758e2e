"""End-to-end frames/s and CPU seconds per frame of ``gflow track`` as processes over zenoh
versus ``--inline``, for the chamfer tracker and the appearance tracker, side by
side in one run, and the peak memory (RSS) of every stage process.
One command: ``python bench/bench_pipeline.py``.

Runs on ../shared/data/caviar1 (or the synthetic scene when the data is absent). Frames/s
counts the frames tracked over the wall time from the first to the last estimate (start-up
excluded), from the recording's log times. CPU s/frame is the user + system time of the
whole run (start-up included) over the frames: for ``--inline`` this process's own, for
the processes each stage process's (sampled with psutil every 50 ms until it exits, so the
last < 50 ms of shutdown is not counted) and their sum. Start-up is the launcher's start to
the first estimate in the recording. RSS is what each stage's heartbeat reports, peak over
the run. ``--repeat N`` runs each mode N times (interleaved) and prints every run.
"""

from __future__ import annotations

import argparse
import resource
import sys
import threading
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

from pipeline.runtime.build import apply_defaults  # noqa: E402
from pipeline.runtime.graph import load_graph  # noqa: E402
from pipeline.runtime.inline import run_inline  # noqa: E402
from pipeline.runtime.launcher import Launcher  # noqa: E402
from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.recording.results import read_boxes  # noqa: E402
from pipeline.cli.commands.track import DEFAULT_TRACKER  # noqa: E402
from pipeline.runtime.transport import ZenohSettings, free_port  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def plan_for(tracker: str, particles: int | None):
    seq = DATA / "caviar1"
    if seq.is_dir():
        init = list(read_boxes(seq / "groundtruth.csv")[0])
        src = {"kind": "folder", "path": str(seq / "frames")}
        from pipeline.cli.trackers import appearance, chamfer

        # the overrides `gflow track --tracker T` gives (the particles go to the graph's tracker block)
        ns = argparse.Namespace(init=init, particles=particles, seed=0)
        graph, ov = (chamfer if tracker == "chamfer" else appearance).overrides(ns)
        ov["source"] = src
        return "caviar1", load_graph(graph, overrides=ov)
    print(f"note: {seq} not found; using the synthetic scene (chamfer graph)", file=sys.stderr)
    return "synthetic", apply_defaults(load_graph("demo", overrides={"source": {"frames": 300},
                                                                     "filter": {"particles": particles or 500}}))


def estimate_times(path: str) -> list[int]:
    return sorted(r.log_ns for r in iter_records(path) if r.type in ("Estimate", "PoseEstimate"))


def tracked_fps(t: list[int]) -> float:
    return (len(t) - 1) / ((t[-1] - t[0]) / 1e9)


class CpuSampler:
    """CPU time (user + system) of this process and of every child process, sampled every
    ``every`` s with the wall time (ns), until each exits: ``cpu_between(pid, t0, t1)``.

    The sampler runs in the measuring process (the launcher's, or the one --inline runs in),
    so it is kept cheap: the list of children (a scan of every process on the machine) is
    refreshed every ``rescan`` s only, and each known process's times are read from its own
    /proc file (measured with 6 children: a psutil children() scan every 20 ms took 170 ms of
    CPU a second, 17 % of one of the two cores the pipeline runs on, and the GIL of the
    --inline run; this one 28 ms a second)."""

    def __init__(self, every: float = 0.05, rescan: float = 0.25) -> None:
        self.cpu: dict[int, float] = {}
        self.samples: dict[int, list[tuple[int, float]]] = {}
        self.every = every
        self.rescan = rescan
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        me = psutil.Process()
        procs: dict[int, psutil.Process] = {me.pid: me}
        scanned = 0.0
        while not self._stop.is_set():
            if time.monotonic() - scanned > self.rescan:
                scanned = time.monotonic()
                try:
                    for c in me.children(recursive=True):
                        procs.setdefault(c.pid, c)
                except psutil.Error:
                    pass
            for pid, c in list(procs.items()):
                try:
                    t = c.cpu_times()
                except psutil.Error:
                    del procs[pid]
                    continue
                self.cpu[pid] = t.user + t.system
                self.samples.setdefault(pid, []).append((time.time_ns(), t.user + t.system))
            self._stop.wait(self.every)

    def cpu_between(self, pid: int, t0: int, t1: int) -> float:
        """CPU seconds ``pid`` used between wall times t0 and t1 (ns), from the samples around them."""
        s = self.samples.get(pid, [])
        if not s:
            return 0.0

        def at(t: int) -> float:
            for ts, c in s:
                if ts >= t:
                    return c
            return s[-1][1]
        return at(t1) - at(t0)

    def __enter__(self) -> "CpuSampler":
        self._t.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._t.join()


def run_once(tracker: str, particles: int | None, out: str, k: int) -> dict:
    name, plan = plan_for(tracker, particles)
    rec_i = f"{out}/{tracker}-inline-{k}.mcap"
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    with CpuSampler() as cs:
        run_inline(plan, recording=rec_i)
    wall_i = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu_i = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    t_i = estimate_times(rec_i)
    steady_i = cs.cpu_between(psutil.Process().pid, t_i[0], t_i[-1])
    name, plan = plan_for(tracker, particles)
    rec_p = f"{out}/{tracker}-processes-{k}.mcap"
    start_ns = time.time_ns()
    with CpuSampler() as cs:
        res = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=rec_p,
                       progress=False).run()
    assert res.ok, res.exits
    t_p = estimate_times(rec_p)
    per_stage = {n: sum(cs.cpu.get(pid, 0.0) for pid in pids) for n, pids in res.pids.items()}
    steady = {n: sum(cs.cpu_between(pid, t_p[0], t_p[-1]) for pid in pids) for n, pids in res.pids.items()}
    return {"seq": name, "n_i": len(t_i), "fps_i": tracked_fps(t_i), "wall_i": wall_i, "cpu_i": cpu_i,
            "steady_i": steady_i, "steady": steady, "n_p": len(t_p), "fps_p": tracked_fps(t_p), "wall_p": res.seconds,
            "startup_p": (t_p[0] - start_ns) / 1e9, "cpu_stage": per_stage, "rss": res.peak_rss_mb}


def cli_startup(out: str, runs: int) -> list[float]:
    """Seconds from starting ``gflow track`` (a new Python process, default tracker, processes)
    on caviar1 to the first estimate in its recording."""
    import subprocess

    seq = DATA / "caviar1"
    if not seq.is_dir():
        return []
    init = ",".join(f"{v:g}" for v in read_boxes(seq / "groundtruth.csv")[0])
    times = []
    for k in range(runs):
        rec = f"{out}/cli-{k}.mcap"
        t0 = time.time_ns()
        r = subprocess.run([sys.executable, "-m", "pipeline.cli.main", "track", str(seq), "--init", init, "--stop", "10",
                            "--record", rec, "--out", f"{out}/cli-{k}.csv", "-q"], capture_output=True, text=True)
        if r.returncode != 0:
            print(f"gflow track failed: {r.stderr.strip()[-300:]}", file=sys.stderr)
            continue
        times.append((estimate_times(rec)[0] - t0) / 1e9)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=None, help="default: each tracker's own (500 chamfer, 300 appearance)")
    ap.add_argument("--trackers", default="chamfer,appearance")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--out", default=None, help="keep the recordings in this folder (default: a temporary one, deleted)")
    args = ap.parse_args()
    out = str(scratch("gflow-bench-", keep=args.out))
    trackers = [t.strip() for t in args.trackers.split(",") if t.strip()]
    print(f"load before: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())} on {psutil.cpu_count()} cores")
    runs: dict[str, list[dict]] = {t: [] for t in trackers}
    for k in range(args.repeat):
        for t in trackers:
            runs[t].append(run_once(t, args.particles, out, k))
    rows = []
    for t in trackers:
        for k, r in enumerate(runs[t]):
            n = r["n_p"]
            steady_p = sum(r["steady"].values()) / (n - 1)
            steady_i = r["steady_i"] / (r["n_i"] - 1)
            total_p = sum(r["cpu_stage"].values()) / n
            rows.append([t, k, n, f"{r['fps_i']:.1f}", f"{r['fps_p']:.1f}", f"{r['fps_p'] / r['fps_i']:.2f}",
                         f"{1e3 * steady_i:.1f}", f"{1e3 * steady_p:.1f}", f"{steady_p / steady_i:.2f}",
                         f"{1e3 * r['cpu_i'] / r['n_i']:.1f}", f"{1e3 * total_p:.1f}", f"{r['startup_p']:.2f}"])
    print("caviar1 (or synthetic), processes over zenoh vs --inline. CPU ms/frame: 'tracking' from the first to "
          "the last estimate, 'whole run' with start-up and shutdown (processes: every stage summed)")
    print(table(rows, ["tracker", "run", "frames", "inline fps", "proc fps", "proc/inline",
                       "inline CPU ms/f tracking", "proc CPU ms/f tracking", "CPU proc/inline",
                       "inline CPU ms/f whole run", "proc CPU ms/f whole run", "proc start-up s"]))
    print()
    names = sorted({n for t in trackers for r in runs[t] for n in r["cpu_stage"]})
    rows = []
    for n in names:
        row = [n]
        for t in trackers:
            r = runs[t][-1]
            have = n in r["cpu_stage"]
            row += [f"{1e3 * r['steady'][n] / (r['n_p'] - 1):.1f}" if have else "-",
                    f"{r['cpu_stage'][n]:.2f}" if have else "-",
                    f"{r['rss'].get(n, float('nan')):.0f}" if have else "-"]
        rows.append(row)
    print("per stage process (last run): CPU ms per frame while tracking, CPU s over the whole run, peak RSS MB "
          "(budget 250)")
    print(table(rows, ["stage"] + [h for t in trackers for h in (f"{t} CPU ms/f", f"{t} CPU s", f"{t} RSS MB")]))
    starts = cli_startup(out, max(2, args.repeat))
    if starts:
        print(f"\nstart-up of `gflow track caviar1 --stop 10` (new process, {DEFAULT_TRACKER}, the default tracker, processes) to its first "
              f"estimate: {', '.join(f'{t:.2f}' for t in starts)} s")
    print(f"load after: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())}")


if __name__ == "__main__":
    main()
