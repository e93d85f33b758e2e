"""Start-up of short ``gflow`` commands: the wall and CPU time of a new process that prints ``--help``, says a
mistake in its command, or describes a small recording, and the imports of a stage process; the median of
``--runs`` runs of each, run one after another in turn (so a change of load touches every command alike).

Each command runs as the ``gflow`` console script beside this Python (``-c`` with the same entry point where
there is none), with ``PYTHONPATH`` set to the code measured, in a temporary folder removed at the end (with
the recording ``gflow info`` reads, made once by ``gflow demo --frames 8 --inline``, untimed). The CPU is
user + system of the process and of every process it started (this benchmark reaps them as a subreaper:
``gflow track`` forks its stage processes' zygote at once, and that zygote's imports are start-up too). Python
writes its bytecode beside the code it measures (``__pycache__``, ignored by git) in one untimed run of each
command first, so no run compiles it, whether or not PYTHONDONTWRITEBYTECODE is set here.

``--compare DIR`` runs the same commands on the code in DIR (another worktree or checkout, e.g. the base of a
change) alternately with this one, and prints both and the ratio of their CPU.

    python bench/bench_command_startup.py
    python bench/bench_command_startup.py --runs 9 --compare /path/to/base/checkout
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import checkout, scratch, table  # noqa: E402

#: label -> the arguments of ``gflow`` (None: the Python line below instead), and the exit status expected
COMMANDS: list[tuple[str, list[str] | None, str, int]] = [
    ("python -c pass (the interpreter: the floor)", None, "pass", 0),
    ("gflow --help", ["--help"], "", 0),
    ("gflow track --help", ["track", "--help"], "", 0),
    ("gflow track --init 1,2,3,4 (no --out: a usage mistake)", ["track", "--init", "1,2,3,4"], "", 2),
    ("gflow track /nonexistent --init 1,2,3,4 --out b.csv", ["track", "/nonexistent", "--init", "1,2,3,4", "--out",
                                                            "b.csv"], "", 2),
    ("gflow eval --gt x.csv --pred y.csv (no such files)", ["eval", "--gt", "x.csv", "--pred", "y.csv"], "", 2),
    ("gflow info demo.mcap (8 frames)", ["info", "demo.mcap"], "", 0),
    ("a stage process's imports (import pipeline.runtime.node)", None, "import pipeline.runtime.node", 0),
    ("the default tracker's stage (import stages.box_tracker, gflow_core.dcf.tracker)", None,
     "import stages.box_tracker, gflow_core.dcf.tracker", 0),
]

#: ``gflow ARGS`` where there is no console script: what it runs
ENTRY = "import sys; sys.argv[0] = 'gflow'; from pipeline.cli.main import main; sys.exit(main())"


def gflow_command() -> list[str]:
    script = Path(sys.executable).with_name("gflow")
    return [sys.executable, str(script)] if script.is_file() else [sys.executable, "-c", ENTRY]


def become_subreaper() -> bool:
    """Have the processes our commands leave behind (the zygote) re-parented to us, so their CPU is counted."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0) == 0  # PR_SET_CHILD_SUBREAPER
    except (OSError, AttributeError):
        return False


def reap(timeout: float = 10.0) -> None:
    """Wait for every child left (orphans re-parented to us: the zygote dies with the command), so
    RUSAGE_CHILDREN holds their CPU; one still there after ``timeout`` s is left."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            time.sleep(0.002)


def env_for(code: str) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=code)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # the untimed first run writes the bytecode; no timed run compiles
    return env


def run_once(argv: list[str], env: dict[str, str], cwd: Path, want: int) -> tuple[float, float]:
    """(wall s, CPU s) of one run of ``argv``, to the end of its output (as a test's subprocess.run waits)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(argv, env=env, cwd=cwd, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=120)
    wall = time.perf_counter() - t0
    reap()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != want:
        sys.exit(f"startup: {' '.join(argv[1:])} exited {r.returncode}, not {want}: {r.stderr.strip()[-400:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def make_recording(out: Path, code: str) -> None:
    r = subprocess.run(gflow_command() + ["demo", "--frames", "8", "--inline", "--record", "demo.mcap"],
                       env=env_for(code), cwd=out, capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        sys.exit(f"startup: gflow demo could not make the recording: {r.stderr.strip()[-400:]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=7, help="timed runs of each command (default 7; the median is shown)")
    ap.add_argument("--compare", metavar="DIR", help="another checkout to alternate with (e.g. the base)")
    args = ap.parse_args()
    if args.runs < 1:
        ap.error("--runs must be >= 1")
    codes = {"this": str(ROOT)} | ({"compare": str(checkout(ap, args.compare))} if args.compare else {})
    counted = become_subreaper()
    out = scratch("gflow-bench-startup-")
    make_recording(out, str(ROOT))
    load0 = os.getloadavg()
    gflow = gflow_command()
    times: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for label, words, line, want in COMMANDS:
        argv = gflow + words if words is not None else [sys.executable, "-c", line]
        for c, code in codes.items():
            run_once(argv, env_for(code), out, want)  # untimed: bytecode written, files in the page cache
        for _ in range(args.runs):
            for c, code in codes.items():
                times.setdefault((label, c), []).append(run_once(argv, env_for(code), out, want))
    load1 = os.getloadavg()
    header = ["command"]
    for c in codes:
        header += [f"{c}: wall s", f"{c}: CPU s"]
    if args.compare:
        header.append("CPU this / compare")
    rows = []
    for label, *_ in COMMANDS:
        row = [label]
        cpu = {}
        for c in codes:
            t = times[(label, c)]
            cpu[c] = statistics.median(x[1] for x in t)
            row += [f"{statistics.median(x[0] for x in t):.3f}", f"{cpu[c]:.3f}"]
        if args.compare:
            row.append(f"{cpu['this'] / cpu['compare']:.2f}" if cpu["compare"] > 0 else "-")
        rows.append(row)
    print(f"median of {args.runs} runs of each command; {os.cpu_count()} cores, load average {load0[0]:.2f} before, "
          f"{load1[0]:.2f} after; CPU: user + system, {'the zygote included' if counted else 'without orphans'}")
    for c, code in codes.items():
        print(f"  {c}: {code}")
    print(table(rows, header))
    shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
