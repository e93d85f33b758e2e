"""Check a recording from end to end (``gflow verify``).

:func:`verify` reads every record of an MCAP file in order with ``mcap.stream_reader.StreamReader``
(chunks kept whole, so each is located by its byte offset) and checks, stopping at the first fault:

* every record's opcode is one MCAP defines, and every chunk's record length is the one its fields
  take (the reader goes by the fields; a reader that seeks by the length would fail);
* every chunk decompresses and matches its CRC (where the file has one), and its messages' log
  times lie within the times the chunk states;
* the data-section CRC (where the file has one), checked by the reader at the data end;
* every channel's schema and every message's channel are defined before they are used;
* every message decodes with the msgspec type of its schema (``gflow.Frame`` ->
  :class:`gflow_msgs.messages.Frame`, the Foxglove JSON schemas -> their types); a protobuf schema
  (a ``gflow foxglove`` copy) is decoded with its own FileDescriptorSet where google.protobuf is
  installed; a schema gflow does not know is not decoded;
* the message indexes after each chunk count that chunk's messages per channel;
* the summary: its CRC, the footer's summary offset, the statistics (counts and times), the
  chunk indexes (offset, length, sizes, times of every chunk, and no other) and the metadata
  indexes against what the data section holds; the closing magic and nothing after it.

A file that ends inside a record (a killed writer, or one still writing) has no summary: it is
reported as torn, with the number of messages of its complete chunks. A record that fails to parse is
read again by its framing alone (:mod:`pipeline.io.mcap_framing`), to tell damaged contents (the
records after it can still be read) from a damaged length. ``gflow recover`` copies every intact chunk,
after the damage too (:func:`pipeline.recording.recover.salvageable` counts them).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message, MessageIndex, Metadata,
                          MetadataIndex, Schema, Statistics)
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

from pipeline.io.mcap_framing import (OPCODE_NAMES, bounded, chunk_length, chunk_size_damage, compressed_size_damage,
                                      record_at)
from pipeline.io.mcap_io import TORN_END_ERRORS, check_recording
from pipeline.io.mcap_writer import MAGIC, crc32
from pipeline.io.recorder import SCHEMA_PREFIX
from gflow_msgs.messages import MESSAGE_TYPES, MessageError, decode, decode_as
from gflow_msgs.foxglove import FOXGLOVE_SCHEMAS

__all__ = ["verify", "VerifyResult", "Progress", "recording_damage"]

_FOXGLOVE_BY_SCHEMA: dict[str, type] = {name: typ for typ, name in FOXGLOVE_SCHEMAS.items()}

#: told (bytes read, file size, messages checked) after each chunk
Progress = Callable[[int, int, int], None]


@dataclass
class VerifyResult:
    """What :func:`verify` found in one file.

    ``messages`` counts the messages read and checked: all of them when the file is intact, those
    before the fault otherwise (the complete chunks before it, which ``gflow recover`` salvages).
    """

    path: str
    size: int = 0
    messages: int = 0
    channels: int = 0
    start_ns: int = 0
    end_ns: int = 0
    damage: str = ""  # the first fault: what and where ("" when intact)
    torn: bool = False  # the file ends inside a record (no summary, no footer) or inside its closing magic bytes

    @property
    def ok(self) -> bool:
        return not self.damage

    @property
    def duration_s(self) -> float:
        return max(0, self.end_ns - self.start_ns) / 1e9


class _Fault(Exception):
    """The first fault found; its text says what and where."""


@dataclass
class _ChunkSeen:
    number: int  # 1, 2, ... in file order
    offset: int
    length: int  # bytes of the whole record
    record: Chunk
    per_channel: dict[int, int]


def _protobuf_decoder(schema: Schema) -> Callable[[bytes], Any] | None:
    """A callable that parses a protobuf payload of ``schema`` (its data a FileDescriptorSet, as
    ``gflow foxglove`` writes them); None without google.protobuf (then it is not decoded)."""
    try:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
        from google.protobuf.message import DecodeError
    except ImportError:
        return None
    try:
        pool = descriptor_pool.DescriptorPool()
        for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
            pool.Add(f)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    except (DecodeError, KeyError, TypeError) as e:
        raise _Fault(f"schema {schema.id} ({schema.name}): not a protobuf FileDescriptorSet of it ({e})") from None

    def check(data: bytes) -> Any:
        try:
            return cls.FromString(data)
        except DecodeError as e:
            raise MessageError(f"not a protobuf {schema.name}: {e}") from None
    return check


def _message_decoder(schema: Schema | None) -> Callable[[bytes], Any] | None:
    """A callable that decodes (and so checks) a payload of ``schema``; None when gflow does not know it."""
    if schema is None:
        return None
    if schema.encoding == "protobuf":  # a Foxglove well-known schema as gflow foxglove writes it
        return _protobuf_decoder(schema)
    name = schema.name
    if name.startswith(SCHEMA_PREFIX) and name[len(SCHEMA_PREFIX):] in MESSAGE_TYPES:
        typ = MESSAGE_TYPES[name[len(SCHEMA_PREFIX):]]
        return lambda data: decode_as(data, typ)
    fox = _FOXGLOVE_BY_SCHEMA.get(name)
    if fox is not None:
        def check(data: bytes) -> Any:
            m = decode(data)
            if not isinstance(m, fox):
                raise MessageError(f"a {type(m).__name__}, not a {fox.__name__}")
            return m
        return check
    return None


def _indexed_topics(following: Iterator[Any], channels: dict[int, Channel]) -> str:
    """The topics of an unreadable chunk, from the message indexes written after it (if they can be read)."""
    ids = []
    try:
        for rec in following:
            if not isinstance(rec, MessageIndex):
                break
            ids.append(rec.channel_id)
    except TORN_END_ERRORS:
        pass
    names = sorted({channels[i].topic for i in ids if i in channels})
    return f"; it holds messages on {', '.join(names)}" if names else ""


class _Walk:
    """The state of one pass over a file: what the data section defined, and where."""

    def __init__(self, result: VerifyResult) -> None:
        self.r = result
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.decoders: dict[int, Callable[[bytes], Any] | None] = {}
        self.chunks: dict[int, _ChunkSeen] = {}  # by offset
        self.last_chunk: _ChunkSeen | None = None
        self.metadata: dict[int, str] = {}  # offset -> name
        self.summary_start = 0  # the offset after the data end
        self.stats: Statistics | None = None
        self.chunk_indexes: list[ChunkIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.summary_defs: list[Schema | Channel] = []
        self.per_channel: dict[int, int] = {}
        self.n_records = 0

    # the data section ------------------------------------------------------------------------------------
    def schema(self, s: Schema, where: str) -> None:
        old = self.schemas.get(s.id)
        if old is not None and (old.name, old.encoding, old.data) != (s.name, s.encoding, s.data):
            raise _Fault(f"{where}: schema {s.id} redefined as {s.name!r} (first {old.name!r})")
        self.schemas[s.id] = s

    def channel(self, c: Channel, where: str) -> None:
        if c.schema_id != 0 and c.schema_id not in self.schemas:
            raise _Fault(f"{where}: channel {c.id} ({c.topic}) names schema {c.schema_id}, which the file "
                         f"has not defined")
        old = self.channels.get(c.id)
        if old is not None and (old.topic, old.schema_id) != (c.topic, c.schema_id):
            raise _Fault(f"{where}: channel {c.id} redefined as {c.topic!r} (first {old.topic!r})")
        if old is None:
            self.channels[c.id] = c
            self.decoders[c.id] = _message_decoder(self.schemas.get(c.schema_id))

    def message(self, m: Message, where: str, chunk: Chunk | None = None) -> None:
        c = self.channels.get(m.channel_id)
        if c is None:
            raise _Fault(f"{where}: a message (seq {m.sequence}) on channel {m.channel_id}, which the file has "
                         f"not defined")
        if chunk is not None and not chunk.message_start_time <= m.log_time <= chunk.message_end_time:
            raise _Fault(f"{where}: a message on {c.topic} (seq {m.sequence}) logged at {m.log_time} ns, outside "
                         f"the chunk's stated {chunk.message_start_time}..{chunk.message_end_time}")
        dec = self.decoders.get(m.channel_id)
        if dec is not None:
            try:
                dec(m.data)
            except (MessageError, ValueError, TypeError) as e:
                raise _Fault(f"{where}: the message on {c.topic} (seq {m.sequence}) does not decode as "
                             f"{self.schemas[c.schema_id].name} ({' '.join(str(e).split())})") from None
        r = self.r
        r.messages += 1
        r.start_ns = m.log_time if r.messages == 1 else min(r.start_ns, m.log_time)
        r.end_ns = max(r.end_ns, m.log_time)
        self.per_channel[m.channel_id] = self.per_channel.get(m.channel_id, 0) + 1

    def chunk(self, ch: Chunk, offset: int, end: int, following: Iterator[Any]) -> None:
        """Check one chunk; ``following`` (the records after it) names the topics of one that cannot be read."""
        k = len(self.chunks) + 1
        where = f"chunk {k} at byte {offset}"
        why = chunk_size_damage(ch)[1]  # before it is decompressed: zstd would allocate the size it states
        if why:
            raise _Fault(f"{where}: {why}")
        try:
            inner = breakup_chunk(ch, validate_crc=True)
        except CRCValidationError as e:
            raise _Fault(f"{where}: its CRC does not match its contents (stated {e.expected:#010x}, computed "
                         f"{e.actual:#010x}){_indexed_topics(following, self.channels)}") from None
        except TORN_END_ERRORS as e:
            raise _Fault(f"{where}: its {ch.compression or 'uncompressed'} data cannot be read "
                         f"({type(e).__name__}: {' '.join(str(e).split())})"
                         f"{_indexed_topics(following, self.channels)}") from None
        seen = _ChunkSeen(k, offset, end - offset, ch, {})
        before = self.r.messages
        for rec in inner:
            if isinstance(rec, Schema):
                self.schema(rec, where)
            elif isinstance(rec, Channel):
                self.channel(rec, where)
            elif isinstance(rec, Message):
                try:
                    self.message(rec, where, ch)
                except _Fault:
                    self.r.messages = before  # recover keeps whole chunks: none of this one
                    raise
                seen.per_channel[rec.channel_id] = seen.per_channel.get(rec.channel_id, 0) + 1
        self.chunks[offset] = seen
        self.last_chunk = seen

    def message_index(self, mi: MessageIndex, offset: int) -> None:
        ck = self.last_chunk
        if ck is None:
            raise _Fault(f"byte {offset}: a message index before any chunk")
        where = f"the message index at byte {offset} (chunk {ck.number})"
        n = ck.per_channel.get(mi.channel_id, 0)
        if len(mi.records) != n:
            topic = self.channels[mi.channel_id].topic if mi.channel_id in self.channels else f"channel {mi.channel_id}"
            raise _Fault(f"{where}: lists {len(mi.records)} messages on {topic}; the chunk holds {n}")

    # the summary -----------------------------------------------------------------------------------------
    def check_summary(self, footer: Footer, footer_at: int, f) -> None:
        where = f"the summary (from byte {self.summary_start})"
        if footer.summary_start not in (0, self.summary_start):
            raise _Fault(f"the footer at byte {footer_at}: it says the summary starts at byte "
                         f"{footer.summary_start}; it starts at {self.summary_start}")
        if footer.summary_crc != 0:
            f.seek(self.summary_start)
            data = f.read(footer_at - self.summary_start) if footer.summary_start else b""
            crc = crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, footer.summary_start,
                                    footer.summary_offset_start), crc32(data))
            if crc != footer.summary_crc:
                raise _Fault(f"{where}: its CRC does not match (stated {footer.summary_crc:#010x}, computed "
                             f"{crc:#010x})")
        for d in self.summary_defs:
            known: Any = self.schemas.get(d.id) if isinstance(d, Schema) else self.channels.get(d.id)
            kind = "schema" if isinstance(d, Schema) else "channel"
            if known is None or (isinstance(d, Channel) and (known.topic, known.schema_id) != (d.topic, d.schema_id)) \
                    or (isinstance(d, Schema) and (known.name, known.data) != (d.name, d.data)):
                raise _Fault(f"{where}: {kind} {d.id} differs from the data section's")
        s = self.stats
        if s is not None:
            r = self.r
            counts = {k: v for k, v in s.channel_message_counts.items() if v}
            for what, stated, held in (("messages", s.message_count, r.messages),
                                       ("channels", s.channel_count, len(self.channels)),
                                       ("schemas", s.schema_count, len(self.schemas)),
                                       ("chunks", s.chunk_count, len(self.chunks)),
                                       ("metadata records", s.metadata_count, len(self.metadata))):
                if stated != held:
                    raise _Fault(f"{where}: the statistics say {stated} {what}; the file holds {held}")
            if counts != self.per_channel:
                bad = sorted(set(counts) | set(self.per_channel),
                             key=lambda c: counts.get(c, 0) == self.per_channel.get(c, 0))[0]
                topic = self.channels[bad].topic if bad in self.channels else f"channel {bad}"
                raise _Fault(f"{where}: the statistics say {counts.get(bad, 0)} messages on {topic}; the file "
                             f"holds {self.per_channel.get(bad, 0)}")
            if r.messages and (s.message_start_time, s.message_end_time) != (r.start_ns, r.end_ns):
                raise _Fault(f"{where}: the statistics give the messages' times as {s.message_start_time}.."
                             f"{s.message_end_time} ns; they are {r.start_ns}..{r.end_ns}")
        if self.chunk_indexes:
            listed = {ci.chunk_start_offset: ci for ci in self.chunk_indexes}
            for off, ck in self.chunks.items():
                ci = listed.pop(off, None)
                if ci is None:
                    raise _Fault(f"{where}: no chunk index for chunk {ck.number} at byte {off}")
                c = ck.record
                if (ci.chunk_length, ci.compressed_size, ci.uncompressed_size, ci.message_start_time,
                        ci.message_end_time) != (ck.length, len(c.data), c.uncompressed_size, c.message_start_time,
                                                 c.message_end_time):
                    raise _Fault(f"{where}: the chunk index of chunk {ck.number} at byte {off} does not match it")
                if not set(ci.message_index_offsets) <= set(ck.per_channel):
                    raise _Fault(f"{where}: the chunk index of chunk {ck.number} at byte {off} names channels "
                                 f"it does not hold")
            if listed:
                raise _Fault(f"{where}: a chunk index points at byte {min(listed)}, where no chunk starts")
        for mi in self.metadata_indexes:
            if self.metadata.get(mi.offset) != mi.name:
                raise _Fault(f"{where}: the metadata index of {mi.name!r} points at byte {mi.offset}, where no "
                             f"such metadata record starts")


def _check_opcode(f, at: int) -> None:
    """The record at byte ``at`` has an opcode MCAP defines (the reader would skip any other unread)."""
    f.seek(at)
    op = f.read(1)
    f.seek(at)
    if op and op[0] not in OPCODE_NAMES:
        raise _Fault(f"byte {at}: {op[0]:#04x} is no MCAP record's opcode (the record's frame is damaged)")


def _check_frame(f, at: int, size: int, number: int) -> None:
    """The record at byte ``at``, before the reader reads it: its opcode is one MCAP defines, and, when it is chunk
    ``number``, no length of it runs past the end of the file or of its record, which the reader would ask for
    that many bytes (2**62: MemoryError): a record length past the end of the file whose fields the file holds
    (the length is damaged), or a compressed size past the end of a record the file holds (the size is damaged).
    A chunk the file ends inside (a torn end) is left to the reader."""
    _check_opcode(f, at)
    f.seek(at)
    head = f.read(9 + 32)
    f.seek(at)
    if len(head) < 9 + 32 or head[0] != Opcode.CHUNK:
        return
    (length,) = struct.unpack_from("<Q", head, 1)
    if at + 9 + length > size:
        own = chunk_length(f, at, size)
        f.seek(at)
        if own:
            raise _Fault(f"chunk {number} at byte {at}: its record length says {length} bytes; its fields take "
                         f"{own} (the length is damaged)")
        return
    (clen,) = struct.unpack_from("<I", head, 9 + 28)
    if 32 + clen + 8 > length:
        return  # its compression's name runs past its record: the reader says so
    f.seek(at + 9)
    why = compressed_size_damage(f.read(32 + clen + 8), length)
    f.seek(at)
    if why:
        raise _Fault(f"chunk {number} at byte {at}: {why} (the size is damaged; the record's length holds)")


def _check_chunk_length(f, at: int, end: int, size: int, number: int) -> None:
    """The record length of the chunk at byte ``at`` is the one its fields take: the reader reads a chunk by
    its fields, but a reader that goes by the record's length (an index, a seek) fails where they differ."""
    own = chunk_length(f, at, size)
    f.seek(at + 1)
    (length,) = struct.unpack("<Q", f.read(8))
    f.seek(end)
    if length != own:
        raise _Fault(f"chunk {number} at byte {at}: its record length says {length} bytes; its fields take {own} "
                     f"(the length is damaged)")


