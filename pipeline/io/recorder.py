"""MCAP recording of every message: one channel per (topic, message type, publishing zenoh
session), a JSON schema per message type, chunked and compressed, flushed on a timer.

Each record keeps the payload bytes exactly as they travelled (so a re-run can be compared
bit for bit), the topic, the log time (when the recorder received it), the publish time
(from the sample's attachment) and the sequence number (the frame index).

``ChunkWriter.flush()`` (``pipeline/io/mcap_writer.py``) closes the open chunk; calling it
at least every ``flush_interval`` seconds bounds what a killed recorder loses. The graph and the
configuration are stored as MCAP metadata records named ``gflow.graph`` and ``gflow.config``.

Disk full: the recorder keeps a small reserve file beside the recording. When a write fails
for lack of space (ENOSPC, EDQUOT, EFBIG), it frees the reserve, cuts the file back to the
end of the last chunk it flushed, ends it with a data-end record, a footer and the closing
magic (a valid MCAP file without a summary, readable to that point) and raises
:class:`DiskFull`.

Page cache: a recording is written once and not read back while it is written, so the
writer (``pipeline/io/mcap_writer.py``) drops what it has written from the page cache as it
goes (``posix_fadvise`` DONTNEED on the last ``DROP_WINDOW`` bytes every ``DROP_EVERY`` bytes: the first call
starts the write-back, a later one frees the pages once they are clean; the older half of the
window is waited for until clean first, so a disk slower than the writes holds the recorder back
rather than leaving the file in the cache). The recording then
holds a bounded amount of page cache whatever its length, and the kernel recycles the same
pages instead of taking fresh ones: measured on this project's 2-core VM, where free memory
is handed back to the hypervisor (virtio-balloon free page reporting) and every fresh page
costs a fault on the host, a 600 MB file written in 4 MiB blocks went from 270-320 MB/s to
1,000-1,900 MB/s, and perf had found half of the recorder's CPU in the kernel's copy into
fresh page-cache pages (``bench/bench_recorder.py`` prints the recorder's CPU per message).
"""

from __future__ import annotations

import builtins  # the field `bytes` below hides the type in the class body
import errno
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import msgspec
from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer

from pipeline.io.mcap_io import SOURCE_KEY
from pipeline.io.mcap_writer import MAGIC, ChunkWriter
from pipeline.io.recording_files import create_new

from gflow_msgs.messages import FOXGLOVE_TYPES, MESSAGE_TYPES, json_schema
from gflow_msgs.foxglove import FOXGLOVE_SCHEMAS, foxglove_schema

__all__ = ["McapRecorder", "DiskFull", "peek_type", "MESSAGE_ENCODING", "SCHEMA_ENCODING"]

RESERVE_BYTES = 256 * 1024
_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


class DiskFull(OSError):
    """The recording's disk is full: the file was closed at its last complete chunk."""

MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
SCHEMA_PREFIX = "gflow."


class _Peek(msgspec.Struct):
    type: str = ""


_peek = msgspec.msgpack.Decoder(_Peek)


def peek_type(payload: bytes) -> str:
    """The message type tag of a payload, without decoding the rest ('' if unreadable)."""
    try:
        return _peek.decode(payload).type
    except msgspec.DecodeError:
        return ""


