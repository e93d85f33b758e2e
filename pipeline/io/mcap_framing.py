"""An MCAP file walked record by record by its framing, so that one damaged record costs only itself.

Every MCAP record is framed as ``opcode (1 byte) | length (8 bytes, little endian) | body (length
bytes)``. ``mcap.stream_reader.StreamReader`` parses each body straight from the file, so a body whose
contents are damaged (a string length inside a metadata record, a chunk whose CRC or compression fails)
stops the reader, and everything after it is lost to every tool that reads through it. Here each body is
read as ``length`` bytes first and parsed from those bytes alone: a body that does not parse is reported
as damaged and the walk goes on at the next record, which its framing locates.

A length damaged to a huge value is found before anything is read by it: a chunk whose compressed size
runs past the end of its record is read by its record's length (and one whose record length is wrong by its
fields), each saying so; the mcap readers gflow hands a file to read it through :class:`Bounded`, which never
asks for more bytes than the file holds (a length of 2**62 would have them allocate that much).

Only a damaged frame (an opcode MCAP does not define, or a length that runs past the end of the file)
breaks the chain. If the file was closed (it ends with the closing magic bytes after a readable footer),
its summary's chunk indexes say where every chunk starts, and the walk resumes at the first chunk after
the damage; otherwise the walk stops there. A file with no closing magic whose last record runs past its
end is torn (its writer was killed, or is still writing), not damaged.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from dataclasses import dataclass, field
from typing import IO, Any, Iterator, cast

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message,
                          MessageIndex, Metadata, MetadataIndex, Schema, Statistics, SummaryOffset)
from mcap.stream_reader import breakup_chunk

__all__ = ["Framed", "framed_records", "record_at", "chunk_length", "read_summary", "Summary", "OPCODE_NAMES",
           "Located", "locate", "Bounded", "bounded", "PastEnd", "chunk_size_damage", "compressed_size_damage",
           "chunk_records", "ChunkSizeDamaged", "Cut", "torn_at"]

MAGIC = b"\x89MCAP0\r\n"
_FRAME = struct.Struct("<BQ")

_RECORD_TYPES: dict[int, Any] = {
    Opcode.HEADER: Header, Opcode.FOOTER: Footer, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
    Opcode.MESSAGE: Message, Opcode.CHUNK: Chunk, Opcode.MESSAGE_INDEX: MessageIndex,
    Opcode.CHUNK_INDEX: ChunkIndex, Opcode.ATTACHMENT: Attachment, Opcode.ATTACHMENT_INDEX: AttachmentIndex,
    Opcode.STATISTICS: Statistics, Opcode.METADATA: Metadata, Opcode.METADATA_INDEX: MetadataIndex,
    Opcode.SUMMARY_OFFSET: SummaryOffset, Opcode.DATA_END: DataEnd,
}

#: the record kinds by opcode, as messages name them ("a metadata record")
OPCODE_NAMES: dict[int, str] = {
    Opcode.HEADER: "header", Opcode.FOOTER: "footer", Opcode.SCHEMA: "schema", Opcode.CHANNEL: "channel",
    Opcode.MESSAGE: "message", Opcode.CHUNK: "chunk", Opcode.MESSAGE_INDEX: "message index",
    Opcode.CHUNK_INDEX: "chunk index", Opcode.ATTACHMENT: "attachment", Opcode.ATTACHMENT_INDEX: "attachment index",
    Opcode.STATISTICS: "statistics", Opcode.METADATA: "metadata", Opcode.METADATA_INDEX: "metadata index",
    Opcode.SUMMARY_OFFSET: "summary offset", Opcode.DATA_END: "data end",
}


@dataclass
class Framed:
    """One step of the walk.

    ``record`` is the parsed record, or None with ``damage`` saying why (its body does not parse, or the
    frame itself is damaged). ``skipped_to`` is set on a damaged frame the walk resumed after: the offset of
    the chunk it resumed at (0: it stopped). ``torn``: the file ends inside this record (no damage to its
    bytes; its writer was killed or is still writing)."""

    offset: int
    opcode: int
    length: int
    record: Any = None
    damage: str = ""
    skipped_to: int = 0
    torn: bool = False
    broken_frame: bool = False  # the opcode or the length is damaged: the next record could not be located

    @property
    def kind(self) -> str:
        return OPCODE_NAMES.get(self.opcode, f"opcode {self.opcode:#04x}")


class PastEnd(EndOfFile):
    """A read of ``asked`` bytes at byte ``at`` of a file of ``size`` bytes: past its end, by a length that only
    damage (or a cut far inside a record) can give. An :class:`~mcap.exceptions.EndOfFile`, so the readers
    take it as they take the end of a file; the file is left at its end, as a read to its end leaves it."""

    def __init__(self, at: int, asked: int, size: int) -> None:
        super().__init__(f"a length of {asked} bytes, read from byte {at}, runs past the end of the file "
                         f"({size} bytes)")
        self.at, self.asked, self.size = at, asked, size


class Bounded:
    """A binary file whose ``read(n)`` never asks for more bytes than the file holds from where it is.

    mcap's readers read a record's body, a chunk's compressed data or a string by the length the file states:
    a length damaged to 2**62 had them ask the file for that many bytes, which raises MemoryError (2**64 - 1:
    OverflowError) before a byte is read. Here a read of more than :attr:`BIG` bytes that runs past the end of
    the file raises :class:`PastEnd` instead, before anything is allocated; a smaller one is the file's own (a
    short read at its end). Everything but ``read`` is the file's own."""

    BIG = 1 << 20  # a read of more bytes than this looks at the file's size first (a small one cannot hurt)

    def __init__(self, f: IO[bytes]) -> None:
        self._f = f

    def read(self, n: int | None = -1) -> bytes:
        """At most ``n`` bytes (all the rest when ``n`` is None or negative); see the class docstring."""
        if n is not None and n > self.BIG:
            at, size = self._f.tell(), os.fstat(self._f.fileno()).st_size
            if at + n > size:
                self._f.seek(size)
                raise PastEnd(at, n, size)
        return self._f.read(-1 if n is None else n)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


