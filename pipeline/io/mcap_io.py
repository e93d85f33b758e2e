"""Reading gflow recordings: records in file order, metadata, and a summary for ``gflow info``.

A recording whose writer was killed has no footer; ``make_reader`` recovers nothing from
it, so :func:`iter_records` reads the records in file order, as mcap's ``NonSeekingReader``
does, and yields every complete chunk before the torn end (and reports that it stopped
early). Each chunk is read by :func:`pipeline.io.mcap_framing.chunk_records`, never by the
uncompressed size it states alone: zstd would allocate that size.

A recorder restarted after a crash writes the rest of the run to a new segment file beside
the first one, ``NAME.part1.mcap``, ``NAME.part2.mcap``, ...; :func:`iter_records` reads a
recording's segments after it, as one recording (:func:`segments`).
"""

from __future__ import annotations

import json
import logging
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader

from pipeline.io import damage_notes
from pipeline.io.mcap_framing import (PastEnd, bounded, chunk_records, chunk_size_damage, framed_records, locate,
                                      record_at, torn_at)
from pipeline.io.mcap_writer import MAGIC
from pipeline.io.path_errors import FolderForFile, MissingPath
from pipeline.io.run_sessions import RunSessions

__all__ = ["Record", "iter_records", "recorded_topics", "segments", "segment_path", "read_metadata", "summarize",
           "RecordingSummary", "TruncatedRecording", "Damaged", "SOURCE_KEY", "torn_segments", "torn_cause",
           "check_recording", "damage_cause", "damage_told", "damage_place"]


class TruncatedRecording(Exception):
    """Raised (or reported) when a recording ends in the middle of a record."""


class Damaged(str):
    """What ``on_truncated`` is told when a record fails to read with more of the file after it
    (corrupt, e.g. two writers on one file), rather than at a torn end."""


#: the damaged recordings already said (once per process, however often a command reads one)
_DAMAGE_SAID: set[str] = set()
#: {file: what was found damaged in it}, for every file a reader of this process found damaged
_DAMAGE_FOUND: dict[str, str] = {}


def damage_cause(path: str | Path) -> str:
    """What damage a reader of this process met in recording ``path`` (or a segment of it), as the
    one line that says it ("" when none was met): for a command whose answer (nothing to step, no
    estimate, nothing compared) would otherwise be taken for what the run recorded."""
    for seg in segments(path):
        if str(seg) in _DAMAGE_FOUND:
            return _DAMAGE_FOUND[str(seg)]
    return ""


#: a place a damage report names: "byte 1297", "bytes 8..3012", "bytes 1297-1588"
_PLACE = re.compile(r"\bbytes? \d+(?:(?:\.\.|-)\d+)?")


def damage_place(text: str, path: str | Path) -> str:
    """Where the damage a one-line report ``text`` ("FILE: recording is damaged...", a reader's or
    :func:`pipeline.recording.verify.recording_damage`'s) lies: its first byte offset ("byte 1297"), with the
    segment named when it is not recording ``path`` ("byte 30 of REC.part1.mcap"); "" when it names none."""
    seg, sep, what = text.partition(": recording is damaged")
    m = _PLACE.search(what) if sep else None
    if m is None:
        return ""
    return m.group(0) + ("" if seg == str(path) else f" of {seg}")


def damage_told(text: str) -> None:
    """The damage ``text`` (an ``on_truncated`` report) is said by the command that was told it: the readers of this
    process that meet it later do not warn of it again (a command would name the same damage twice)."""
    if isinstance(text, Damaged):
        _DAMAGE_SAID.add(text)
        damage_notes.told(text)


def _say_damage(text: str) -> None:
    """Warn, once per file, of damage inside a recording that a reader without ``on_truncated`` met:
    what such a command shows or computes stops there, and the file's end (which the commands'
    check for a torn file looks at) is intact, so nothing else would say it."""
    if text not in _DAMAGE_SAID:
        _DAMAGE_SAID.add(text)
        damage_notes.keep(text)  # logged at once, or (gflow) when the command ends, unless its last line said it


