"""``gflow clean [FOLDER] --keep N``: remove all but the newest N recordings of a folder."""

from __future__ import annotations

ORDER = 58

import argparse
import sys
from pathlib import Path


def _not_a_recording(path: Path) -> bool:
    """Whether ``path`` holds bytes that do not begin as an MCAP file's (its magic, ``\\x89MCAP0\\r\\n``). A torn
    or damaged recording begins as one and is a recording to clean; an empty file is a recorder's that wrote
    nothing, cleaned with the rest; a file cut inside the magic is one whose writer died at once."""
    from pipeline.io.mcap_writer import MAGIC as magic

    try:
        with open(path, "rb") as f:
            head = f.read(len(magic))
    except OSError:  # gone, or not readable: folder_recordings' count of it stands
        return False
    return not magic.startswith(head) if len(head) < len(magic) else head != magic


def cmd_clean(args) -> int:
    from pipeline.io.recording_files import StoredRecording, folder_recordings
    from pipeline.runtime.running import running
    from pipeline.cli.commands.common import CliError

    folder = Path(args.folder)
    if not folder.exists():  # a mistyped name: "not a folder" would have the user look at a file that is not there
        raise CliError(f"{folder} does not exist (give the folder of recordings to clean)")
    if not folder.is_dir():
        raise CliError(f"{folder} is not a folder")
    recs: list[StoredRecording] = []
    foreign: list[StoredRecording] = []
    for r in folder_recordings(folder):  # a file named .mcap that is not one holds something else: not ours to remove
        (foreign if _not_a_recording(r.path) else recs).append(r)
    if not recs:  # nothing to clean is not a fault (a cron job), but a folder of no recordings may be the wrong one
        below = sum(1 for _ in folder.glob("*/**/*.mcap"))
        print(f"{folder} holds no recordings (.mcap files); nothing removed"
              + (f" (its subfolders hold {below}: clean one of them)" if below else ""))
        _say_left_alone(foreign)
        return 0
    busy = {Path(str(i["recording"])).resolve() for i in running() if i.get("recording")}
    kept = recs[:args.keep]
    drop: list[StoredRecording] = []
    in_use: list[StoredRecording] = []
    for r in recs[args.keep:]:
        (in_use if r.path.resolve() in busy else drop).append(r)
    freed = sum(r.bytes for r in drop)
    if not args.dry_run:
        for r in drop:
            for f in r.files:
                f.unlink(missing_ok=True)
    verb = "would remove" if args.dry_run else "removed"
    print(f"{verb} {len(drop)} recording(s) ({freed / 1e6:.1f} MB) from {folder}; kept the newest {len(kept)} "
          f"({sum(r.bytes for r in kept) / 1e6:.1f} MB)"
          + (f" and {len(in_use)} still being written" if in_use else ""))
    if args.verbose_list:
        for r in drop:
            print(f"  {r.path} ({r.bytes / 1e6:.1f} MB{', ' + str(len(r.files)) + ' files' if len(r.files) > 1 else ''})",
                  file=sys.stderr)
    _say_left_alone(foreign)
    return 0


def _say_left_alone(foreign: list) -> None:
    if foreign:
        print(f"left alone: {', '.join(str(r.path) for r in foreign)} (named .mcap, but not MCAP files)",
              file=sys.stderr)


def register(sub) -> None:
    from pipeline.cli.commands.common import nonnegative_int

    p = sub.add_parser("clean", help="remove all but the newest N recordings of a folder (default recordings/)",
                       description="Removes the oldest recordings of a folder (each .mcap with its segment files "
                                   "NAME.partN.mcap), keeping the newest N and any a running pipeline is writing. "
                                   "Every run records every frame, a few hundred KB each; a run warns when the folder "
                                   "holds more than GFLOW_RECORDINGS_WARN_MB (default 2000; 0: never).",
                       epilog="examples:\n  gflow clean --keep 5 --dry-run   (what would go)\n"
                              "  gflow clean --keep 5\n  gflow clean runs/ --keep 0",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder", nargs="?", default="recordings", help="the folder of recordings (default recordings)")
    # a whole number >= 0, refused as parsed: before the folder is looked at
    p.add_argument("--keep", type=nonnegative_int, required=True, metavar="N",
                   help="how many of the newest recordings to keep")
    p.add_argument("-n", "--dry-run", action="store_true", help="say what would be removed, remove nothing")
    p.add_argument("--list", dest="verbose_list", action="store_true", help="name each recording removed")
    p.set_defaults(func=cmd_clean)
