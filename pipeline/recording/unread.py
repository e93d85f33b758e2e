"""What of a damaged recording the readers could not read: the chunks they passed over or never reached, and
the messages in them, as far as the file itself can tell (``gflow info``'s count of what it left out).

The commands that describe a recording read it with mcap's reader (:func:`pipeline.io.mcap_io.iter_records`),
which skips a record whose opcode MCAP does not define (a chunk passed over, its messages missing from the
count) and stops at a record it cannot read (nothing after it read). Here each file is read twice more:

* as that reader reads it, chunk by chunk, to learn which chunks it took its messages from;
* by its framing (:func:`pipeline.io.mcap_framing.framed_records`, as ``gflow recover`` walks it), with the
  summary's chunk indexes, to find every chunk the file holds and count each one's messages: an intact chunk's
  by reading them, a damaged one's from the message indexes written after it (the chunk index names them).

Where no message index of a damaged chunk can be read, the statistics (when every file has them) give the
count: the messages they list less those read. A count that cannot be known (nor that way: no summary, a file
that ends early, a damaged frame in a file with no summary hiding where the next chunks are) is said to be a
lower bound, never guessed.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, MessageIndex
from mcap.stream_reader import StreamReader, breakup_chunk

from pipeline.io.mcap_framing import (OPCODE_NAMES, Cut, Summary, bounded, chunk_records, chunk_size_damage,
                                      framed_records, read_summary, record_at, record_at_length, torn_at)
from pipeline.io.mcap_io import TORN_END_ERRORS, segments, torn_segments
from pipeline.io.mcap_writer import MAGIC

__all__ = ["NotRead", "not_read", "cut_short"]

#: at most this many chunks are named by their byte offset in a line
NAMED = 5


@dataclass
class NotRead:
    """The chunks of a recording the readers did not read, and the messages in them.

    ``messages`` counts the messages known to be in those chunks; ``exact`` says it is their number (False: at
    least that many). ``more_chunks``: there may be more chunks than those found: the file ends early (what
    its unfinished last record held cannot be known), or a damaged frame in a file with no summary hides where
    the next chunks start. ``listed`` is the message count the statistics of every file state (-1: a file has
    none readable); ``read`` the messages the reader took, counted chunk by chunk here.
    """

    chunks: list[tuple[str, int]] = field(default_factory=list)  # (file, byte offset) of each chunk not read
    messages: int = 0
    exact: bool = True
    more_chunks: bool = False
    listed: int = -1
    read: int = 0
    files: int = 1  # the recording's files: its segments
    cuts: list[tuple[str, Cut]] = field(default_factory=list)  # (file, where it ends) of each torn file
    summary_damaged: bool = False  # a summary's CRC does not match: its statistics' count is not used

    def where(self, path: str) -> str:
        """'byte 1297', 'bytes 1297, 1588', a segment's as 'byte 30 of REC.part1.mcap' (the first NAMED)."""
        named = [f"{off}" if seg == str(path) else f"{off} of {seg}" for seg, off in self.chunks[:NAMED]]
        more = ", ..." if len(self.chunks) > NAMED else ""
        return f"byte{'s' * (len(self.chunks) > 1)} {', '.join(named)}{more}"

    def held(self) -> str:
        """'2 messages', 'at least 2 messages' or 'an unknown number of messages'."""
        if not self.exact and not self.messages:
            return "an unknown number of messages"
        return f"{'' if self.exact else 'at least '}{self.messages} message{'s' * (self.messages != 1)}"

    def line(self, path: str, read: int) -> str:
        """What was not read, for ``gflow info``'s ``not read:`` line (``read``: the messages it counted)."""
        n = len(self.chunks)
        parts = [f"{'at least ' * self.more_chunks}{n} chunk{'s' * (n != 1)} (at {self.where(path)})"] if n else []
        if not n and self.more_chunks:
            parts.append("chunks after a damaged frame, whose place no summary gives")
        parts += [self._cut(seg, cut, path) for seg, cut in self.cuts if cut.holds_messages]
        text = " and ".join(parts) + f" with {self.held()}" if parts else "no chunk: every chunk was read"
        text += "".join(f"; {self._cut(seg, cut, path)}" for seg, cut in self.cuts if not cut.holds_messages)
        lists = "the summary lists" if self.files == 1 else "their summaries list"
        if self.summary_damaged:
            return text + f"; {read} messages read (no count of the summary's is used: its CRC does not match)"
        return text + (f"; {read} of the {self.listed} messages {lists} were read" if self.listed >= 0 else "")

    @staticmethod
    def _cut(seg: str, cut: Cut, path: str) -> str:
        """Where the torn file ``seg`` ends ('the chunk the file ends inside, chunk 3 at byte 1880, ...')."""
        return cut.part() + ("" if seg == str(path) else f" ({seg})")

    def short(self) -> str:
        """What was not read, for ``gflow info``'s line on stderr: '1 chunk with 2 messages not read'."""
        n, cut = len(self.chunks), [c for _, c in self.cuts if c.holds_messages]
        if not n and not cut:
            return "chunks after the damage not read, how many unknown" if self.more_chunks else "every chunk read"
        parts = [f"{'at least ' * self.more_chunks}{n} chunk{'s' * (n != 1)}"] if n else []
        if cut:
            what = "chunk" if all(c.opcode == Opcode.CHUNK and c.length >= 0 for c in cut) else "record"
            parts.append(f"{len(cut)} {what}{'s' * (len(cut) != 1)} cut short")
        return f"{' and '.join(parts)} with {self.held()} not read"

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``gflow info --json``'s ``not_read``."""
        return {"chunks": len(self.chunks), "more_chunks": self.more_chunks,
                "chunks_at": [{"file": seg, "byte": off} for seg, off in self.chunks],
                "messages": self.messages if self.exact or self.messages else None, "messages_exact": self.exact,
                "listed": self.listed if self.listed >= 0 else None, "summary_damaged": self.summary_damaged,
                "cut": [dict(cut.to_json(), file=seg) for seg, cut in self.cuts]}


