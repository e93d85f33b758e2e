"""Rewrite the figure tables of the docs in place, each with the command that made it and the versions.

    python bench/make_tables.py                  # every table (the stress benchmark takes an hour or more)
    python bench/make_tables.py --only shared    # the trackers on the shared sequences (docs/accuracy.md)
    python bench/make_tables.py --only grey      # the same on grey versions of them (docs/accuracy.md)
    python bench/make_tables.py --only blur      # ... blurred, every 3rd frame (fast), half size (small)
    python bench/make_tables.py --list           # the tables, their pages and their commands

A table the docs keep sits in its page between ``<!-- figures: NAME -->`` and
``<!-- end figures: NAME -->``; everything between the two lines is written here: a line
saying when it was measured, with which command and on which versions (``gflow --version``),
then what the command printed. Edit the commands in ``TABLES`` below, never the figures in
the pages. ``tests/test_doc_figures.py`` re-runs part of the ``shared`` table and fails when a
figure differs from what the page says.

The commands run from the repository root with this Python (``python -m pipeline.cli``), on
``../shared/data``. The shared-sequence table compares with OpenCV's CSRT and KCF, which are in
``opencv-contrib-python-headless``, not in the project's OpenCV: run this script with the Python
of an environment that has it (``docs/accuracy.md``, "Benchmarking on your own data"); it
refuses to write a table without them. m2 runs with a model learned on caviar1 frames 0-149
(``M2_LEARN``), written to a temporary folder removed at the end.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from pipeline.runtime.instruction_sets import hold  # noqa: E402

hold()  # the kernels of the gflow commands this runs, so the versions line says what they ran with
from _util import scratch  # noqa: E402

#: the model m2 runs with: learned on caviar1 frames 0-149 ({m2} is the file)
M2_LEARN = ["learn", "m2", "../shared/data/caviar1", "--boxes", "../shared/data/caviar1/groundtruth.csv", "--frames",
            "0:150", "-K", "20", "--out", "{m2}", "-q"]
TRACKERS = "dcf,appearance,chamfer,m2,gflow"
#: the trackers of the stress table of every tracker (its run takes about two hours); the default's
#: own stress table ("stress-default") is made apart
STRESS_TRACKERS = "appearance,chamfer,m2,gflow"
#: the cases of that table, named so that a case added later gets a table of its own ("stress-distract",
#: "stress-confetti")
#: instead of another two hours of every case
STRESS_CASES = ("none,occlude-10,occlude-25,occlude-60,occlude-150,sweep-40,partial-33,partial-67,slide-60,"
                "roll-target-35,roll-camera-20,roll-camera-35,roll-camera-45,look,dark-40,blur-30,fast-2,fast-3,leave-40")


@dataclass(frozen=True)
class Figures:
    """One table of the docs: where it is, the command that makes it, and what of its output it keeps."""

    name: str
    page: str
    what: str
    argv: tuple[str, ...]  # gflow's arguments; "{m2}" is the m2 model
    keep_from: str = ""  # the output from the first line that starts with this (default: all of it)
    opencv: tuple[str, ...] = ()  # OpenCV trackers the table must have
    speed: bool = False  # a speed table: frames/s per tracker and sequence, from the JSON


TABLES = (
    Figures("shared", "docs/accuracy.md", "every tracker on every shared sequence, OpenCV's CSRT and KCF, the "
            "published trackers and a box that never moves",
            ("benchmark", "../shared/data", "--trackers", TRACKERS, "--m2-model", "{m2}", "--opencv", "csrt,kcf",
             "--inline", "--seed", "1", "--no-fps", "--markdown", "-q", "--plot", "docs/success-shared.png"),
            opencv=("csrt", "kcf")),
    Figures("grey", "docs/accuracy.md", "every tracker, OpenCV's CSRT and KCF and a box that never moves on grey "
            "versions of the shared sequences (--variant grey)",
            ("benchmark", "../shared/data", "--variant", "grey", "--trackers", TRACKERS, "--m2-model", "{m2}",
             "--opencv", "csrt,kcf", "--inline", "--seed", "1", "--no-fps", "--markdown", "-q"),
            opencv=("csrt", "kcf")),
    *(Figures(v, "docs/accuracy.md", f"every tracker, OpenCV's CSRT and KCF and a box that never moves on the {v} "
              f"variant of the shared sequences (--variant {v}: {what})",
              ("benchmark", "../shared/data", "--variant", v, "--trackers", TRACKERS, "--m2-model", "{m2}",
               "--opencv", "csrt,kcf", "--inline", "--seed", "1", "--no-fps", "--markdown", "-q"),
              opencv=("csrt", "kcf"))
      for v, what in (("blur", "a blurring camera"), ("fast", "every 3rd frame"), ("small", "half the size"),
                      ("fast+blur", "every 3rd frame of a blurring camera, fast motion with blur"),
                      ("noise", "a noisy camera in poor light, JPEG-compressed"))),
    Figures("stress", "docs/stress.md", "the stress benchmark over every shared sequence, every tracker and CSRT: "
            "cases got back per family and per sequence",
            ("benchmark", "../shared/data", "--stress", "--cases", STRESS_CASES, "--trackers", STRESS_TRACKERS,
             "--m2-model", "{m2}", "--opencv", "csrt", "--inline", "--seed", "1", "--markdown", "-q"),
            keep_from="### every tracker", opencv=("csrt",)),
    Figures("stress-distract", "docs/stress.md", "every tracker, CSRT and KCF where a copy of the target passes in front "
            "of it (the stress case distract-40), over every shared sequence",
            ("benchmark", "../shared/data", "--stress", "--cases", "distract", "--trackers", TRACKERS, "--m2-model",
             "{m2}", "--opencv", "csrt,kcf", "--inline", "--seed", "1", "--markdown", "-q"),
            keep_from="### every tracker", opencv=("csrt", "kcf")),
    Figures("stress-confetti", "docs/stress.md", "every tracker, CSRT and KCF where a shower of flakes falls in front of "
            "the target (the stress case confetti-40), over every shared sequence",
            ("benchmark", "../shared/data", "--stress", "--cases", "confetti", "--trackers", TRACKERS, "--m2-model",
             "{m2}", "--opencv", "csrt,kcf", "--inline", "--seed", "1", "--markdown", "-q"),
            keep_from="### every tracker", opencv=("csrt", "kcf")),
    Figures("stress-default", "docs/stress.md", "the stress benchmark over every shared sequence, the default tracker",
            ("benchmark", "../shared/data", "--stress", "--trackers", "dcf", "--opencv", "none", "--inline", "--seed",
             "1", "--markdown", "-q")),
    Figures("speed", "docs/performance.md", "frames/s of every tracker on real video, one process per stage",
            ("benchmark", "../shared/data", "--sequences", "caviar1,david_indoor,skating1", "--trackers", TRACKERS,
             "--m2-model", "{m2}", "--seed", "1", "--json", "-q"),
            speed=True),
)


def gflow(argv: list[str], capture: bool = True) -> str:
    """Run ``gflow ARGV`` from the repository root with this Python; its stdout (stderr passes through)."""
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", *argv], cwd=ROOT, text=True,
                       stdout=subprocess.PIPE if capture else None)
    if r.returncode != 0:
        raise SystemExit(f"make_tables: gflow {' '.join(argv)} failed (exit {r.returncode})")
    return r.stdout or ""


def shown(argv: tuple[str, ...] | list[str], m2: str = "caviar1-m2.npz") -> str:
    return "gflow " + " ".join(a.replace("{m2}", m2) for a in argv)


def check_opencv(fig: Figures) -> None:
    """The OpenCV trackers the table compares with are in this Python's OpenCV (else exit, saying how)."""
    from pipeline.evaluation.sequence_benchmark import opencv_tracker

    missing = [c for c in fig.opencv if opencv_tracker(c)[0] is None]
    if missing:
        raise SystemExit(f"make_tables: the {fig.name} table compares with OpenCV's {', '.join(missing).upper()}, which "
                         f"this Python's OpenCV lacks: run this script with the python of an environment with "
                         "opencv-contrib-python-headless (docs/accuracy.md, 'Benchmarking on your own data')")