# What reading a torn or corrupt file raises: the mcap reader's own errors, struct's (a file torn
# inside a record's opcode and length), and the decompressors' (lz4 raises RuntimeError on an
# incomplete frame; zstandard ZstdError, and OverflowError for a chunk whose uncompressed size is
# damaged to 2**63 or more).
TORN_END_ERRORS: tuple[type[BaseException], ...] = (McapError, EOFError, ValueError, RuntimeError, struct.error,
                                                    OverflowError)
try:
    import zstandard as _zstd

    TORN_END_ERRORS += (_zstd.ZstdError,)
except ImportError:  # zstandard is optional for reading lz4 files
    pass
# ... and what reading the footer of a file shorter than one raises (a seek before its start)
_NO_FOOTER_ERRORS = TORN_END_ERRORS + (OSError,)


#: channel metadata naming the zenoh session (hex id) whose samples the channel holds (the recorder's)
SOURCE_KEY = "gflow.source"


@dataclass(frozen=True)
class Record:
    topic: str
    type: str
    log_ns: int
    publish_ns: int
    seq: int
    data: bytes
    schema: str = ""
    schema_encoding: str = ""
    source: str = ""  # the zenoh session that published it ("" when the recording does not say)


def check_recording(path: str | Path) -> Path:
    """``path`` as a Path when it is an MCAP file; else a one-line error naming it: a folder
    (:class:`~pipeline.io.path_errors.FolderForFile`, an IsADirectoryError), nothing there
    (:class:`~pipeline.io.path_errors.MissingPath`, a FileNotFoundError) or another kind of file
    (:class:`ValueError`). Commands call it to refuse an input before they write anything."""
    p = Path(path)
    if p.is_dir():  # there, so "not found" would send the user looking for a file that exists
        raise FolderForFile(f"{p} is a folder, not a recording file (give an .mcap file)")
    if not p.is_file():
        raise MissingPath(f"recording not found: {p}")
    with open(p, "rb") as f:
        magic = f.read(8)
    if not magic:  # "bad magic bytes b''" had the user look for bytes in a file that has none
        raise ValueError(f"{p} is empty (0 bytes), not an MCAP file")
    if magic != MAGIC and MAGIC.startswith(magic):
        raise ValueError(f"{p} is not an MCAP file yet: it ends after {len(magic)} bytes, inside the MCAP magic "
                         f"bytes (a recording torn before its first record, with nothing to read)")
    if magic != MAGIC:
        raise ValueError(f"{p} is not an MCAP file (bad magic bytes {magic!r})")
    return p


def segment_path(path: str | Path, n: int) -> Path:
    """The n-th segment of a recording (0: the recording itself)."""
    p = Path(path)
    return p if n == 0 else p.with_name(f"{p.stem}.part{n}{p.suffix}")


def segments(path: str | Path) -> list[Path]:
    """The files of one recording: itself, then the segments a restarted recorder wrote."""
    out = [Path(path)]
    n = 1
    while segment_path(path, n).is_file():
        out.append(segment_path(path, n))
        n += 1
    return out


def iter_records(path: str | Path, topics: list[str] | None = None, *, strict: bool = False,
                 on_truncated=None) -> Iterator[Record]:
    """Every message of a recording and its segments, in file (write) order (see :func:`_iter_file`)."""
    for i, seg in enumerate(segments(path)):
        if i > 0 and seg.stat().st_size < 8:  # a restarted recorder that could not write (a full disk, say)
            if on_truncated is not None:
                on_truncated(f"{seg}: an empty segment")
            continue
        yield from _iter_file(seg, topics, strict=strict, on_truncated=on_truncated)


