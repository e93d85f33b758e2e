"""The recorder's own MCAP writer: the same bytes as the mcap library's writer, read by its
readers, and a bounded page cache behind it."""

from __future__ import annotations

import ctypes
import io
import mmap
import os
import sys

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

import pipeline.io.mcap_writer as mw
from pipeline.io.mcap_io import iter_records
from pipeline.io.recorder import McapRecorder
from pipeline.recording.recover import recover


def _calls(w, seed: int = 0) -> None:
    """Schemas, channels (one registered mid-chunk), metadata before and between chunks, a flush,
    out-of-order log times and payloads from 10 B to 90 KB."""
    rng = np.random.default_rng(seed)
    w.start(profile="", library="gflow")
    w.add_metadata("gflow.graph", {"name": "t"})
    s = w.register_schema("gflow.Frame", "jsonschema", b"{}")
    c1 = w.register_channel("gflow/t/frames", "msgpack", s, metadata={"gflow.type": "Frame"})
    c2 = c1
    for i in range(60):
        if i == 7:
            c2 = w.register_channel("gflow/t/estimate", "msgpack", s, {"gflow.type": "Estimate"})
        if i == 30:
            w.flush()
        if i == 31:
            w.add_metadata("late", {"k": "v"})
        data = rng.integers(0, 40, int(rng.integers(10, 90_000)), dtype=np.uint8).tobytes()
        w.add_message(c2 if i % 3 == 0 else c1, log_time=1000 + 7 * i - i % 4, data=data, publish_time=5 + i,
                      sequence=i)
    w.finish()


@pytest.mark.parametrize("ours, theirs", [("", CompressionType.NONE), ("lz4", CompressionType.LZ4),
                                          ("zstd", CompressionType.ZSTD)])
def test_same_bytes_as_the_mcap_library(ours, theirs):
    a, b = io.BytesIO(), io.BytesIO()
    _calls(Writer(a, chunk_size=300_000, compression=theirs))
    _calls(mw.ChunkWriter(b, chunk_size=300_000, compression=ours))
    assert len(a.getvalue()) > 1_000_000
    assert b.getvalue() == a.getvalue()


def test_a_recording_reads_back_and_recovers(tmp_path):
    path = tmp_path / "r.mcap"
    rng = np.random.default_rng(3)
    sent = [rng.integers(0, 255, 50_000 + i, dtype=np.uint8).tobytes() for i in range(120)]
    with McapRecorder(path, chunk_size=1 << 20) as rec:
        for i, p in enumerate(sent):
            rec.write(f"gflow/t/{'a' if i % 2 else 'b'}", p, i, publish_ns=i + 1, log_ns=10 + i)
    got = list(iter_records(path, strict=True))
    assert [r.data for r in got] == sent and [r.seq for r in got] == list(range(120))
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == 120 and len(summary.chunk_indexes) >= 5
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    res = recover(torn, tmp_path / "fixed.mcap")
    assert not res.complete and 40 < res.messages < 120
    assert [r.data for r in iter_records(tmp_path / "fixed.mcap", strict=True)] == sent[: res.messages]


def _resident(path) -> int:
    """Bytes of ``path`` in the page cache (mincore on a mapping of it)."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mmap.restype = ctypes.c_void_p
    libc.mmap.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_long)
    libc.munmap.argtypes = (ctypes.c_void_p, ctypes.c_size_t)
    libc.mincore.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.POINTER(ctypes.c_ubyte))
    size = os.path.getsize(path)
    vec = (ctypes.c_ubyte * ((size + mmap.PAGESIZE - 1) // mmap.PAGESIZE))()
    with open(path, "rb") as f:
        addr = libc.mmap(None, size, mmap.PROT_READ, mmap.MAP_SHARED, f.fileno(), 0)
        assert addr not in (None, ctypes.c_void_p(-1).value), os.strerror(ctypes.get_errno())
        try:
            assert libc.mincore(addr, size, vec) == 0, os.strerror(ctypes.get_errno())
        finally:
            libc.munmap(addr, size)
    return sum(v & 1 for v in vec) * mmap.PAGESIZE


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="posix_fadvise and mincore: Linux")
def test_what_was_written_leaves_the_page_cache(tmp_path, monkeypatch):
    monkeypatch.setattr(mw, "DROP_EVERY", 1 << 20)
    monkeypatch.setattr(mw, "DROP_WINDOW", 8 << 20)
    payload = np.random.default_rng(0).integers(0, 255, 300_000, dtype=np.uint8).tobytes()
    resident = {}
    for drop in (False, True):
        path = tmp_path / f"drop-{drop}.mcap"
        with McapRecorder(path, chunk_size=1 << 20, compression="none", drop_cache=drop) as rec:
            for i in range(160):  # 48 MB
                rec.write("gflow/t/frames", payload, i)
        resident[drop] = _resident(path)
    assert resident[False] > 40e6, resident  # without: the whole recording stays in the page cache
    assert resident[True] < 24e6, resident
