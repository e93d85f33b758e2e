"""MCAP recording of every message: one channel per (topic, message type), a JSON schema
per message type, chunked and compressed, flushed on a timer.

Each record keeps the payload bytes exactly as they travelled (so a re-run can be compared
bit for bit), the topic, the log time (when the recorder received it), the publish time
(from the sample's attachment) and the sequence number (the frame index).

``Writer.flush()`` (mcap >= 1.2) closes the open chunk; calling it at least every
``flush_interval`` seconds bounds what a killed recorder loses. The graph and the
configuration are stored as MCAP metadata records named ``gflow.graph`` and ``gflow.config``.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import msgspec
from mcap.writer import CompressionType, Writer

from stages.messages import FOXGLOVE_TYPES, MESSAGE_TYPES, json_schema
from stages.messages_foxglove import FOXGLOVE_SCHEMAS, foxglove_schema

__all__ = ["McapRecorder", "peek_type", "MESSAGE_ENCODING", "SCHEMA_ENCODING"]

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
    path : output file (parent folders are created).
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
    _w: Writer | None = None
    _schemas: dict[str, int] = field(default_factory=dict)
    _channels: dict[tuple[str, str], int] = field(default_factory=dict)
    _last_flush: float = 0.0
    messages: int = 0
    bytes: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)

    def open(self) -> "McapRecorder":
        comp = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD, "none": CompressionType.NONE}.get(self.compression)
        if comp is None:
            raise ValueError(f"unknown MCAP compression {self.compression!r}; use lz4, zstd or none")
        p = Path(self.path)
        p.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(p, "wb")
        self._w = Writer(self._f, chunk_size=self.chunk_size, compression=comp)
        self._w.start(profile="", library="gflow")
        for name, data in self.metadata.items():
            self._w.add_metadata(name, data)
        self._last_flush = time.monotonic()
        return self

    def __enter__(self) -> "McapRecorder":
        return self.open() if self._w is None else self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        assert self._w is not None, "recorder is not open"
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def _channel(self, topic: str, type_name: str) -> int:
        key = (topic, type_name)
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
        cid = self._w.register_channel(topic, "json" if fox is not None else MESSAGE_ENCODING, sid,
                                       metadata={"gflow.type": type_name or "unknown"})
        self._channels[key] = cid
        return cid

    def write(self, topic: str, payload: bytes, seq: int, publish_ns: int = 0, log_ns: int | None = None,
              type_name: str = "") -> None:
        """Record one payload exactly as received. ``type_name`` comes with the sample; without
        it the MessagePack type tag is read."""
        assert self._w is not None, "recorder is not open"
        log_ns = time.time_ns() if log_ns is None else log_ns
        if not type_name or (type_name not in MESSAGE_TYPES and type_name not in FOXGLOVE_TYPES):
            type_name = peek_type(payload)
            if type_name not in MESSAGE_TYPES:
                type_name = ""  # an unknown tag: the topic's one `unknown` channel, not a channel per tag
        cid = self._channel(topic, type_name)
        self._w.add_message(cid, log_time=log_ns, data=payload, publish_time=publish_ns or log_ns,
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
        self._w.flush()
        self._f.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write the summary and footer. Safe to call twice."""
        if self._w is not None:
            self._w.finish()
            self._w = None
        if self._f is not None:
            self._f.close()
            self._f = None