@dataclass
class McapRecorder:
    """Write messages to an MCAP file.

    Parameters
    ----------
    path : output file, created here (a file that exists is an error; parent folders are created).
    flush_interval : seconds between chunk flushes (<= 0.5 s by default).
    compression : "lz4" (default, fast), "zstd" or "none".
    chunk_size : bytes per chunk before an automatic flush.
    """

    path: str | os.PathLike
    flush_interval: float = 0.5
    compression: str = "lz4"
    chunk_size: int = 4 * 1024 * 1024
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    _f: IO[bytes] | None = None
    _w: ChunkWriter | None = None
    _schemas: dict[str, int] = field(default_factory=dict)
    _channels: dict[tuple[str, str, str], int] = field(default_factory=dict)
    _last_flush: float = 0.0
    messages: int = 0
    bytes: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)
    _good: int = 0  # file offset after the last complete flush
    _good_messages: int = 0
    _reserve: Path | None = None
    drop_cache: bool = True  # drop what was written from the page cache (see the module docstring)

    def open(self) -> "McapRecorder":
        comp = {"lz4": "lz4", "zstd": "zstd", "none": ""}.get(self.compression)
        if comp is None:
            raise ValueError(f"unknown MCAP compression {self.compression!r}; use lz4, zstd or none")
        p = Path(self.path)
        p.parent.mkdir(parents=True, exist_ok=True)
        reserve = p.with_name(f".{p.name}.reserve")
        try:
            with open(reserve, "wb") as f:
                f.write(b"\0" * RESERVE_BYTES)
        except OSError as e:
            reserve.unlink(missing_ok=True)
            if e.errno in _FULL:
                raise DiskFull(e.errno, f"no space left for a recording in {p.parent}") from None
            raise
        self._reserve = reserve
        try:
            self._f = create_new(p)  # never over another recording (pipeline/io/recording_files.py)
        except FileExistsError:
            reserve.unlink(missing_ok=True)
            self._reserve = None
            raise
        self._w = ChunkWriter(self._f, chunk_size=self.chunk_size, compression=comp, drop_cache=self.drop_cache)
        self._guard(self._start)
        self._last_flush = time.monotonic()
        return self

    def _start(self) -> None:
        assert self._w is not None and self._f is not None
        self._w.start(profile="", library="gflow")
        for name, data in self.metadata.items():
            self._w.add_metadata(name, data)
        self._w.flush()
        self._good = self._w.good_offset

    def _guard(self, fn, *args, **kw):
        """Run a write; on a full disk, close the file at its last good chunk and raise DiskFull."""
        try:
            return fn(*args, **kw)
        except OSError as e:
            if e.errno not in _FULL:
                raise
            self._close_at_good()
            raise DiskFull(e.errno, f"the disk is full: {self.path} closed after {self._good_messages} messages "
                                    f"({self._good} bytes), readable to there") from None

    def _close_at_good(self) -> None:
        """Cut the file back to the last complete chunk and end it (no summary) with the space the reserve held."""
        if self._reserve is not None:
            self._reserve.unlink(missing_ok=True)
            self._reserve = None
        f, w, self._f, self._w = self._f, self._w, None, None
        if w is not None:
            self._good, self._good_messages = w.good_offset, w.good_messages
        if f is None:
            return
        try:
            f.close()  # its buffer may fail to flush: that part is cut off below anyway
        except OSError:
            pass
        b = RecordBuilder()
        DataEnd(0).write(b)
        Footer(0, 0, 0).write(b)
        with open(self.path, "r+b") as g:
            g.truncate(self._good)
            g.seek(self._good)
            g.write(b.end() + MAGIC)

    def __enter__(self) -> "McapRecorder":
        return self.open() if self._w is None else self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        assert self._w is not None, "recorder is not open"
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def _channel(self, topic: str, type_name: str, source: str = "") -> int:
        key = (topic, type_name, source)
        cid = self._channels.get(key)
        if cid is not None:
            return cid
        assert self._w is not None
        sid = self._schemas.get(type_name)
        fox = FOXGLOVE_TYPES.get(type_name)
        if sid is None:
            typ = MESSAGE_TYPES.get(type_name)
            if fox is not None:  # Foxglove well-known schema, JSON
                sid = self._w.register_schema(FOXGLOVE_SCHEMAS[fox], SCHEMA_ENCODING,
                                              json.dumps(foxglove_schema(fox)).encode())
            elif typ is None:  # unreadable payload: keep it, under a schema-less channel
                sid = 0
            else:
                sid = self._w.register_schema(SCHEMA_PREFIX + type_name, SCHEMA_ENCODING,
                                              json.dumps(json_schema(typ)).encode())
            self._schemas[type_name] = sid
        meta = {"gflow.type": type_name or "unknown"}
        if source:  # the zenoh session that published on it (pipeline.runtime.transport.sample_source)
            meta[SOURCE_KEY] = source
        cid = self._w.register_channel(topic, "json" if fox is not None else MESSAGE_ENCODING, sid, metadata=meta)
        self._channels[key] = cid
        return cid

    def write(self, topic: str, payload: builtins.bytes, seq: int, publish_ns: int = 0, log_ns: int | None = None,
              type_name: str = "", source: str = "") -> None:
        """Record one payload exactly as received. ``type_name`` comes with the sample; without
        it the MessagePack type tag is read. ``source`` is the zenoh session that published it
        (a channel of its own per session, its metadata ``gflow.source``; "" when not known)."""
        assert self._w is not None, "recorder is not open"
        log_ns = time.time_ns() if log_ns is None else log_ns
        if not type_name or (type_name not in MESSAGE_TYPES and type_name not in FOXGLOVE_TYPES):
            type_name = peek_type(payload)
            if type_name not in MESSAGE_TYPES:
                type_name = ""  # an unknown tag: the topic's one `unknown` channel, not a channel per tag
        cid = self._guard(self._channel, topic, type_name, source)
        self._guard(self._w.add_message, cid, log_time=log_ns, data=payload, publish_time=publish_ns or log_ns,
                    sequence=max(seq, 0) & 0xFFFFFFFF)
        self.messages += 1
        self.bytes += len(payload)
        self.per_topic[topic] = self.per_topic.get(topic, 0) + 1
        self.maybe_flush()

    def maybe_flush(self) -> None:
        """Close the open chunk if ``flush_interval`` has passed."""
        now = time.monotonic()
        if self._w is not None and now - self._last_flush >= self.flush_interval:
            self.flush()

    def flush(self) -> None:
        assert self._w is not None and self._f is not None
        self._guard(self._flush)
        self._last_flush = time.monotonic()

    def _flush(self) -> None:
        assert self._w is not None
        self._w.flush()  # the chunk, the file's flush, then the writer's good offset

    @property
    def is_open(self) -> bool:
        """True from :meth:`open` until :meth:`close` has closed the file."""
        return self._f is not None

    def close(self) -> None:
        """Write the summary and footer. Safe to call twice."""
        if self._w is not None:
            self._guard(self._finish)
        if self._f is not None:
            self._f.close()
            self._f = None
        if self._reserve is not None:
            self._reserve.unlink(missing_ok=True)
            self._reserve = None

    def _finish(self) -> None:
        assert self._w is not None and self._f is not None
        self._w.finish()
        self._w = None
        self._f.flush()
