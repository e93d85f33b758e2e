"""A chunked MCAP writer whose per-message path does not copy the payload.

It writes the same records, in the same order, as ``mcap.writer.Writer`` with its default
options (chunked, all indexes, statistics, summary offsets, chunk CRCs): for the same calls
the two give byte-identical files (``tests/test_mcap_writer.py``), and every MCAP reader
reads them. What differs is the cost per message. ``mcap.writer.Writer`` copies each payload
into a ``BytesIO`` (which grows by reallocation), copies the chunk out of it, and copies the
compressed chunk into a second ``BytesIO`` before writing it. Here a message is a 31-byte
record header and a reference to the payload; at the end of a chunk the pieces are joined
once (compression needs one buffer; with no compression they are written as they are),
the CRC is computed with ISA-L's CRC-32 when ``isal`` is installed (about 4x zlib's here),
and the chunk record is written as its header and the compressed bytes, not concatenated.

Everything is written on the caller's thread. A writer thread (CRC, compression and writes
overlapping the caller's receiving) was tried and measured: no gain on 2 cores, where the
publisher, zenoh's threads and the recorder already share both (``bench/bench_recorder.py``).

Memory: the open chunk holds references to at most ``chunk_size`` bytes of payloads (plus
one message), the join and the compressed copy exist only while the chunk is closed.
"""

from __future__ import annotations

import ctypes
import os
import struct
from collections import defaultdict
from typing import IO, Callable

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex, Schema, Statistics,
                          SummaryOffset)

try:  # ISA-L's CRC-32 (the zlib polynomial, same values), much faster than zlib's
    from isal.isal_zlib import crc32 as _crc32
except ImportError:  # pragma: no cover - isal is a dependency; zlib is the fallback
    from zlib import crc32 as _crc32

__all__ = ["ChunkWriter", "COMPRESSIONS", "crc32"]