def speed_table(res: dict) -> str:
    """Frames/s of every tracker per sequence, from ``gflow benchmark --json``."""
    seqs = res["sequences"]
    names = list(dict.fromkeys(r["tracker"] for r in res["rows"] if r["kind"] == "tracker"))
    fps = {(r["sequence"], r["tracker"]): r.get("fps") for r in res["rows"]}
    size = {r["sequence"]: r["frames"] for r in res["rows"] if r["kind"] == "baseline"}
    out = ["| tracker | " + " | ".join(f"{s} ({size.get(s, '?')} frames)" for s in seqs) + " |",
           "|" + "---|" * (len(seqs) + 1)]
    for n in names:
        out.append(f"| {n} | " + " | ".join("-" if fps.get((s, n)) is None else f"{fps[s, n]:.1f}" for s in seqs)
                   + " |")
    return "\n".join(out)


def measure(fig: Figures, m2: str) -> str:
    """Run the table's command; the block to write (without its marker lines)."""
    from pipeline.runtime.versions import version_text

    argv = [a.replace("{m2}", m2) for a in fig.argv]
    for opt in ("--plot", "--precision-plot"):
        if opt in argv:
            # the picture is this table's own, made again with it (gflow never writes over a picture)
            (ROOT / argv[argv.index(opt) + 1]).unlink(missing_ok=True)
    load0 = os.getloadavg()[0]
    t0, c0 = time.monotonic(), resource.getrusage(resource.RUSAGE_CHILDREN)
    out = gflow(argv)
    wall, c1 = time.monotonic() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    load1 = os.getloadavg()[0]
    if fig.speed:
        body = speed_table(json.loads(out))
    else:
        lines = out.rstrip().splitlines()
        # the trailer names the mode, seed and versions (the header below says so) and the folders
        # that are not sequences (avletters)
        while lines and (not lines[-1].strip() or lines[-1].startswith(("inline, seed", "processes, seed", "skipped "))):
            lines.pop()
        if fig.keep_from:
            start = next((i for i, ln in enumerate(lines) if ln.startswith(fig.keep_from)), None)
            if start is None:
                raise SystemExit(f"make_tables: the output of {shown(fig.argv)} has no line {fig.keep_from!r}")
            lines = lines[start:]
        body = "\n".join(lines)
    day = datetime.date.today().isoformat()
    head = (f"Measured on {day} by `python bench/make_tables.py --only {fig.name}`, which runs "
            f"`{shown(fig.argv)}`" + (f" (m2's model: `{shown(M2_LEARN)}`)" if "{m2}" in fig.argv else "")
            + f", on {version_text()}, {os.cpu_count()} cores; the run took {wall / 60:.1f} min of wall time"
            + (f" and {cpu / 60:.1f} min of CPU" if "--inline" in argv else "")  # stage processes are not all ours to time
            + f", load average {load0:.1f} before and {load1:.1f} after"
            + (f", at niceness {os.nice(0)}" if os.nice(0) else "") + ".")
    return head + "\n\n" + body