@dataclass
class _ReaderPass:
    """What mcap's reader takes from one file: the chunks it reads (their offsets), its messages, the records
    of an opcode MCAP does not define that it skips (offset -> messages, when the record is a chunk whose
    opcode alone is damaged; -1 when it is not known to be one), and whether it read to the end."""

    read: set[int] = field(default_factory=set)
    messages: int = 0
    skipped: dict[int, int] = field(default_factory=dict)
    complete: bool = False  # it read to the file's end


def _skipped(f: IO[bytes], at: int, out: dict[int, int]) -> int:
    """The records from byte ``at`` on that the reader skips (their opcodes are no MCAP record's), into ``out``:
    each read again as a chunk, which its own fields and CRC confirm (its messages counted), or -1 (not known to
    be one); returns the offset of the record after them, the one the reader reads."""
    back = f.tell()
    while True:
        f.seek(at)
        head = f.read(9)
        if len(head) < 9 or head[0] in OPCODE_NAMES:
            break
        (length,) = struct.unpack("<Q", head[1:])
        if at + 9 + length > f.seek(0, 2):  # the reader cannot skip past the end either: it stops there
            break
        fr = record_at_length(f, at, length, Opcode.CHUNK)
        out[at] = -1
        if isinstance(fr.record, Chunk):
            try:
                sized = chunk_size_damage(fr.record)[0]
                if sized is not None:
                    out[at] = sum(isinstance(r, Message) for r in breakup_chunk(sized, validate_crc=True))
            except TORN_END_ERRORS:
                pass
        if out[at] < 0 and isinstance(record_at_length(f, at, length, Opcode.MESSAGE_INDEX).record, MessageIndex):
            del out[at]  # a message index whose opcode alone is damaged: no messages of its own
        at += 9 + length
    f.seek(back)
    return at