def _sync_file_range() -> Callable[[int, int, int], int] | None:
    """Linux's ``sync_file_range(fd, offset, nbytes, WAIT_BEFORE | WRITE | WAIT_AFTER)``: write
    back a range of a file and wait until it is clean, the rest of the file untouched (unlike
    fdatasync). None where libc does not have it."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).sync_file_range
    except (AttributeError, OSError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return lambda fd, offset, nbytes: fn(fd, offset, nbytes, 1 | 2 | 4)


_write_back = _sync_file_range()

#: the first and last bytes of every MCAP file (the header's and the footer's magic); the one copy the project reads
MAGIC = b"\x89MCAP0\r\n"
crc32: Callable[..., int] = _crc32

DROP_EVERY = 4 * 2**20  # bytes written between two page-cache drops
DROP_WINDOW = 64 * 2**20  # the span before the write position that each drop covers
_MSG = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log time, publish time
_MSG_FIXED = 22  # the message record's fields before the data
_CHUNK = struct.Struct("<BQQQQI")  # opcode, record length, start, end, uncompressed size, uncompressed crc


def _lz4(data: bytes) -> bytes:
    import lz4.frame

    return lz4.frame.compress(data)


def _zstd(data: bytes) -> bytes:
    import zstandard

    return zstandard.compress(data)


COMPRESSIONS: dict[str, Callable[[bytes], bytes] | None] = {"lz4": _lz4, "zstd": _zstd, "": None}


def _record(rec) -> bytes:
    b = RecordBuilder()
    rec.write(b)
    return b.end()


class ChunkWriter:
    """Write an MCAP file to ``stream`` (binary, with ``tell``): the calls of ``mcap.writer.Writer``.

    Parameters
    ----------
    stream : the file, positioned at its start.
    chunk_size : a chunk is closed once its uncompressed records exceed this many bytes.
    compression : "lz4", "zstd" or "" (none).
    """

    def __init__(self, stream: IO[bytes], chunk_size: int = 1024 * 1024, compression: str = "lz4",
                 drop_cache: bool = False) -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(f"unknown MCAP compression {compression!r}")
        self._f = stream
        self.chunk_size = int(chunk_size)
        self.compression = compression
        self._compress = COMPRESSIONS[compression]
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: defaultdict[int, int] = defaultdict(int)
        self.message_count = 0
        self._start_time = 0
        self._end_time = 0
        self.metadata_count = 0
        # the open chunk: its records as pieces, their total length, per-channel (log time, offset) pairs
        self._parts: list[bytes | bytearray | memoryview] = []
        self._len = 0
        self._n = 0
        self._index: dict[int, list[int]] = {}
        self._c_start = 0
        self._c_end = 0
        self.good_offset = 0  # file offset after the last flushed chunk (see flush)
        self.good_messages = 0  # messages in the file up to there
        self.drop_cache = drop_cache
        self._dropped_at = 0

    # -- records outside chunks ----------------------------------------------------------------
    def start(self, profile: str = "", library: str = "gflow") -> None:
        self._f.write(MAGIC + _record(Header(profile, library)))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        rec = _record(Metadata(name=name, metadata=data))
        self.metadata_count += 1
        self._metadata_indexes.append(MetadataIndex(offset=self._f.tell(), length=len(rec), name=name))
        self._f.write(rec)

    # -- records in chunks ---------------------------------------------------------------------
    def _add(self, rec: bytes) -> None:
        self._parts.append(rec)
        self._len += len(rec)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        s = self._schemas[sid] = Schema(id=sid, data=data, encoding=encoding, name=name)
        self._add(_record(s))
        self._maybe_close_chunk()
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str] | None = None) -> int:
        cid = len(self._channels) + 1
        c = self._channels[cid] = Channel(id=cid, topic=topic, message_encoding=message_encoding, schema_id=schema_id,
                                          metadata=dict(metadata or {}))
        self._add(_record(c))
        self._maybe_close_chunk()
        return cid

    def add_message(self, channel_id: int, log_time: int, data: bytes | bytearray | memoryview, publish_time: int,
                    sequence: int = 0) -> None:
        """Add one message to the open chunk. ``data`` is kept by reference until the chunk is
        written: it must not change meanwhile (bytes never do)."""
        n = len(data)
        if self.message_count == 0:
            self._start_time = log_time
        elif log_time < self._start_time:
            self._start_time = log_time
        if log_time > self._end_time:
            self._end_time = log_time
        self._counts[channel_id] += 1
        self.message_count += 1
        if self._n == 0:
            self._c_start = self._c_end = log_time
        else:
            if log_time < self._c_start:
                self._c_start = log_time
            if log_time > self._c_end:
                self._c_end = log_time
        idx = self._index.get(channel_id)
        if idx is None:
            idx = self._index[channel_id] = []
        idx.append(log_time)
        idx.append(self._len)
        self._n += 1
        self._parts.append(_MSG.pack(Opcode.MESSAGE, _MSG_FIXED + n, channel_id, sequence, log_time, publish_time))
        self._parts.append(data)
        self._len += _MSG.size + n
        if self._len > self.chunk_size:
            self.close_chunk()

    def _maybe_close_chunk(self) -> None:
        if self._len > self.chunk_size:
            self.close_chunk()

    def close_chunk(self) -> None:
        """Write the open chunk (if it has a message), then its message indexes."""
        if self._n == 0:
            return
        job = (self._parts, self._len, self._index, self._c_start, self._c_end)
        self._parts = []
        self._len = 0
        self._n = 0
        self._index = {}
        self._write_chunk(*job)

    def _write_chunk(self, parts: list, size: int, index: dict[int, list[int]], c_start: int, c_end: int) -> None:
        crc = 0
        for p in parts:
            crc = _crc32(p, crc)
        if self._compress is None:
            body: list = parts
            body_len = size
        else:
            data = self._compress(b"".join(parts))
            body, body_len = [data], len(data)
        comp = self.compression.encode()
        start = self._f.tell()
        head = _CHUNK.pack(Opcode.CHUNK, 8 + 8 + 8 + 4 + 4 + len(comp) + 8 + body_len, c_start, c_end,
                           size, crc) + struct.pack("<I", len(comp)) + comp + struct.pack("<Q", body_len)
        self._f.write(head)
        for b in body:
            self._f.write(b)
        chunk_len = len(head) + body_len
        index_start = start + chunk_len
        offsets: dict[int, int] = {}
        pieces = []
        at = index_start
        for cid, pairs in index.items():
            offsets[cid] = at
            rec = struct.pack(f"<BQHI{len(pairs)}Q", Opcode.MESSAGE_INDEX, 6 + 8 * len(pairs), cid, 8 * len(pairs),
                              *pairs)
            pieces.append(rec)
            at += len(rec)
        self._f.write(b"".join(pieces))
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=c_start, message_end_time=c_end, chunk_start_offset=start,
            chunk_length=chunk_len, message_index_offsets=offsets, message_index_length=at - index_start,
            compression=self.compression, compressed_size=body_len, uncompressed_size=size))
        if self.drop_cache:
            self._drop_written(at)

    def _drop_written(self, end: int) -> None:
        """Every ``DROP_EVERY`` bytes, ask the kernel to write back, and to forget, the last
        ``DROP_WINDOW`` bytes: the first call on a range starts its write-back, a later one
        frees its pages once they are clean (dirty pages are never dropped). The older half of
        the window, set writing several calls ago, is first waited for until it is clean
        (``sync_file_range``; usually it already is), so a disk slower than the writes cannot
        leave the recording in the page cache: the wait holds the recorder back instead, as a
        full inbox holds back the publishers."""
        if end - self._dropped_at < DROP_EVERY:
            return
        self._dropped_at = end
        lo = max(0, end - DROP_WINDOW)
        mid = max(lo, end - DROP_WINDOW // 2)
        try:
            self._f.flush()
            fd = self._f.fileno()
            if _write_back is not None and mid > lo:
                _write_back(fd, lo, mid - lo)
            os.posix_fadvise(fd, lo, end - lo, os.POSIX_FADV_DONTNEED)
        except (AttributeError, OSError, ValueError):  # no fadvise (not Linux), or not a real file
            self.drop_cache = False

    def flush(self) -> None:
        """Write the open chunk (if it has a message) and flush the stream (no fsync); then
        :attr:`good_offset` and :attr:`good_messages` say where the file is complete."""
        self.close_chunk()
        self._f.flush()
        self.good_offset = self._f.tell()
        self.good_messages = self.message_count

    # -- the end -------------------------------------------------------------------------------
    def finish(self) -> None:
        """Write the open chunk, the data end, the summary, the footer and the closing magic
        (as ``mcap.writer.Writer.finish``). The stream is left open."""
        self.close_chunk()
        self._f.write(_record(DataEnd(0)))
        summary_start = self._f.tell()
        b = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records) -> None:
            at = b.count
            for r in records:
                r.write(b)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + at,
                                         group_length=b.count - at))

        stats = Statistics(attachment_count=0, channel_count=len(self._channels),
                           channel_message_counts=dict(self._counts), chunk_count=len(self._chunk_indexes),
                           message_count=self.message_count, metadata_count=self.metadata_count,
                           message_start_time=self._start_time, message_end_time=self._end_time,
                           schema_count=len(self._schemas))
        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = summary_start + b.count
        for o in offsets:
            o.write(b)
        summary = b.end()
        crc = _crc32(summary)
        crc = _crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start if summary else 0, offset_start), crc)
        self._f.write(summary)
        self._f.write(_record(Footer(summary_start=summary_start if summary else 0, summary_offset_start=offset_start,
                                     summary_crc=crc)))
        self._f.write(MAGIC)