def _iter_file(path: str | Path, topics: list[str] | None = None, *, strict: bool = False,
               on_truncated=None) -> Iterator[Record]:
    """Every message of a recording in file (write) order.

    Parameters
    ----------
    topics : keep only these topics (exact names).
    strict : raise :class:`TruncatedRecording` at a torn end instead of stopping quietly.
    on_truncated : callable(str) told when the file ended early.
    """
    p = check_recording(path)
    want = set(topics) if topics else None
    with open(p, "rb") as f:
        try:
            for schema, channel, msg in _messages(f):
                if want is not None and channel.topic not in want:
                    continue
                yield Record(channel.topic, channel.metadata.get("gflow.type", schema.name if schema else ""),
                             msg.log_time, msg.publish_time, msg.sequence, msg.data,
                             schema.name if schema else "", schema.encoding if schema else "",
                             channel.metadata.get(SOURCE_KEY, ""))
        except TORN_END_ERRORS as e:  # a torn or corrupt end
            try:
                pos, size = f.tell(), p.stat().st_size
            except (OSError, ValueError):
                pos = size = 0
            text: str
            why = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__  # EndOfFile has no message
            if pos < size:  # bytes after the record that failed: the file is damaged, not just cut short
                at, which = _damaged_record(f, pos, size)
                why = _size_damage(f, at, size) or why
                text = Damaged(f"{p}: recording is damaged at byte {at} of {size}{which} ({why}); nothing after it "
                               f"can be read here (`gflow recover` copies every intact chunk, before and after it)")
            elif _closed(p):  # a damaged length had the reader run to the end of a file that was closed
                text = _closed_damage(p, f, e, why, size)
            else:
                why = _cut_short(f, size) or ("EndOfFile" if isinstance(e, PastEnd) else why)
                text = f"{p}: recording ends early ({why}); it was not closed properly (try `gflow recover`)"
            _tell(text, strict, on_truncated)
        else:
            try:
                pos, size = f.tell(), p.stat().st_size
            except (OSError, ValueError):
                pos = size = 0
            if pos < size:  # bytes after the footer (two writers on one file, a copy appended): not read
                _tell(Damaged(f"{p}: recording is damaged: {size - pos} bytes after its closing magic bytes at byte "
                              f"{pos}; they are not read (`gflow verify` says more)"), strict, on_truncated)


def _messages(f) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Every message of the MCAP file ``f`` in file order, with its schema and channel, as mcap's
    ``NonSeekingReader`` reads them (CRCs checked; a record of an opcode MCAP does not define skipped; a message of
    a channel not yet met is an error), each chunk read by :func:`~pipeline.io.mcap_framing.chunk_records`: a
    damaged uncompressed size stops the reading, as other damage does, where mcap's reader would have zstd allocate
    the size it states."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for rec in StreamReader(bounded(f), emit_chunks=True, validate_crcs=True).records:
        for r in chunk_records(rec) if isinstance(rec, Chunk) else (rec,):
            if isinstance(r, Schema):
                schemas[r.id] = r
            elif isinstance(r, Channel):
                if r.schema_id != 0 and r.schema_id not in schemas:
                    raise McapError(f"no schema record found with id {r.schema_id}")
                channels[r.id] = r
            elif isinstance(r, Message):
                if r.channel_id not in channels:
                    raise McapError(f"no channel record found with id {r.channel_id}")
                channel = channels[r.channel_id]
                yield (schemas[channel.schema_id] if channel.schema_id else None), channel, r


def _cut_short(f, size: int) -> str:
    """Where a torn file of ``size`` bytes ends: inside which record, and how much of it the file holds ('the file
    ends inside chunk 3 at byte 1880, 211 of whose 264 bytes it holds'; "" when the frames do not say)."""
    try:
        cut = torn_at(f, size)
    except (OSError, ValueError, struct.error):
        return ""
    return cut.describe() if cut is not None else ""


def _closed_damage(p: Path, f, e: BaseException, why: str, size: int) -> Damaged:
    """What stopped a reader that ran to the end of the closed file ``p`` (``size`` bytes): a damaged length, in
    the record that holds the byte it was read from (:class:`~pipeline.io.mcap_framing.PastEnd`) or else in the
    first record the file's framing finds damaged (its byte, and which record, as ``gflow verify`` names them)."""
    at, which = -1, ""
    try:
        if isinstance(e, PastEnd):
            at, which = _damaged_record(f, e.at + 1, size)
        else:
            first = next((fr for fr in framed_records(f, size) if fr.damage and not fr.torn), None)
            if first is not None:
                at, which = first.offset, f", in the {first.kind} record: {first.damage}"
    except (OSError, ValueError, struct.error):
        at = -1
    if at < 0:
        return Damaged(f"{p}: recording is damaged: a record cannot be read ({why}), yet the file ends as a closed "
                       f"recording does; nothing after the damage can be read (`gflow verify` says where it is, "
                       f"`gflow recover` copies every intact chunk)")
    return Damaged(f"{p}: recording is damaged at byte {at} of {size}{which} ({why}); nothing after it can be read "
                   f"here (`gflow recover` copies every intact chunk, before and after it)")


