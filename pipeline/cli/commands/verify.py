"""``gflow verify RECORDING.mcap [...]``: read every record of each recording and say whether it is intact."""

from __future__ import annotations

ORDER = 55

import argparse
import sys
import time
from pathlib import Path

#: seconds between two progress lines on stderr
PROGRESS_EVERY_S = 3.0


class _Progress:
    """``  verify: FILE  READ/SIZE MB, N messages`` on stderr, at most every PROGRESS_EVERY_S seconds."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.last = time.monotonic()

    def __call__(self, pos: int, size: int, messages: int) -> None:
        now = time.monotonic()
        if now - self.last >= PROGRESS_EVERY_S:
            self.last = now
            print(f"  verify: {self.path}  {pos / 1e6:.1f}/{size / 1e6:.1f} MB, {messages} messages", file=sys.stderr,
                  flush=True)


def _being_written() -> dict[Path, dict]:
    """The recordings running pipelines announce they are writing (as ``gflow clean`` spares them)."""
    from pipeline.runtime.running import running

    return {Path(str(i["recording"])).resolve(): i for i in running() if i.get("recording")}


def verify_line(path: str, busy: dict[Path, dict], quiet: bool) -> tuple[bool, str]:
    """(intact or being written, the line to print; "" for none) for one file."""
    from pipeline.recording.verify import verify

    r = verify(path, progress=None if quiet else _Progress(path))
    run = busy.get(Path(path).resolve())
    if run is not None:
        line = (f"{path}: IN PROGRESS: being written by {run.get('name') or run.get('stream')} (pid {run.get('pid')}); "
                f"{r.messages} messages in its complete chunks so far")
        return True, "" if quiet else line
    if r.ok:
        from pipeline.io.mcap_io import segments

        more = [s.name for s in segments(path)[1:]]  # a restarted recorder's files: each is checked on its own
        return True, "" if quiet else (f"{path}: OK: {r.messages} messages, {r.channels} channels, "
                                       f"{r.duration_s:.3f} seconds"
                                       + (f" (the recording goes on in {', '.join(more)})" if more else ""))
    from pipeline.recording.recover import salvageable

    n = salvageable(path).messages  # every intact chunk, before the damage and after it
    many = "them" if n == r.messages else f"{n} message{'s' * (n != 1)}"
    salvage = f"gflow recover {path} FIXED.mcap can salvage {many}" if n else "nothing to salvage"
    return False, (f"{path}: DAMAGED: {r.damage}; {r.messages} message{'s' * (r.messages != 1)} readable before it; "
                   f"{salvage}")


def cmd_verify(args) -> int:
    from pipeline.io.mcap_io import check_recording

    for path in args.files:  # a folder where a recording is named: a mistake in the command (exit 2), said as every
        if Path(path).is_dir():  # command says it, before any file is read (a missing or damaged file is an answer)
            check_recording(path)
    busy = _being_written()
    bad = 0
    for path in args.files:
        try:
            ok, line = verify_line(path, busy, args.quiet)
        except (FileNotFoundError, IsADirectoryError, ValueError) as e:  # missing, empty or not MCAP: one line
            size = Path(path).stat().st_size if Path(path).is_file() else -1
            why = f"{path} is empty (0 bytes), not an MCAP recording" if size == 0 else " ".join(str(e).split())
            print(f"gflow verify: error: {why}", file=sys.stderr)
            bad += 1
            continue
        except OSError as e:  # unreadable (permissions): name it
            print(f"gflow verify: error: {path}: {e.strerror or e}", file=sys.stderr)
            bad += 1
            continue
        if line:
            print(line, flush=True)
        bad += not ok
    if bad and len(args.files) > 1:
        print(f"gflow verify: {bad} of {len(args.files)} files damaged or unreadable", file=sys.stderr)
    return 1 if bad else 0


def register(sub) -> None:
    p = sub.add_parser("verify", help="read every record of recordings and say whether each is intact",
                       description="Reads every record of each MCAP file: decompresses every chunk and checks its "
                                   "CRC, the data-section and summary CRCs, the statistics and indexes against what "
                                   "the file holds, that every message's channel and schema exist and that every "
                                   "message decodes as its gflow type. One line per file: OK, DAMAGED (what, where, "
                                   "and how many messages gflow recover can salvage) or IN PROGRESS (a running "
                                   "pipeline is writing it). Exit 1 when any file is damaged or unreadable "
                                   "(missing, empty, not MCAP); 2 when a folder is given for a recording (nothing "
                                   "is read).",
                       epilog="examples:\n  gflow verify run.mcap\n  gflow verify recordings/*.mcap --quiet",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("files", nargs="+", metavar="RECORDING", help="MCAP recordings")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the damaged files (and no progress)")
    p.set_defaults(func=cmd_verify)