def marker(name: str) -> tuple[str, str]:
    return f"<!-- figures: {name} -->", f"<!-- end figures: {name} -->"


def write(fig: Figures, block: str) -> None:
    """Put ``block`` between the table's markers in its page."""
    page = ROOT / fig.page
    text = page.read_text()
    start, end = marker(fig.name)
    rx = re.compile(re.escape(start) + r"\n.*?" + re.escape(end), re.S)
    if not rx.search(text):
        raise SystemExit(f"make_tables: {fig.page} has no '{start}' ... '{end}' lines")
    page.write_text(rx.sub(lambda _: f"{start}\n{block}\n{end}", text, count=1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", metavar="NAME,...", help=f"only these tables ({', '.join(f.name for f in TABLES)})")
    ap.add_argument("--list", action="store_true", help="print the tables, their pages and commands, and exit")
    args = ap.parse_args(argv)
    if args.list:
        for f in TABLES:
            width = max(len(t.name) for t in TABLES)
            print(f"{f.name:{width}s} {f.page:22s} {f.what}\n{'':{width + 23}s}{shown(f.argv)}")
        return 0
    known = {f.name: f for f in TABLES}
    names = list(known) if not args.only else [n.strip() for n in args.only.split(",") if n.strip()]
    bad = [n for n in names if n not in known]
    if bad or not names:
        ap.error(f"--only: unknown table {bad[0] if bad else ''!r} (known: {', '.join(known)})")
    figs = [known[n] for n in names]
    for f in figs:  # before any work: the pages have their markers, OpenCV has what the tables compare with
        check_opencv(f)
        if marker(f.name)[0] not in (ROOT / f.page).read_text():
            raise SystemExit(f"make_tables: {f.page} has no '{marker(f.name)[0]}' line")
    m2 = str(scratch("gflow-make-tables-") / "caviar1-m2.npz")
    if any("{m2}" in f.argv for f in figs):
        gflow([a.replace("{m2}", m2) for a in M2_LEARN], capture=False)
    for f in figs:
        print(f"make_tables: {f.name}: {shown(f.argv)}", file=sys.stderr, flush=True)
        write(f, measure(f, m2))
        print(f"make_tables: {f.name}: written to {f.page}", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