def _size_damage(f, at: int, size: int) -> str:
    """What is wrong with the uncompressed size of the chunk at byte ``at``, when that is what stopped the reader
    (zstd cannot take a size of 2**63 or more: OverflowError); "" when it is not a chunk, or its size is right."""
    try:
        fr = record_at(f, at, size)
    except (OSError, ValueError, struct.error):
        return ""
    return chunk_size_damage(fr.record)[1] if isinstance(fr.record, Chunk) else ""


def _damaged_record(f, pos: int, size: int) -> tuple[int, str]:
    """Where the damage is that stopped a reader at byte ``pos``: the start of the record that holds it and
    which record that is, as ``gflow verify`` names it (11674447, ', in chunk 7 (bytes 11674447-13774486)');
    else (``pos``, '')."""
    try:
        where = locate(f, size, pos)
    except (OSError, ValueError, struct.error):
        where = None
    return (pos, "") if where is None else (where.offset, f", in {where.describe()}")


def _tell(text: str, strict: bool, on_truncated) -> None:
    """Say where a recording's reading stopped early (see :func:`_iter_file`)."""
    if isinstance(text, Damaged):
        _DAMAGE_FOUND.setdefault(text.split(": recording is damaged", 1)[0], text)
    if strict:
        raise TruncatedRecording(text) from None
    if on_truncated is not None:
        on_truncated(text)
    elif isinstance(text, Damaged):
        _say_damage(text)



def _closed(path: str | Path) -> bool:
    """Whether the file ends with an MCAP footer's closing magic bytes (its writer closed it)."""
    try:
        with open(path, "rb") as f:
            size = f.seek(0, 2)
            f.seek(max(0, size - len(MAGIC)))
            return f.read() == MAGIC and size > 2 * len(MAGIC)
    except OSError:
        return False


def torn_segments(path: str | Path) -> list[str]:
    """The segments of recording ``path`` that do not end with an MCAP footer (their writer was
    killed, or is still writing). Costs a seek per segment, not a read of the file; a file that is
    not MCAP at all, or cannot be opened, is left to the command that reads it to name."""
    torn = []
    for seg in segments(path):
        try:
            with open(seg, "rb") as f:
                if f.read(len(MAGIC)) != MAGIC:
                    continue
                size = f.seek(0, 2)
                f.seek(max(0, size - len(MAGIC)))
                closed = f.read() == MAGIC and size > 2 * len(MAGIC)
        except OSError:
            continue
        if not closed:
            torn.append(str(seg))
    return torn


def torn_cause(path: str | Path) -> str:
    """Why a recording may lack what a command looks for, when a segment of it is torn ("" when every
    one was closed): said in the command's error, so a cut is not taken for what the run recorded
    (or for a file another program wrote)."""
    torn = torn_segments(path)
    if not torn:
        return ""
    which = "it" if torn[0] == str(path) else f"its segment {torn[0]}"
    return (f"{which} ends early, torn where its writer was killed (or is still writing); `gflow recover` "
            f"salvages its complete chunks")