def _reader_pass(f: IO[bytes]) -> _ReaderPass:
    """The file read as :func:`pipeline.io.mcap_io.iter_records` reads it (``NonSeekingReader``): a record of an
    opcode MCAP does not define is skipped, and the reading stops at the first record, chunk or message it
    cannot read (a message of a channel it has not met)."""
    f.seek(0)
    records = iter(StreamReader(bounded(f), emit_chunks=True, validate_crcs=True).records)
    out = _ReaderPass()
    channels: set[int] = set()
    at = len(MAGIC)
    while True:
        try:
            rec = next(records)
        except StopIteration:
            out.complete = True
            break
        except TORN_END_ERRORS:
            break
        start = _skipped(f, at, out.skipped)  # where the record it returned starts
        inner = [rec]
        if isinstance(rec, Chunk):
            try:
                inner = list(chunk_records(rec))  # as the reader reads it
            except TORN_END_ERRORS:
                break
        for r in inner:
            if isinstance(r, Channel):
                channels.add(r.id)
            elif isinstance(r, Message):
                if r.channel_id not in channels:
                    return out
                out.messages += 1
        if isinstance(rec, Chunk):
            out.read.add(start)
        at = f.tell()
    return out


def _indexed(f: IO[bytes], size: int, summary: Summary, offset: int) -> tuple[int, bool] | None:
    """(messages, all counted) of the chunk at ``offset`` by the message indexes its chunk index names;
    None when the summary has no chunk index of it."""
    ci = summary.chunk_indexes.get(offset)
    if ci is None:
        return None
    n, exact = 0, True
    for at in ci.message_index_offsets.values():
        fr = record_at(f, at, size) if 0 < at < size else None
        if fr is not None and isinstance(fr.record, MessageIndex):
            n += len(fr.record.records)
        else:
            exact = False
    return n, exact


def _chunk_counts(f: IO[bytes], size: int, summary: Summary) -> tuple[dict[int, tuple[int, bool]], int]:
    """({offset: (messages, exact)} of every chunk the walk finds, the damaged frame it stopped at (-1: none):
    with no summary to say where the next chunk starts, what follows it is hidden from the walk.
    An intact chunk's messages are counted; a damaged one's come from the message indexes its chunk index
    names, or else (no summary) from those the walk meets right after it; not exact when none can be read."""
    counts: dict[int, tuple[int, bool]] = {}
    indexes: dict[int, tuple[int, bool]] = {}  # a damaged chunk's: (messages they list, every one read)
    after: int | None = None  # the damaged chunk whose message indexes may follow
    hidden = -1
    starts: set[int] = set()  # where the records the walk met start
    gaps: list[tuple[int, int]] = []  # the bytes it passed over at a damaged frame
    for fr in framed_records(f, size):
        starts.add(fr.offset)
        if fr.broken_frame:
            gaps.append((fr.offset, fr.skipped_to or size))
        if fr.opcode == Opcode.MESSAGE_INDEX and after is not None:
            n, ok = indexes.get(after, (0, True))
            mi = fr.record if isinstance(fr.record, MessageIndex) else None
            indexes[after] = (n + (len(mi.records) if mi is not None else 0), ok and mi is not None)
            continue
        after = None
        if fr.broken_frame and not fr.skipped_to:
            hidden = fr.offset
        if fr.opcode != Opcode.CHUNK or fr.broken_frame:
            continue
        counts[fr.offset] = (0, False)
        if isinstance(fr.record, Chunk):
            try:
                sized = chunk_size_damage(fr.record)[0]  # as recover reads it
                if sized is not None:
                    counts[fr.offset] = (sum(isinstance(r, Message) for r in breakup_chunk(sized, validate_crc=True)),
                                         True)
                    continue
            except TORN_END_ERRORS:  # its CRC or its compressed data is damaged
                pass
        after = fr.offset
    for off in set(summary.chunk_offsets) | set(counts):  # a damaged chunk, or one passed over (a damaged frame)
        if off in counts and counts[off][1]:
            continue
        if off not in starts and not any(a <= off < b for a, b in gaps):
            continue  # a damaged chunk index: no record starts there
        by_index = _indexed(f, size, summary, off)
        if by_index is None and off in indexes:
            by_index = indexes[off]
        counts[off] = by_index or (0, False)
    return counts, hidden


