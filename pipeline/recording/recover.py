"""Salvage a recording whose writer was killed (``gflow recover``).

A killed recorder leaves no summary or footer. Every chunk it flushed is complete on disk;
``mcap.stream_reader.StreamReader`` reads the records in order until the torn end. This copies every complete
message, with its channel, schema, times and sequence number, and the metadata records,
into a new, properly closed file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from mcap.exceptions import EndOfFile
from mcap.stream_reader import StreamReader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from pipeline.io.mcap_io import TORN_END_ERRORS, check_recording
from pipeline.io.recording_files import create_beside, move_new

__all__ = ["recover", "RecoverResult"]


@dataclass
class RecoverResult:
    messages: int
    channels: int
    metadata: int
    complete: bool
    stopped_because: str
    last_log_ns: int


def recover(broken: str | Path, fixed: str | Path) -> RecoverResult:
    """Copy every readable record of ``broken`` into the new file ``fixed``.

    ``fixed`` is written under a temporary name beside it and moved there once closed, never over a file
    that is there (:func:`pipeline.io.recording_files.move_new`), and only when a message was recovered
    (a file of metadata alone would be taken for a recording): an error midway (a full disk) raises with
    nothing left under either name.
    """
    src = check_recording(broken)  # a folder, missing, or not MCAP: said before anything is created
    if Path(fixed).resolve() == src.resolve():
        raise ValueError("write the recovered recording to a new file, not over the broken one")
    out, tmp = create_beside(fixed)
    try:
        with open(src, "rb") as fin, out:
            result = _copy(fin, out)
            out.flush()
            os.fsync(out.fileno())  # on disk before it takes the name: a crash leaves no empty FIXED
        if result.messages:
            move_new(tmp, fixed)
    finally:
        tmp.unlink(missing_ok=True)  # after move_new: gone already
    return result


def _copy(fin: IO[bytes], fout: IO[bytes]) -> RecoverResult:
    """Every complete record of the MCAP stream ``fin`` written to ``fout`` as a closed MCAP file."""
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    n = n_meta = 0
    last = 0
    why = ""
    complete = True
    w = Writer(fout, compression=CompressionType.LZ4)
    w.start(profile="", library="gflow recover")
    try:
        for rec in StreamReader(fin, validate_crcs=True).records:
            if isinstance(rec, Schema):
                if rec.id not in schemas:
                    schemas[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                if rec.id not in channels:
                    channels[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                          schemas.get(rec.schema_id, 0), dict(rec.metadata))
            elif isinstance(rec, Message):
                cid = channels.get(rec.channel_id)
                if cid is None:
                    continue
                w.add_message(cid, log_time=rec.log_time, data=rec.data, publish_time=rec.publish_time,
                              sequence=rec.sequence)
                n += 1
                last = max(last, rec.log_time)
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
                n_meta += 1
    except EndOfFile:  # the torn end: every record before it has been copied
        complete = False
        why = "it ends in the middle of a record: the writer was killed"
    except TORN_END_ERRORS as e:  # a corrupt record: keep what came before it
        complete = False
        why = f"a corrupt record ({type(e).__name__}: {e})"
    w.finish()
    return RecoverResult(messages=n, channels=len(channels), metadata=n_meta, complete=complete,
                         stopped_because=why, last_log_ns=last)
