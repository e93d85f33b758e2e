"""``gflow recover BROKEN.mcap FIXED.mcap``: salvage a recording whose writer was killed or whose bytes were damaged."""

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
    damaged = "; ".join(k.describe() for k in r.skipped)
    if r.messages == 0:  # exit 1: nothing was saved; a FIXED of metadata alone is not left to look like a recording
        why = (f"no chunk is complete before where it stops ({r.stopped_because})" if r.stopped_because
               else f"no message is intact ({damaged})" if damaged else "it holds no message")
        print(f"gflow recover: error: nothing could be recovered from {args.broken}: {why}; {args.fixed} not written",
              file=sys.stderr)
        return 1
    of = f" of the {r.stated} its summary lists" if 0 <= r.stated != r.messages else ""
    state = ("every record before its summary was intact; its summary is damaged (its CRC does not match) and "
             "is written anew" if r.complete and r.summary_damaged else
             "the file was complete" if r.complete else
             f"the file ends early ({r.stopped_because})" if r.torn_end else
             f"the copy stopped early ({r.stopped_because})" if r.stopped_because else "the rest of the file was intact")
    print(f"recovered {r.messages} messages{of} on {r.channels} channels and {r.metadata} metadata records "
          f"into {args.fixed}; {state}")
    for k in r.skipped:  # each damaged part left out, and what it held
        print(f"  left out {k.describe()}")
    for what in r.repaired:
        print(f"  read despite damage: {what}")
    if r.orphans:
        print(f"  left out {r.orphans} messages on channels defined only in the damaged parts")
    return 0

def register(sub) -> None:
    p = sub.add_parser("recover", help="salvage every intact chunk of a recording whose writer was killed or whose "
                                       "bytes were damaged",
                       description="Copies every message of every intact chunk, with its channel, schema, times "
                                   "and sequence number, and the metadata, into a new, properly closed MCAP file. "
                                   "A damaged chunk or record is left out, named with its byte offset and the "
                                   "messages it held, and the copy goes on after it; a torn end (a killed writer) "
                                   "ends it.")
    p.add_argument("broken", help="the torn or damaged recording")
    p.add_argument("fixed", help="where to write the recovered recording (a new file)")
    p.set_defaults(func=cmd_recover)