def _segment(seg: Path) -> NotRead:
    """What mcap's reader does not read of one file."""
    size = seg.stat().st_size
    with open(seg, "rb") as f:
        summary = read_summary(f, size)
        reader = _reader_pass(f)
        counts, hidden = _chunk_counts(f, size, summary)
        f.seek(max(0, size - len(MAGIC)))
        torn = size <= 2 * len(MAGIC) or f.read() != MAGIC  # what its last, unfinished record held is unknown
        cut = torn_at(f, size) if torn and size >= len(MAGIC) else None
    if cut is not None:
        counts.pop(cut.offset, None)  # named as the record the file ends inside, not as a chunk passed over
    unknown = False  # a record the reader skipped that may be a chunk (no summary lists the chunks)
    for off, n in reader.skipped.items():  # a chunk whose opcode alone is damaged, which the walk stopped at
        if n >= 0 and not counts.get(off, (0, False))[1]:
            counts[off] = (n, True)
        unknown = unknown or (n < 0 and not summary.chunk_indexes)
    lost = sorted(set(counts) - reader.read)
    more = (torn and cut is None) or unknown or (hidden >= 0 and not reader.complete)
    return NotRead(chunks=[(str(seg), off) for off in lost], messages=sum(counts[off][0] for off in lost),
                   exact=all(counts[off][1] for off in lost) and not more and not (cut and cut.holds_messages),
                   more_chunks=more, listed=summary.messages if summary.intact else -1, read=reader.messages,
                   summary_damaged=not summary.intact,
                   cuts=[(str(seg), cut)] if cut is not None else [])


def cut_short(path: str | Path, read: int) -> NotRead | None:
    """What a torn recording ``path`` that is not damaged leaves unread: the record each torn file (segment) ends
    inside, found by the frames alone (9 bytes read a record, not the whole file again, as :func:`not_read`
    reads it); ``read`` is the messages the reader took. None when no file is torn."""
    cuts: list[tuple[str, Cut]] = []
    for seg in torn_segments(path):
        with open(seg, "rb") as f:
            cut = torn_at(f, f.seek(0, 2))
        if cut is not None:
            cuts.append((seg, cut))
    if not cuts:
        return None
    return NotRead(exact=not any(cut.holds_messages for _, cut in cuts), read=read, files=len(segments(path)),
                   cuts=cuts)


def not_read(path: str | Path) -> NotRead:
    """What mcap's reader does not read of recording ``path`` and its segments (see the module docstring).

    Where the chunks' own counts fall short of knowing (a chunk none of whose message indexes can be read), the
    statistics of every file, when each has them, give the number: those they list less those read.
    """
    parts = [_segment(seg) for seg in segments(path)]
    total = NotRead(chunks=[c for p in parts for c in p.chunks], messages=sum(p.messages for p in parts),
                    exact=all(p.exact for p in parts), more_chunks=any(p.more_chunks for p in parts),
                    listed=sum(p.listed for p in parts) if all(p.listed >= 0 for p in parts) else -1,
                    read=sum(p.read for p in parts), files=len(parts), cuts=[c for p in parts for c in p.cuts],
                    summary_damaged=any(p.summary_damaged for p in parts))
    if not total.exact and total.listed >= total.read + total.messages:
        total.messages, total.exact = total.listed - total.read, True  # as the statistics list them
    return total