def bounded(f: IO[bytes]) -> IO[bytes]:
    """``f`` read through :class:`Bounded`, typed as the file it stands for (what mcap's readers take)."""
    return cast(IO[bytes], Bounded(f))


def compressed_size_damage(body: bytes | bytearray, length: int | None = None) -> str:
    """What is wrong with the compressed size a chunk's ``body`` states ("" when its data fits in the body): a
    size that runs past the end of its record (a reader would try to read that many bytes). ``length``: the
    body's length, when ``body`` is only its start (its fields, up to and with the compressed size)."""
    length = len(body) if length is None else length
    if len(body) < 32:
        return ""
    (clen,) = struct.unpack_from("<I", body, 28)
    if 32 + clen + 8 > min(len(body), length):
        return ""  # the compression name's own length runs past the record: the parser says so
    (stated,) = struct.unpack_from("<Q", body, 32 + clen)
    room = length - (32 + clen + 8)
    if stated <= room:
        return ""
    return (f"its compressed size ({stated} bytes) runs past the end of its record ({room} bytes after its "
            f"fields)")


def _parse(opcode: int, body: bytes) -> Any:
    """The record of ``opcode`` parsed from its ``body`` alone (reading past it raises)."""
    why = compressed_size_damage(body) if opcode == Opcode.CHUNK else ""
    if why:
        raise ValueError(why)
    stream = ReadDataStream(io.BytesIO(body))
    typ = _RECORD_TYPES[opcode]
    rec = typ.read(stream, len(body)) if typ is Message else typ.read(stream)
    if typ is Chunk:  # Chunk.read takes the compressed bytes by their own length: it must fill the body
        if stream.count != len(body):
            raise ValueError(f"its fields take {stream.count} of its {len(body)} bytes")
    return rec


@dataclass
class Summary:
    """What the summary section of a closed file says: every chunk's start (sorted), the schemas and
    channels it repeats (by id), how many messages the file holds and each chunk's index (by its offset)."""

    chunk_offsets: list[int]
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    messages: int = -1  # the statistics' message count (-1: none readable)
    intact: bool = True  # its CRC matches (or the footer gives none): False, and its counts are not to be believed
    chunk_indexes: dict[int, ChunkIndex] = field(default_factory=dict)


