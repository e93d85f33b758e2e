"""``gflow recover BROKEN.mcap FIXED.mcap``: salvage a recording whose writer was killed."""

from __future__ import annotations

ORDER = 56

import os
import sys


def cmd_recover(args) -> int:
    from pipeline.recording.recover import recover
    from pipeline.cli.commands.common import CliError, check_outputs

    if os.path.abspath(args.broken) == os.path.abspath(args.fixed):
        raise CliError("FIXED must be a new file, not the broken recording itself")
    check_outputs(FIXED=args.fixed)
    from pipeline.io.recording_files import refuse_existing

    refuse_existing(args.fixed, "FIXED")  # a recording never overwrites a file
    from pipeline.io.mcap_io import check_recording

    check_recording(args.broken)  # a folder, missing or not MCAP: the user's mistake (exit 2), before any write
    try:
        r = recover(args.broken, args.fixed)  # written beside FIXED and moved there once closed
    except OSError as e:  # a full disk, say, midway: exit 1, as a run that went wrong; nothing is left of FIXED
        print(f"gflow recover: error: recovering {args.broken} failed: {e.strerror or e}; {args.fixed} not written",
              file=sys.stderr)
        return 1
    if r.messages == 0:  # exit 1: nothing was saved; a FIXED of metadata alone is not left to look like a recording
        why = (f"no chunk is complete before where it stops ({r.stopped_because})" if not r.complete
               else "it holds no message")
        print(f"gflow recover: error: nothing could be recovered from {args.broken}: {why}; {args.fixed} not written",
              file=sys.stderr)
        return 1
    state = "the file was complete" if r.complete else f"the file ends early ({r.stopped_because})"
    print(f"recovered {r.messages} messages on {r.channels} channels and {r.metadata} metadata records "
          f"into {args.fixed}; {state}")
    return 0

def register(sub) -> None:
    p = sub.add_parser("recover", help="salvage every complete chunk of a recording whose writer was killed",
                       description="Copies every message of every complete chunk, with its channel, schema, times "
                                   "and sequence number, and the metadata, into a new, properly closed MCAP file.")
    p.add_argument("broken", help="the truncated recording")
    p.add_argument("fixed", help="where to write the recovered recording (a new file)")
    p.set_defaults(func=cmd_recover)