def recorded_topics(path: str | Path) -> list[str]:
    """The topics of a recording and its segments (from the summary where there is one; a torn
    file is read to its last complete chunk)."""
    out: set[str] = set()
    for seg in segments(path):
        p = check_recording(seg) if seg == Path(path) else seg
        summary = None
        with open(p, "rb") as f:
            try:
                summary = make_reader(bounded(f)).get_summary()
            except _NO_FOOTER_ERRORS:
                summary = None
        if summary is not None and summary.channels:
            out.update(c.topic for c in summary.channels.values())
        else:
            out.update(r.topic for r in _iter_file(p))
    return sorted(out)


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The MCAP metadata records, by name. Works on truncated files too."""
    p = check_recording(path)
    out: dict[str, dict[str, str]] = {}
    with open(p, "rb") as f:
        try:
            for md in make_reader(bounded(f)).iter_metadata():
                out[md.name] = dict(md.metadata)
            return out
        except _NO_FOOTER_ERRORS:  # no footer (a killed writer): fall back to reading the records
            out.clear()
    from mcap.records import Metadata

    with open(p, "rb") as f:
        try:  # metadata are never inside a chunk: chunks are passed over, not decompressed
            for rec in StreamReader(bounded(f), emit_chunks=True).records:
                if isinstance(rec, Metadata):
                    out[rec.name] = dict(rec.metadata)
        except TORN_END_ERRORS:  # the torn end of a truncated file
            pass
    return out


@dataclass
class TopicSummary:
    type: str
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    first_seq: int = -1
    last_seq: int = -1
    bytes: int = 0
    seqs: list[int] = field(default_factory=list)

    @property
    def rate_hz(self) -> float:
        if self.count < 2 or self.last_ns <= self.first_ns:
            return 0.0
        return (self.count - 1) * 1e9 / (self.last_ns - self.first_ns)


@dataclass
class RecordingSummary:
    path: str
    messages: int
    start_ns: int
    end_ns: int
    topics: dict[str, TopicSummary]
    schemas: dict[str, str]
    metadata: dict[str, dict[str, str]]
    truncated: str = ""
    segments: list[str] = field(default_factory=list)  # the files of the recording, when more than one
    sessions: RunSessions = field(default_factory=RunSessions)  # the run's zenoh sessions and what came from outside
    damaged: bool = False  # a record failed to read before the end of the file
    damage: str = ""  # the first damage found, as the one line that says it (what, where)

    @property
    def unreadable(self) -> str:
        """Why this recording cannot be trusted as a record of its run ("" when it can): it is
        damaged, or it holds no message it could read."""
        if self.damaged:
            return "the recording is damaged"
        if self.truncated and self.messages == 0:
            return "no message could be read"
        return ""

    @property
    def duration_s(self) -> float:
        return max(0, self.end_ns - self.start_ns) / 1e9

    def to_json(self) -> dict:
        return {
            "path": self.path, "messages": self.messages, "duration_s": round(self.duration_s, 3),
            "truncated": self.truncated or None, "segments": self.segments or None,
            "outside_the_run": self.sessions.to_json() or None,
            "topics": {t: {"type": s.type, "count": s.count, "rate_hz": round(s.rate_hz, 2), "bytes": s.bytes,
                           "first_seq": s.first_seq, "last_seq": s.last_seq} for t, s in self.topics.items()},
            "schemas": self.schemas,
            "metadata": {k: {kk: (json.loads(vv) if vv[:1] in "[{" else vv) for kk, vv in v.items()}
                         for k, v in self.metadata.items()},
        }


def summarize(path: str | Path) -> RecordingSummary:
    """Walk a recording once: per-topic counts, rates, bytes, sequence ranges; schemas; metadata."""
    truncated: list[str] = []
    schemas: dict[str, str] = {}
    topics: dict[str, TopicSummary] = {}
    n = 0
    start = end = 0
    sessions = RunSessions()
    for r in iter_records(path, on_truncated=truncated.append):
        sessions.add(r)
        key = f"{r.topic}"
        s = topics.get(key)
        if s is None:
            s = topics[key] = TopicSummary(type=r.type, first_ns=r.log_ns, first_seq=r.seq)
        elif r.type != s.type and r.type not in s.type.split("+"):
            s.type = f"{s.type}+{r.type}"
        s.count += 1
        s.last_ns = r.log_ns
        s.last_seq = r.seq
        s.bytes += len(r.data)
        if r.schema:
            schemas[r.schema] = r.schema_encoding
        n += 1
        start = r.log_ns if start == 0 else min(start, r.log_ns)
        end = max(end, r.log_ns)
    segs = segments(path)
    return RecordingSummary(str(path), n, start, end, topics, schemas, read_metadata(path),
                            "; ".join(truncated), [str(p) for p in segs] if len(segs) > 1 else [], sessions,
                            damaged=any(isinstance(t, Damaged) for t in truncated),
                            damage=next((t for t in truncated if isinstance(t, Damaged)), ""))