def read_summary(f: IO[bytes], size: int) -> Summary:
    """The summary of a closed file, each of its records read by its framing (a damaged one is left out);
    empty when the file has no readable footer or summary (a torn file)."""
    out = Summary([], {}, {})
    foot_len = 9 + 20 + len(MAGIC)
    if size < len(MAGIC) + foot_len:
        return out
    f.seek(size - foot_len)
    tail = f.read(foot_len)
    if tail[-len(MAGIC):] != MAGIC or tail[0] != Opcode.FOOTER:
        return out
    try:
        footer = _parse(Opcode.FOOTER, tail[9:29])
    except Exception:  # noqa: BLE001  (a damaged footer: no summary to go by)
        return out
    start, end = footer.summary_start, size - foot_len
    if not len(MAGIC) <= start < end:
        return out
    if footer.summary_crc:  # a CRC of the summary up to the footer's summary_crc field
        f.seek(start)
        out.intact = zlib.crc32(f.read(size - len(MAGIC) - 4 - start)) == footer.summary_crc
    f.seek(start)
    at = start
    while at + 9 <= end:
        opcode, length = _FRAME.unpack(f.read(9))
        if at + 9 + length > end or opcode not in _RECORD_TYPES:
            break
        body = f.read(length)
        at += 9 + length
        try:
            rec = _parse(opcode, body)
        except Exception:  # noqa: BLE001  (one damaged record: the others still count)
            continue
        if isinstance(rec, ChunkIndex) and len(MAGIC) <= rec.chunk_start_offset < start:
            out.chunk_offsets.append(rec.chunk_start_offset)
            out.chunk_indexes[rec.chunk_start_offset] = rec
        elif isinstance(rec, Schema):
            out.schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            out.channels[rec.id] = rec
        elif isinstance(rec, Statistics):
            out.messages = rec.message_count
    out.chunk_offsets.sort()
    return out


def record_at(f: IO[bytes], at: int, size: int) -> Framed:
    """The record whose frame starts at byte ``at`` of the file ``f`` (``size`` bytes), read by its framing
    alone: parsed, or with ``damage`` (and ``torn`` or ``broken_frame``) saying what is wrong."""
    f.seek(at)
    head = f.read(9)
    if len(head) < 9:
        return Framed(at, head[0] if head else 0, 0, torn=True, damage="the file ends inside a record's frame")
    opcode, length = _FRAME.unpack(head)
    if opcode == Opcode.CHUNK:
        own = chunk_length(f, at, size)
        if own and own != length:  # the frame's length is damaged; the chunk's own fields (and its CRC) hold
            fr = record_at_length(f, at, own)
            if fr.record is not None:
                fr.damage = (f"its frame is damaged (its length says {length} bytes; the chunk's own fields "
                             f"take {own}, and it is read by them)")
                return fr
        by_length = _chunk_by_its_length(f, at, length) if at + 9 + length <= size else None
        if by_length is not None:
            return by_length
    if at + 9 + length > size or opcode not in _RECORD_TYPES:
        if opcode in _RECORD_TYPES and not _closed(f, size):
            return Framed(at, opcode, length, torn=True,
                          damage=f"the file ends inside the {OPCODE_NAMES[opcode]} record at byte {at}")
        what = ("its length runs past the end of the file" if opcode in _RECORD_TYPES
                else f"{opcode:#04x} is no record's opcode")
        return Framed(at, opcode, length, damage=f"the record's frame is damaged ({what})", broken_frame=True)
    return record_at_length(f, at, length, opcode)


@dataclass(frozen=True)
class Located:
    """Where a reader stopped, by the records' framing: the record that holds the byte (or whose frame is
    broken before it), its ``offset`` and ``end`` (the byte after it), its ``opcode``, and ``number``, its
    place among the file's records of that kind (1: the first chunk), as ``gflow verify`` numbers them."""

    offset: int
    end: int
    opcode: int
    number: int

    def describe(self) -> str:
        """'chunk 7 (bytes 11674447-13774486)'."""
        return f"{OPCODE_NAMES.get(self.opcode, f'opcode {self.opcode:#04x}')} {self.number} " \
               f"(bytes {self.offset}-{self.end})"


