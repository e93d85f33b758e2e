"""Salvage a recording whose writer was killed, or whose bytes were damaged (``gflow recover``).

A killed recorder leaves no summary or footer. Every chunk it flushed is complete on disk. Damage
(a disk's bad sector, a bad copy) spoils the records it hits and nothing else: MCAP frames every
record with its length, and each chunk is compressed and checked (CRC) on its own. The file is walked
by that framing (:mod:`pipeline.io.mcap_framing`), so a damaged chunk or metadata record is skipped,
said, and the walk goes on; a damaged frame is passed over to the next chunk the summary lists. Every
message of every intact chunk, with its channel, schema, times and sequence number, and every intact
metadata record are copied into a new, properly closed file. A channel whose definition was in a
damaged chunk is taken from the summary, which repeats every channel and schema.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Message, MessageIndex, Metadata, Schema
from mcap.stream_reader import CRCValidationError, breakup_chunk
from mcap.writer import CompressionType, Writer

from pipeline.io.mcap_framing import chunk_size_damage, framed_records, read_summary
from pipeline.io.mcap_io import TORN_END_ERRORS, check_recording
from pipeline.io.recording_files import create_beside, move_new

__all__ = ["recover", "salvageable", "RecoverResult", "Skipped"]

TORN = "it ends in the middle of a record: the writer was killed"
UNCLOSED = "it ends after a complete record, with no summary or footer: the writer was killed"


@dataclass
class Skipped:
    """A damaged part of the file that was left out: ``what`` says which and why; ``messages`` the messages
    it held, as the message indexes after a chunk list them (-1: not known), on ``topics``."""

    offset: int
    what: str
    messages: int = -1
    topics: set[str] = field(default_factory=set)

    def describe(self) -> str:
        held = ""
        if self.messages >= 0:
            on = f" on {', '.join(sorted(self.topics))}" if self.topics else ""
            held = f"; {self.messages} messages{on} lost"
        return self.what + held


@dataclass
class RecoverResult:
    messages: int
    channels: int
    metadata: int
    complete: bool  # nothing was left out: no damage and no torn end
    stopped_because: str  # why the walk ended before the file's end ("" when it read to the end)
    last_log_ns: int
    skipped: list[Skipped] = field(default_factory=list)
    orphans: int = 0  # messages on a channel defined nowhere readable: left out
    stated: int = -1  # the messages the file's summary says it holds (-1: no readable summary, or a damaged one)
    summary_damaged: bool = False  # the file's summary fails its CRC (the copy's is written anew)
    repaired: list[str] = field(default_factory=list)  # damaged frames read past by a chunk's own fields

    @property
    def torn_end(self) -> bool:
        """The file ends inside a record (its writer was killed), rather than at damage it cannot pass."""
        return self.stopped_because in (TORN, UNCLOSED)



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
            w = Writer(out, compression=CompressionType.LZ4)
            w.start(profile="", library="gflow recover")
            result = _copy(fin, src.stat().st_size, w)
            w.finish()
            out.flush()
            os.fsync(out.fileno())  # on disk before it takes the name: a crash leaves no empty FIXED
        if result.messages:
            move_new(tmp, fixed)
    finally:
        tmp.unlink(missing_ok=True)  # after move_new: gone already
    return result


def salvageable(path: str | Path) -> RecoverResult:
    """What :func:`recover` would copy out of ``path``, counted without writing anything."""
    src = check_recording(path)
    with open(src, "rb") as fin:
        return _copy(fin, src.stat().st_size, _Count())


class _Count:
    """A writer that only hands out ids (``salvageable``)."""

    def __init__(self) -> None:
        self.n = 0

    def register_schema(self, *a: Any) -> int:
        self.n += 1
        return self.n

    register_channel = register_schema

    def add_message(self, *a: Any, **k: Any) -> None:
        pass

    def add_metadata(self, *a: Any) -> None:
        pass


class _Copy:
    """The state of one copy: the ids the output gave the schemas and channels of the input."""

    def __init__(self, w: Any, summary_schemas: dict[int, Schema], summary_channels: dict[int, Channel]) -> None:
        self.w = w
        self.schemas: dict[int, int] = {}
        self.channels: dict[int, int] = {}
        self.topics: dict[int, str] = {}
        self.seen_schemas: dict[int, Schema] = {}
        self.summary_schemas, self.summary_channels = summary_schemas, summary_channels
        self.n = self.n_meta = self.orphans = 0
        self.last = 0

    def schema(self, rec: Schema) -> None:
        self.seen_schemas.setdefault(rec.id, rec)
        if rec.id not in self.schemas:
            self.schemas[rec.id] = self.w.register_schema(rec.name, rec.encoding, rec.data)

    def channel(self, rec: Channel) -> None:
        if rec.id in self.channels:
            return
        if rec.schema_id and rec.schema_id not in self.schemas:  # its schema was in a damaged part
            known = self.summary_schemas.get(rec.schema_id)
            if known is not None:
                self.schema(known)
        self.channels[rec.id] = self.w.register_channel(rec.topic, rec.message_encoding,
                                                        self.schemas.get(rec.schema_id, 0), dict(rec.metadata))
        self.topics[rec.id] = rec.topic

    def message(self, rec: Message) -> None:
        if rec.channel_id not in self.channels and rec.channel_id in self.summary_channels:
            self.channel(self.summary_channels[rec.channel_id])  # defined in a damaged chunk
        cid = self.channels.get(rec.channel_id)
        if cid is None:
            self.orphans += 1
            return
        self.w.add_message(cid, log_time=rec.log_time, data=rec.data, publish_time=rec.publish_time,
                           sequence=rec.sequence)
        self.n += 1
        self.last = max(self.last, rec.log_time)

    def chunk(self, rec: Chunk, where: str, offset: int) -> Skipped | None:
        """Copy the records of one chunk; a chunk whose CRC or compressed data is damaged is left out whole
        and returned, to be told."""
        try:
            inner = breakup_chunk(rec, validate_crc=True)
        except CRCValidationError as e:
            return Skipped(offset, f"{where}: its CRC does not match its contents (stated {e.expected:#010x}, "
                                   f"computed {e.actual:#010x})")
        except TORN_END_ERRORS as e:
            return Skipped(offset, f"{where}: its {rec.compression or 'uncompressed'} data cannot be read "
                                   f"({type(e).__name__}: {' '.join(str(e).split())})")
        for r in inner:
            self.record(r)
        return None

    def record(self, rec: Any) -> None:
        """Copy a schema, channel, message or metadata record (any other kind is not copied)."""
        if isinstance(rec, Schema):
            self.schema(rec)
        elif isinstance(rec, Channel):
            self.channel(rec)
        elif isinstance(rec, Message):
            self.message(rec)
        elif isinstance(rec, Metadata):
            self.metadata(rec)

    def metadata(self, rec: Metadata) -> None:
        self.w.add_metadata(rec.name, dict(rec.metadata))
        self.n_meta += 1


def _copy(fin: IO[bytes], size: int, w: Any) -> RecoverResult:
    """Every intact record of the MCAP file ``fin`` (``size`` bytes) handed to the writer ``w``."""
    summary = read_summary(fin, size)
    c = _Copy(w, summary.schemas, summary.channels)
    skipped: list[Skipped] = []
    repaired: list[str] = []
    lost: Skipped | None = None  # the chunk just skipped: the message indexes after it count its messages
    n_chunks = 0
    why = ""
    for fr in framed_records(fin, size):
        rec = fr.record
        if isinstance(rec, MessageIndex):
            if lost is not None:
                lost.messages = max(lost.messages, 0) + len(rec.records)
                if rec.channel_id in c.topics:
                    lost.topics.add(c.topics[rec.channel_id])
                elif rec.channel_id in summary.channels:
                    lost.topics.add(summary.channels[rec.channel_id].topic)
            continue
        lost = None
        if fr.torn:
            why = TORN
            break
        n_chunks += fr.opcode == Opcode.CHUNK
        if fr.damage and rec is not None:  # a damaged frame read past by the record's own fields
            repaired.append(f"chunk {n_chunks} at byte {fr.offset}: {fr.damage}")
        elif fr.damage:
            where = (f"chunk {n_chunks} at byte {fr.offset}" if fr.opcode == Opcode.CHUNK else
                     f"byte {fr.offset}" if fr.broken_frame else f"the {fr.kind} record at byte {fr.offset}")
            then = f"; the walk went on at the chunk at byte {fr.skipped_to}" if fr.skipped_to else ""
            skipped.append(Skipped(fr.offset, f"{where}: {fr.damage}{then}"))
            if fr.broken_frame and not fr.skipped_to:
                why = f"{where}: {fr.damage}, and the file has no summary to say where the next chunk starts"
                break
            lost = skipped[-1] if fr.opcode == Opcode.CHUNK else None
            continue
        if isinstance(rec, Chunk):
            sized, why = chunk_size_damage(rec)  # a damaged uncompressed size: its data's own (its CRC then checked)
            where = f"chunk {n_chunks} at byte {fr.offset}"
            if why and sized is not None:
                repaired.append(f"{where}: {why}, and it is read by its data's")
            lost = c.chunk(sized, where, fr.offset) if sized is not None else Skipped(fr.offset, f"{where}: {why}")
            if lost is not None:
                skipped.append(lost)
        elif isinstance(rec, DataEnd):  # the summary after it repeats what the data section said
            break
        else:
            c.record(rec)
    else:  # the walk came to the end of the file before the data section's end: it was never closed
        why = why or UNCLOSED
    return RecoverResult(messages=c.n, channels=len(c.channels), metadata=c.n_meta,
                         complete=not (why or skipped or repaired), stopped_because=why, last_log_ns=c.last,
                         skipped=skipped, orphans=c.orphans, stated=summary.messages if summary.intact else -1,
                         repaired=repaired, summary_damaged=not summary.intact)
