"""Checkpoints: what a restarted stage resumes from, one file per stage in the run's folder.

A stage the graph restarts (``restart: on-failure``) writes its checkpoint after every step,
atomically (a kill leaves the previous one); a process started again reads it and goes on from
the frame after the one it had done (see :mod:`pipeline.runtime.stage_node`).
"""

from __future__ import annotations

import os
from pathlib import Path

import msgspec

__all__ = ["Checkpoint", "write_checkpoint", "read_checkpoint"]


class Checkpoint(msgspec.Struct, frozen=True):
    """What a restarted stage resumes from: its snapshot after frame ``seq`` (None for a
    stateless stage), the last seq it sent on each output port, and the messages that step
    published ((topic, payload, seq, type name)): a kill can come before zenoh has put them
    on the wire, so a restarted stage sends them again (a consumer that had them takes the
    copy, the same bytes as the last message on its port, for a repeat: no error). ``steps``
    counts the steps done up to and including ``seq``, so a restarted stage's progress goes on
    from it (0 in checkpoints written before it was kept)."""

    seq: int
    data: bytes | None
    max_out: dict[str, int]
    sent: list[tuple[str, bytes, int, str]] = []
    steps: int = 0


def write_checkpoint(path: Path, ck: Checkpoint) -> None:
    """Write ``ck`` to ``path`` atomically."""
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(msgspec.msgpack.encode(ck))
    os.replace(tmp, path)


def read_checkpoint(path: Path) -> Checkpoint:
    """The checkpoint in ``path`` (msgspec.DecodeError when it is unusable)."""
    return msgspec.msgpack.decode(path.read_bytes(), type=Checkpoint)