def locate(f: IO[bytes], size: int, pos: int) -> Located | None:
    """The record of the file ``f`` (``size`` bytes) whose frame holds byte ``pos - 1`` -- the last byte a
    reader that stopped at ``pos`` took -- found by reading the frames alone (9 bytes each) from the start;
    the first record whose frame is broken (an opcode MCAP does not define, a length past the end) if the
    chain breaks before it; None when ``pos`` lies in the magic bytes or past every record."""
    at, counts = len(MAGIC), dict[int, int]()
    while at + 9 <= size:
        f.seek(at)
        opcode, length = _FRAME.unpack(f.read(9))
        counts[opcode] = counts.get(opcode, 0) + 1
        end = at + 9 + length
        if end >= pos or end > size or opcode not in _RECORD_TYPES:
            return Located(at, min(end, size), opcode, counts[opcode])
        at = end
    return None


@dataclass(frozen=True)
class Cut:
    """Where a torn file (no closing magic bytes) ends: inside the record at ``offset``, of ``opcode``, whose
    frame gives its body ``length`` bytes (-1: the file ends inside the frame itself; ``offset == size``: after a
    whole record), ``number`` its place among the file's records of its kind (1: the first chunk); ``size`` is
    the file's."""

    offset: int
    opcode: int
    length: int
    number: int
    size: int

    @property
    def holds_messages(self) -> bool:
        """A chunk or a message cut short (or a frame too short to say which): what it held is not known."""
        return self.offset < self.size and (self.length < 0 or self.opcode in (Opcode.CHUNK, Opcode.MESSAGE))

    def describe(self) -> str:
        """'the file ends inside chunk 3 at byte 1880, 211 of whose 264 bytes it holds', '... inside a record's
        frame at byte 4090, 3 of whose 9 bytes it holds' or 'the file ends at byte 1880, after a whole record'."""
        if self.offset >= self.size:
            return f"the file ends at byte {self.size}, after a whole record"
        if self.length < 0:
            return (f"the file ends inside a record's frame at byte {self.offset}, {self.size - self.offset} of "
                    f"whose 9 bytes it holds")
        return (f"the file ends inside {OPCODE_NAMES[self.opcode]} {self.number} at byte {self.offset}, "
                f"{self.size - self.offset} of whose {9 + self.length} bytes it holds")


    def part(self) -> str:
        """The record cut short, as a part of what was not read: 'chunk 3 at byte 1880, cut short by the file's
        end (the file holds 211 of its 264 bytes)'."""
        if self.offset >= self.size or not self.holds_messages:
            return self.describe()
        what = "a record" if self.length < 0 else f"{OPCODE_NAMES[self.opcode]} {self.number}"
        whole = 9 if self.length < 0 else 9 + self.length
        return (f"{what} at byte {self.offset}, cut short by the file's end (the file holds {self.size - self.offset} "
                f"of its {whole} bytes)")

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``gflow info --json``'s ``not_read.cut``."""
        return {"byte": self.offset, "record": OPCODE_NAMES.get(self.opcode) if self.length >= 0 else None,
                "bytes_held": self.size - self.offset, "bytes": 9 + self.length if self.length >= 0 else None,
                "holds_messages": self.holds_messages}


def torn_at(f: IO[bytes], size: int) -> Cut | None:
    """Where the file ``f`` (``size`` bytes, with no closing magic bytes) ends, found by its frames alone (9 bytes
    read each); None when a frame before the end is broken (an opcode MCAP does not define): what follows that is
    damage, which :func:`framed_records` reports, not a cut."""
    at, counts = len(MAGIC), dict[int, int]()
    while at < size:
        if at + 9 > size:
            return Cut(at, 0, -1, 0, size)
        f.seek(at)
        opcode, length = _FRAME.unpack(f.read(9))
        if opcode not in _RECORD_TYPES:
            return None
        counts[opcode] = counts.get(opcode, 0) + 1
        if at + 9 + length > size:
            return Cut(at, opcode, length, counts[opcode], size)
        at += 9 + length
    return Cut(size, 0, 0, 0, size)