def verify(path: str | Path, progress: Progress | None = None) -> VerifyResult:
    """Read and check every record of one MCAP file (see the module docstring).

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` for one that is not MCAP
    (empty, or other magic bytes); every other fault is the result's ``damage``.
    """
    p = check_recording(path)
    size = p.stat().st_size
    r = VerifyResult(str(path), size=size)
    w = _Walk(r)
    with open(p, "rb") as f:
        records = iter(StreamReader(bounded(f), emit_chunks=True, validate_crcs=True).records)
        at, last_at, in_summary = 0, 0, False
        footer: tuple[Footer, int] | None = None
        try:
            while True:
                at = f.tell() if w.n_records else 8
                if w.n_records and footer is None:  # (before the first record the reader reads the magic bytes)
                    _check_frame(f, at, size, len(w.chunks) + 1)
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except CRCValidationError as e:  # the reader checks the data section's CRC at the data end
                    raise _Fault(f"the data section (bytes 8..{at}): its CRC does not match (stated "
                                 f"{e.expected:#010x}, computed {e.actual:#010x})") from None
                except EndOfFile:
                    if footer is not None:
                        raise _Fault(f"byte {at}: the file ends without its closing magic bytes") from None
                    raise
                except TORN_END_ERRORS as e:
                    if footer is not None:
                        raise _Fault(f"byte {at}: the closing magic bytes are wrong") from None
                    past = f.tell() >= size
                    fr = record_at(f, at, size)  # the record read by its framing alone
                    if fr.record is not None and fr.damage:  # a chunk whose length is damaged, read by its fields
                        raise _Fault(f"byte {at}: the {fr.kind} record: {fr.damage}") from None
                    if fr.damage and not (fr.torn or fr.broken_frame):  # its length is right, its contents are not
                        raise _Fault(f"byte {at}: the {fr.kind} record: {fr.damage}; its frame is intact, so the "
                                     f"records after it can still be read") from None
                    if past:  # a record cut short by the end of the file
                        raise EndOfFile() from None
                    raise _Fault(f"byte {at}: a record cannot be read ({type(e).__name__}: "
                                 f"{' '.join(str(e).split())})") from None
                end = f.tell()
                last_at = at
                w.n_records += 1
                if w.n_records == 1 and not isinstance(rec, Header):
                    raise _Fault(f"byte {at}: the file does not start with a header record")
                if isinstance(rec, Chunk):
                    _check_chunk_length(f, at, end, size, len(w.chunks) + 1)
                    w.chunk(rec, at, end, records)
                    if progress is not None:
                        progress(end, size, r.messages)
                elif isinstance(rec, MessageIndex):
                    w.message_index(rec, at)
                elif isinstance(rec, (Schema, Channel)) and in_summary:
                    w.summary_defs.append(rec)
                elif isinstance(rec, Schema):
                    w.schema(rec, f"byte {at}")
                elif isinstance(rec, Channel):
                    w.channel(rec, f"byte {at}")
                elif isinstance(rec, Message):
                    w.message(rec, f"byte {at}")
                elif isinstance(rec, Metadata):
                    w.metadata[at] = rec.name
                elif isinstance(rec, DataEnd):
                    in_summary = True
                    w.summary_start = end
                elif isinstance(rec, Statistics):
                    w.stats = rec
                elif isinstance(rec, ChunkIndex):
                    w.chunk_indexes.append(rec)
                elif isinstance(rec, MetadataIndex):
                    w.metadata_indexes.append(rec)
                elif isinstance(rec, Footer):
                    footer = (rec, at)
            if footer is None:
                raise EndOfFile()
            if not in_summary:
                raise _Fault(f"byte {footer[1]}: a footer with no data end record before it")
            after = size - f.tell()
            if after > 0:
                raise _Fault(f"byte {f.tell()}: {after} bytes after the closing magic bytes")
            w.check_summary(footer[0], footer[1], f)
        except EndOfFile:
            f.seek(max(0, size - 8))
            if size > 16 and f.read(len(MAGIC)) == MAGIC:  # a closed file: a damaged length ran a record past its end
                start = last_at if at >= size else at  # the record that swallowed the rest, or the one cut short
                r.damage = (f"byte {start}: a record runs to or past the end of the file, which ends with its closing "
                            f"magic bytes (the record's length is damaged)")
            else:
                r.torn = True
                r.damage = (f"the file ends at byte {size}, inside the record that starts at byte {at}, with no "
                            f"summary or footer (its writer was killed, or is still writing)")
        except _Fault as e:  # cut after its footer, before its closing magic bytes end: torn (as the readers say)
            r.damage, r.torn = str(e), footer is not None and size - at < len(MAGIC)
    r.channels = len(w.channels)
    return r


def recording_damage(path: str | Path) -> str:
    """The first damage :func:`verify` finds in recording ``path`` or a segment of it, as one line naming the
    file, what is wrong and where ("" when none is found). A segment that only ends early (torn: its writer was
    killed, or is still writing) is left to the readers, which say so themselves.

    For the commands that describe a recording (``gflow info``) without reading every record as ``gflow verify``
    does: the reader skips a record whose opcode MCAP does not define, so a chunk with a damaged opcode is
    passed over without a word, and its messages are missing from what the command counts.
    """
    from pipeline.io.mcap_io import segments

    for seg in segments(path):
        r = verify(seg)
        if r.damage and not r.torn:
            return f"{seg}: recording is damaged: {r.damage} (`gflow recover` copies every intact chunk)"
    return ""