def chunk_length(f: IO[bytes], at: int, size: int) -> int:
    """The body length the fields of the chunk record at byte ``at`` give it (0: they run past the end of
    the file): times, sizes, CRC, compression name, then the compressed data's own length."""
    f.seek(at + 9 + 28)
    raw = f.read(4)
    if len(raw) < 4:
        return 0
    (clen,) = struct.unpack("<I", raw)
    f.seek(at + 9 + 32 + clen)
    raw = f.read(8)
    if len(raw) < 8:
        return 0
    own = 32 + clen + 8 + struct.unpack("<Q", raw)[0]
    return own if at + 9 + own <= size else 0


def _chunk_by_its_length(f: IO[bytes], at: int, length: int) -> Framed | None:
    """The chunk at byte ``at`` read by its record's ``length`` (which the file holds) when the compressed size
    it states runs past the end of that record: the size is damaged, the data is the rest of the record (its CRC,
    checked when it is decompressed, says whether it is whole); None when the size fits (nothing to repair)."""
    f.seek(at + 9)
    body = bytearray(f.read(length))
    why = compressed_size_damage(body)
    if not why:
        return None
    (clen,) = struct.unpack_from("<I", body, 28)
    struct.pack_into("<Q", body, 32 + clen, length - (32 + clen + 8))
    try:
        rec = _parse(Opcode.CHUNK, bytes(body))
    except Exception:  # noqa: BLE001  (its other fields are damaged too: it cannot be read)
        return Framed(at, Opcode.CHUNK, length, damage=f"its contents cannot be read ({why})")
    return Framed(at, Opcode.CHUNK, length, record=rec,
                  damage=f"{why}: the size is damaged, and the chunk is read by its record's length")


def chunk_size_damage(chunk: Chunk) -> tuple[Chunk | None, str]:
    """``chunk`` with the uncompressed size its compressed data states, and what is wrong with the size the
    chunk's own field gives ("" and ``chunk`` itself when nothing is): a size other than its data's (an
    uncompressed chunk's length, the size an lz4 or zstd frame header gives), or one no decompressor can take.
    zstd allocates the size the field gives when its frame gives none (2**62: MemoryError; 2**63 and more:
    OverflowError), so a chunk is only decompressed once this has said nothing, or with the size it returns;
    None when it cannot be (zstd data that gives no size, and a size more than it can hold)."""
    stated = chunk.uncompressed_size
    own = -1  # the size the data gives (-1: it gives none)
    if chunk.compression == "":
        own = len(chunk.data)
    elif chunk.compression == "lz4":
        try:
            import lz4.frame

            own = lz4.frame.get_frame_info(chunk.data).get("content_size") or -1
        except Exception:  # noqa: BLE001  (a damaged frame header: the decompressor says so)
            own = -1
    elif chunk.compression == "zstd":
        try:
            import zstandard

            own = zstandard.frame_content_size(chunk.data)
        except Exception:  # noqa: BLE001  (a damaged frame header: the decompressor says so)
            own = -1
    if own >= 0 and own != stated:
        fixed = _resized(chunk, own)
        what = "its data holds" if chunk.compression == "" else f"its {chunk.compression} data's header says"
        return fixed, f"its uncompressed size says {stated} bytes; {what} {own} (the size is damaged)"
    if own < 0 and chunk.compression == "zstd" and stated > _ZSTD_MAX_RATIO * len(chunk.data) + (1 << 17):
        held = _zstd_streamed_size(chunk.data)  # no frame size to go by: decompress it to learn its size
        if held < 0:
            return None, (f"its uncompressed size says {stated} bytes, more than its {len(chunk.data)} bytes of zstd "
                          f"data can hold (the size is damaged)")
        return _resized(chunk, held), (f"its uncompressed size says {stated} bytes, more than its {len(chunk.data)} "
                                       f"bytes of zstd data can hold; they hold {held} (the size is damaged)")
    return chunk, ""


def _resized(chunk: Chunk, size: int) -> Chunk:
    """``chunk`` with ``size`` as its uncompressed size."""
    return Chunk(compression=chunk.compression, data=chunk.data, message_end_time=chunk.message_end_time,
                 message_start_time=chunk.message_start_time, uncompressed_crc=chunk.uncompressed_crc,
                 uncompressed_size=size)


def _zstd_streamed_size(data: bytes) -> int:
    """How many bytes the zstd ``data`` (whose frame states no size) decompress to, decompressed as a stream (no
    buffer of a stated size is allocated; at most :data:`_ZSTD_MAX_RATIO` times ``data``); -1 when they do not
    decompress."""
    try:
        import zstandard

        return len(zstandard.ZstdDecompressor().decompressobj().decompress(data))
    except Exception:  # noqa: BLE001  (damaged data: the size cannot be learnt from it)
        return -1


class ChunkSizeDamaged(McapError):
    """A chunk whose uncompressed size is damaged beyond what its data can say (:func:`chunk_size_damage`): a
    reader stops at it, as at any record it cannot read, rather than have zstd allocate the size it states."""


def chunk_records(chunk: Chunk) -> Iterator[Any]:
    """The records inside ``chunk``, its CRC checked, decompressed by the uncompressed size its data gives where
    its own field is damaged (:func:`chunk_size_damage`); raises :class:`ChunkSizeDamaged` when no size can be
    trusted. What every reader of gflow's uses in place of ``mcap.stream_reader.breakup_chunk``."""
    sized, why = chunk_size_damage(chunk)
    if sized is None:
        raise ChunkSizeDamaged(why)
    return iter(breakup_chunk(sized, validate_crc=True))


#: no zstd data expands more than this (a 128 KiB block from a 4-byte run-length block, less its header)
_ZSTD_MAX_RATIO = 1 << 15


def record_at_length(f: IO[bytes], at: int, length: int, opcode: int | None = None) -> Framed:
    """The record at byte ``at`` parsed from the ``length`` bytes of its body (``opcode``: the one in its
    frame, read again when not given)."""
    if opcode is None:
        f.seek(at)
        opcode = f.read(1)[0]
    f.seek(at + 9)
    body = f.read(length)
    try:
        return Framed(at, opcode, length, record=_parse(opcode, body))
    except Exception as e:  # noqa: BLE001  (whatever a damaged body makes the parser raise)
        why = (f"{type(e).__name__}: {' '.join(str(e).split())}" if str(e).strip() else
               "its fields run past its length" if isinstance(e, EndOfFile) else type(e).__name__)
        return Framed(at, opcode, length, damage=f"its contents cannot be read ({why})")


def framed_records(f: IO[bytes], size: int) -> Iterator[Framed]:
    """Every record of the MCAP file ``f`` (``size`` bytes, its magic already checked), in file order, up
    to and including the footer (module docstring). A torn end is the last item, with ``torn`` set."""
    at = len(MAGIC)
    resume_at: list[int] | None = None  # the summary's chunk offsets, read at the first damaged frame
    suspect = 0  # the offset of the record before, when its body did not parse (its length may be wrong too)
    floor = 0  # the walk never resumes at or before a chunk it has resumed at already
    while at < size:
        fr = record_at(f, at, size)
        if fr.torn:
            yield fr
            return
        if fr.broken_frame:
            if resume_at is None:
                resume_at = read_summary(f, size).chunk_offsets
            # a record whose body did not parse may have had a wrong length, which led here: resume after it
            fr.skipped_to = next((o for o in resume_at if o > max(suspect or at, floor)), 0)
            yield fr
            if not fr.skipped_to:
                return
            at = floor = fr.skipped_to
            suspect = 0
            continue
        yield fr
        if fr.opcode == Opcode.FOOTER and not fr.damage:
            return
        suspect = at if fr.damage else 0
        at += 9 + fr.length


def _closed(f: IO[bytes], size: int) -> bool:
    """The file ends with the closing magic bytes."""
    if size < 2 * len(MAGIC):
        return False
    f.seek(size - len(MAGIC))
    return f.read(len(MAGIC)) == MAGIC
