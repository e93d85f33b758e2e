"""``gflow verify`` on a real recording and on damaged copies of it: an intact file passes with
``gflow info``'s message count; flipped bytes name their chunk and offset; a truncated copy says
how many messages ``gflow recover`` salvages (and recover does salvage that many); a message that
does not decode as its type is named; bad or missing files are one-line errors; a recording a
running pipeline is writing is in progress, not damaged."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from pipeline.cli.main import main
from pipeline.io.recorder import McapRecorder
from tests.test_recordings_kept import small_recording  # noqa: F401  (a short real run, recorded)
import cli_fork

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


def _chunks(path: Path) -> list[tuple[int, int]]:
    """(offset, length) of every chunk, from the file's chunk index."""
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    assert s is not None
    return sorted((c.chunk_start_offset, c.chunk_length) for c in s.chunk_indexes)


def _readable(out: str) -> int:
    m = re.search(r"; (\d+) messages? readable before it; ", out)
    assert m, out
    return int(m.group(1))


def _recovered(broken: Path, fixed: Path, capsys) -> int:
    main(["recover", str(broken), str(fixed)])
    m = re.search(r"recovered (\d+) messages", capsys.readouterr().out)
    assert m
    return int(m.group(1))


def test_an_intact_recording_is_ok_with_infos_message_count(small_recording: Path, capsys,  # noqa: F811
                                                             monkeypatch) -> None:
    import pipeline.cli.commands.verify as verify_command

    assert main(["info", str(small_recording), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    monkeypatch.setattr(verify_command, "PROGRESS_EVERY_S", 0.0)  # a progress line after every chunk
    assert main(["verify", str(small_recording)]) == 0
    cap = capsys.readouterr()
    out = cap.out.strip()
    progress = cap.err.splitlines()
    assert progress and all(re.fullmatch(r"  verify: \S+  [\d.]+/[\d.]+ MB, \d+ messages", p) for p in progress), cap.err
    m = re.fullmatch(re.escape(str(small_recording)) + r": OK: (\d+) messages, (\d+) channels, ([\d.]+) seconds", out)
    assert m, out
    assert int(m.group(1)) == info["messages"] > 0
    assert int(m.group(2)) >= len(info["topics"])
    assert float(m.group(3)) == round(info["duration_s"], 3)
    assert main(["verify", "--quiet", str(small_recording)]) == 0
    assert capsys.readouterr() == ("", "")  # --quiet: only the damaged ones, no progress


def test_flipped_bytes_inside_a_chunk_name_the_chunk_and_its_offset(small_recording: Path, tmp_path: Path,  # noqa: F811
                                                                    capsys) -> None:
    """verify names the chunk; recover leaves out that chunk alone, and keeps every chunk after it."""
    chunks = _chunks(small_recording)
    k = len(chunks) // 2  # a chunk after the first, so some messages come before it and some after
    assert 0 < k < len(chunks) - 1, chunks
    offset, length = chunks[k]
    data = bytearray(small_recording.read_bytes())
    for i in range(offset + length // 2, offset + length // 2 + 16):
        data[i] ^= 0xFF
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(data))
    assert main(["verify", "--quiet", str(bad)]) == 1
    out = capsys.readouterr().out
    assert out.startswith(f"{bad}: DAMAGED: chunk {k + 1} at byte {offset}: "), out
    # a tool that reads the messages names the same chunk and byte: the reader stops at the chunk's end
    main(["info", str(bad)])
    said = capsys.readouterr()
    assert (f"recording is damaged at byte {offset} of {len(data)}, in chunk {k + 1} "
            f"(bytes {offset}-{offset + length})") in said.out + said.err, said
    n = _readable(out)
    held = _messages_in_chunk(small_recording, offset)
    total = _total(small_recording)
    assert n == sum(_messages_in_chunk(small_recording, o) for o, _ in chunks[:k]) > 0
    assert f"can salvage {total - held} messages" in out, out
    assert _recovered(bad, tmp_path / "fixed.mcap", capsys) == total - held > n  # the chunks after it too
    assert main(["verify", str(tmp_path / "fixed.mcap")]) == 0  # what recover wrote is intact
    assert f"OK: {total - held} messages" in capsys.readouterr().out


def _total(path: Path) -> int:
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    assert s is not None and s.statistics is not None
    return s.statistics.message_count


def _messages_in_chunk(path: Path, offset: int) -> int:
    """The messages of the chunk at ``offset`` of an intact file."""
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    with open(path, "rb") as f:
        f.seek(offset)
        rec = next(iter(StreamReader(f, skip_magic=True, emit_chunks=True).records))
    assert isinstance(rec, Chunk)
    return sum(isinstance(r, Message) for r in breakup_chunk(rec))


def test_a_truncated_copy_says_how_many_messages_recover_salvages(small_recording: Path, tmp_path: Path,  # noqa: F811
                                                                  capsys) -> None:
    offset, _ = _chunks(small_recording)[-1]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(small_recording.read_bytes()[:offset + 100])  # inside the last chunk: no summary, no footer
    assert main(["verify", str(cut)]) == 1
    out = capsys.readouterr().out
    assert "DAMAGED" in out and "no summary" in out and f"gflow recover {cut} FIXED.mcap can salvage them" in out
    n = _readable(out)
    assert 0 < n == _recovered(cut, tmp_path / "fixed.mcap", capsys)


def test_a_message_that_does_not_decode_as_its_type_is_named(tmp_path: Path, capsys) -> None:
    path = tmp_path / "garbled.mcap"
    rec = McapRecorder(path).open()
    rec.write("gflow/cam0/estimate", b"\x93\x01\x02\x03", seq=1, type_name="Estimate")
    rec.close()
    assert main(["verify", str(path)]) == 1
    out = capsys.readouterr().out
    assert "chunk 1 at byte" in out and "gflow/cam0/estimate (seq 1) does not decode as gflow.Estimate" in out, out
    # recover copies bytes, not meanings: the one message is what it would save
    assert f"0 messages readable before it; gflow recover {path} FIXED.mcap can salvage 1 message" in out, out


def test_bad_and_missing_files_are_one_line_errors(small_recording: Path, tmp_path: Path) -> None:  # noqa: F811
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("these are notes, not a recording\n")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    missing = tmp_path / "missing.mcap"
    r = cli_fork.run_command([*GFLOW, "verify", str(not_mcap), str(missing), str(empty), str(small_recording)],
                             capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert "Traceback" not in r.stderr + r.stdout
    errors = r.stderr.strip().splitlines()
    assert len(errors) == 4, r.stderr  # one per bad file, and the tally
    assert f"{not_mcap} is not an MCAP file" in errors[0]
    assert f"recording not found: {missing}" in errors[1]
    assert f"{empty} is empty" in errors[2]
    assert r.stdout.startswith(f"{small_recording}: OK: ")  # the good file after them is still checked


def test_a_recording_a_running_pipeline_writes_is_in_progress(small_recording: Path, tmp_path: Path,  # noqa: F811
                                                              capsys) -> None:
    from pipeline.runtime.running import announce

    offset, _ = _chunks(small_recording)[-1]
    live = tmp_path / "live.mcap"
    live.write_bytes(small_recording.read_bytes()[:offset + 100])  # as a writer leaves it between two chunks
    with announce("verify-test", [], name="verify-test", recording=str(live)):
        assert main(["verify", str(live)]) == 0
        out = capsys.readouterr().out
    assert f"{live}: IN PROGRESS: being written by verify-test" in out and "DAMAGED" not in out, out
    assert main(["verify", str(live)]) == 1  # once the run is over, the same file is damaged
    assert "DAMAGED" in capsys.readouterr().out


def test_a_summary_that_disagrees_with_the_file_is_damaged(small_recording: Path, tmp_path: Path,  # noqa: F811
                                                          capsys) -> None:
    """Statistics claiming one message more, under a summary CRC made to match: the counts are checked."""
    import struct
    import zlib

    from mcap.records import Statistics
    from mcap.stream_reader import StreamReader

    data = bytearray(small_recording.read_bytes())
    with open(small_recording, "rb") as f:
        at, stats_at = 8, -1
        for rec in StreamReader(f, emit_chunks=True).records:
            if isinstance(rec, Statistics):
                stats_at, n = at, rec.message_count
            at = f.tell()
    assert stats_at > 0
    struct.pack_into("<Q", data, stats_at + 9, n + 1)  # opcode, length, then message_count
    footer_at = len(data) - 8 - (1 + 8 + 20)
    summary_start = struct.unpack_from("<Q", data, footer_at + 9)[0]
    crc = zlib.crc32(data[footer_at:footer_at + 25], zlib.crc32(data[summary_start:footer_at]))
    struct.pack_into("<I", data, footer_at + 25, crc)
    bad = tmp_path / "stats.mcap"
    bad.write_bytes(bytes(data))
    assert main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert f"the statistics say {n + 1} messages; the file holds {n}; {n} messages readable before it" in out, out


def test_a_damaged_record_length_in_a_closed_file_is_not_taken_for_a_torn_end(small_recording: Path,  # noqa: F811
                                                                              tmp_path: Path, capsys) -> None:
    """A chunk's record length damaged: verify says so; recover reads the chunk by its own fields (its CRC
    still holds) and loses nothing."""
    import struct

    offset, length = _chunks(small_recording)[-1]
    data = bytearray(small_recording.read_bytes())
    struct.pack_into("<Q", data, offset + 1, 10**9)  # the last chunk's record length: past the end of the file
    bad = tmp_path / "length.mcap"
    bad.write_bytes(bytes(data))
    assert main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    k = len(_chunks(small_recording))
    assert f"DAMAGED: chunk {k} at byte {offset}: its record length says 1000000000 bytes; its fields take " \
           f"{length - 9} (the length is damaged)" in out and "no summary" not in out, out
    total = _total(small_recording)
    assert _recovered(bad, tmp_path / "fixed.mcap", capsys) == total
    assert main(["verify", str(tmp_path / "fixed.mcap")]) == 0


def test_damage_outside_the_messages_costs_no_message(small_recording: Path, tmp_path: Path, capsys) -> None:  # noqa: F811
    """A metadata record's contents damaged (its frame intact): verify names the record and says the
    records after it can be read; recover keeps every message and the other metadata."""
    import struct

    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    data = bytearray(small_recording.read_bytes())
    with open(small_recording, "rb") as f:
        at, meta = 8, []
        for rec in StreamReader(f, emit_chunks=True).records:
            if isinstance(rec, Metadata):
                meta.append(at)
            at = f.tell()
    first = meta[0]
    struct.pack_into("<I", data, first + 9, 10**6)  # the name's length: past the record's end
    bad = tmp_path / "meta.mcap"
    bad.write_bytes(bytes(data))
    assert main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert f"DAMAGED: byte {first}: the metadata record: its contents cannot be read" in out, out
    assert "the records after it can still be read" in out and "runs to or past the end" not in out, out
    total = _total(small_recording)
    assert f"can salvage {total} messages" in out, out
    main(["recover", str(bad), str(tmp_path / "fixed.mcap")])
    said = capsys.readouterr().out
    assert f"recovered {total} messages" in said and f"and {len(meta) - 1} metadata records" in said, said
    assert f"left out the metadata record at byte {first}" in said, said
    assert main(["verify", str(tmp_path / "fixed.mcap")]) == 0


def test_a_damaged_opcode_is_passed_by_the_summarys_chunk_index(small_recording: Path, tmp_path: Path,  # noqa: F811
                                                                 capsys) -> None:
    """The first chunk's opcode damaged, so the chain of records breaks there: recover goes on at the
    next chunk the summary lists, and the channels the lost chunk defined come from the summary."""
    chunks = _chunks(small_recording)
    offset = chunks[0][0]
    data = bytearray(small_recording.read_bytes())
    data[offset] = 0x77
    bad = tmp_path / "opcode.mcap"
    bad.write_bytes(bytes(data))
    assert main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert f"DAMAGED: byte {offset}: 0x77 is no MCAP record's opcode" in out, out
    kept = _total(small_recording) - _messages_in_chunk(small_recording, offset)
    assert kept > 0 and f"can salvage {kept} messages" in out, out
    main(["recover", str(bad), str(tmp_path / "fixed.mcap")])
    said = capsys.readouterr().out
    assert f"recovered {kept} messages of the {_total(small_recording)} its summary lists" in said, said
    assert f"the walk went on at the chunk at byte {chunks[1][0]}" in said, said
    with open(tmp_path / "fixed.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    with open(small_recording, "rb") as f:
        s = make_reader(f).get_summary()
        later = {s.channels[cid].topic for ci in s.chunk_indexes[1:] for cid in ci.message_index_offsets}
    assert later <= topics, later - topics  # defined in the lost chunk, taken from the summary
    assert main(["verify", str(tmp_path / "fixed.mcap")]) == 0


def _frames_recorded(path: Path, compression: str = "lz4") -> Path:
    """Twelve 8x8 frames written by the recorder, a chunk closed every two or three messages."""
    import numpy as np

    from gflow_msgs.messages import Frame, Header, NDArray, encode

    with McapRecorder(path, chunk_size=512, compression=compression) as w:
        for i in range(12):
            frame = Frame(Header("cam0", i, 1000 * (i + 1)), NDArray.of(np.full((8, 8, 3), i, np.uint8)))
            w.write("gflow/cam0/frames", encode(frame), i, log_ns=1000 * (i + 1), type_name="Frame")
    return path


@pytest.mark.parametrize("record, opcode", [("chunk", 0x06), ("message index", 0x07)])
def test_info_calls_a_damaged_opcode_damage_where_verify_does(tmp_path: Path, record: str, opcode: int) -> None:
    """The reader skips a record whose opcode MCAP does not define: `gflow info` of a file whose second chunk's
    opcode was damaged listed the other chunks' messages and exited 0, with no word of damage, while
    `gflow verify` called it damaged."""
    good = _frames_recorded(tmp_path / "good.mcap")
    with open(good, "rb") as f:
        s = make_reader(f).get_summary()
    assert s is not None and len(s.chunk_indexes) >= 3, s
    second = sorted(s.chunk_indexes, key=lambda ci: ci.chunk_start_offset)[1]
    offset = second.chunk_start_offset if record == "chunk" else min(second.message_index_offsets.values())
    data = bytearray(good.read_bytes())
    assert data[offset] == opcode, (record, data[offset])
    data[offset] = 0x77
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    where = f"byte {offset}: 0x77 is no MCAP record's opcode"
    v = cli_fork.run_command([*GFLOW, "verify", str(bad)], capture_output=True, text=True, timeout=60)
    assert v.returncode == 1 and f"DAMAGED: {where}" in v.stdout, v.stdout + v.stderr
    r = cli_fork.run_command([*GFLOW, "info", str(bad)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1, r.stdout + r.stderr
    assert f"WARNING:   {bad}: recording is damaged: {where}" in r.stdout, r.stdout
    assert r.stderr.startswith(f"gflow info: {bad}: the recording is damaged at byte {offset} ("), r.stderr
    assert "Traceback" not in r.stdout + r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    j = cli_fork.run_command([*GFLOW, "info", str(bad), "--json"], capture_output=True, text=True, timeout=60)
    said = json.loads(j.stdout)
    assert j.returncode == 1 and said["unreadable"] and where in said["truncated"], j.stdout
    ok = cli_fork.run_command([*GFLOW, "info", str(good)], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0 and ok.stderr == "", ok.stderr
    told = ok.stdout.replace(str(good), "GOOD")  # (the test's folder is named after it: "...damaged_opcode...")
    assert "damaged" not in told and "WARNING" not in told and "12 msgs" in told, ok.stdout


def _damaged(good: Path, bad: Path, edits: dict[int, int], cut: int | None = None) -> Path:
    """A copy of ``good`` with the byte at each offset of ``edits`` set to its value, cut at byte ``cut``."""
    data = bytearray(good.read_bytes())
    for at, value in edits.items():
        data[at] = value
    bad.write_bytes(bytes(data[:cut]))
    return bad


def _info(path: Path) -> tuple[subprocess.CompletedProcess, dict]:
    """`gflow info` of ``path`` (text), and `gflow info --json`'s answer, run as the CLI."""
    r = cli_fork.run_command([*GFLOW, "info", str(path)], capture_output=True, text=True, timeout=60)
    j = cli_fork.run_command([*GFLOW, "info", str(path), "--json"], capture_output=True, text=True, timeout=60)
    assert j.returncode == r.returncode, j.stdout + j.stderr
    assert "Traceback" not in r.stdout + r.stderr + j.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == (r.returncode != 0), r.stderr  # one line, when it fails
    return r, json.loads(j.stdout)


def _second_chunk(good: Path) -> tuple[int, int, int]:
    """(offset, its message index's offset, the next chunk's offset) of the second chunk of ``good``."""
    with open(good, "rb") as f:
        s = make_reader(f).get_summary()
    assert s is not None and len(s.chunk_indexes) == 7, s  # 12 frames in 7 chunks: 1, 2, 2, 2, 2, 2, 1
    cis = sorted(s.chunk_indexes, key=lambda ci: ci.chunk_start_offset)
    return cis[1].chunk_start_offset, min(cis[1].message_index_offsets.values()), cis[2].chunk_start_offset


@pytest.mark.parametrize("also_its_index", [False, True])
def test_info_counts_the_chunk_it_passed_over_and_says_where(tmp_path: Path, capsys, also_its_index: bool) -> None:
    """A chunk whose opcode was damaged is passed over by the reader: `gflow info` counted the other chunks'
    10 messages as if they were all, and its line on stderr did not say where the damage is. It now says the
    byte, as verify does, and how many chunks and messages it did not read: 2, as the chunk's message index
    lists them (or, that index damaged too, as the statistics' 12 less the 10 read), as recover counts them."""
    good = _frames_recorded(tmp_path / "good.mcap")
    offset, index, _ = _second_chunk(good)
    bad = _damaged(good, tmp_path / "bad.mcap", {offset: 0x77, **({index: 0x77} if also_its_index else {})})
    r, said = _info(bad)
    assert r.returncode == 1, r.stdout + r.stderr
    assert r.stderr == (f"gflow info: {bad}: the recording is damaged at byte {offset} (10 messages read; 1 chunk "
                        f"with 2 messages not read)\n"), r.stderr
    assert "messages:  10 " in r.stdout, r.stdout
    assert (f"not read:  1 chunk (at byte {offset}) with 2 messages; 10 of the 12 messages the summary lists were "
            f"read\n") in r.stdout, r.stdout
    assert said["messages"] == 10 and said["not_read"] == {
        "chunks": 1, "more_chunks": False, "chunks_at": [{"file": str(bad), "byte": offset}], "messages": 2,
        "messages_exact": True, "listed": 12, "cut": [], "summary_damaged": False}, said
    main(["recover", str(bad), str(tmp_path / "fixed.mcap")])  # the same count as recover's
    assert "recovered 10 messages of the 12 its summary lists" in capsys.readouterr().out


def test_info_of_a_damaged_message_index_says_no_chunk_was_lost(tmp_path: Path) -> None:
    """Only a message index's opcode damaged: every message is read, and info says so rather than leave the
    reader to wonder whether its count is short."""
    good = _frames_recorded(tmp_path / "good.mcap")
    _, index, _ = _second_chunk(good)
    bad = _damaged(good, tmp_path / "bad.mcap", {index: 0x77})
    r, said = _info(bad)
    assert r.returncode == 1 and r.stderr == (f"gflow info: {bad}: the recording is damaged at byte {index} "
                                              f"(12 messages read; every chunk read)\n"), r.stderr
    assert "not read:  no chunk: every chunk was read; 12 of the 12 messages the summary lists were read" in r.stdout
    assert said["not_read"]["chunks"] == 0 and said["not_read"]["messages"] == 0, said
    ok, fine = _info(good)
    assert ok.returncode == 0 and "not read" not in ok.stdout and fine["not_read"] is None, ok.stdout


def test_info_stopped_by_a_damaged_chunk_counts_the_intact_chunks_after_it(tmp_path: Path) -> None:
    """A chunk whose compressed data is damaged stops the reader: nothing after it is read. info says where
    (the chunk's byte, not the byte where the reader stopped) and that the 6 chunks from there, with the 11
    messages the file holds beyond the one read, were not read, while recover saves all but the damaged 2."""
    good = _frames_recorded(tmp_path / "good.mcap")
    offset, _, _ = _second_chunk(good)
    data = good.read_bytes()
    bad = _damaged(good, tmp_path / "bad.mcap", {offset + 60: data[offset + 60] ^ 0xFF})
    r, said = _info(bad)
    assert r.returncode == 1 and r.stderr == (f"gflow info: {bad}: the recording is damaged at byte {offset} "
                                              f"(1 message read; 6 chunks with 11 messages not read)\n"), r.stderr
    assert said["messages"] + said["not_read"]["messages"] == said["not_read"]["listed"] == 12, said
    assert said["not_read"]["chunks_at"][0] == {"file": str(bad), "byte": offset}, said
    v = cli_fork.run_command([*GFLOW, "verify", str(bad)], capture_output=True, text=True, timeout=60)
    assert f"DAMAGED: chunk 2 at byte {offset}: " in v.stdout and "can salvage 10 messages" in v.stdout, v.stdout


@pytest.mark.parametrize("where", ["inside a chunk", "inside a frame", "after a whole record"])
def test_info_of_a_torn_file_names_the_record_it_ends_inside(tmp_path: Path, where: str) -> None:
    """A file cut where its writer was killed said only "recording ends early (EndOfFile)", and no `not read:`
    line. Now the WARNING and the `not read:` line name the record the file ends inside, at its byte, and how
    much of it the file holds (found by the frames alone), and `--json` gives it; the messages before the cut are
    all read and the file is not called damaged."""
    good = _frames_recorded(tmp_path / "good.mcap")
    (third, length), = [c for c in _chunks(good)][2:3]
    size = {"inside a chunk": third + length // 2, "inside a frame": third + 5,  # length: with its frame
            "after a whole record": third}[where]
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(good.read_bytes()[:size])
    r, said = _info(torn)
    assert r.returncode == 0 and r.stderr == "", r.stdout + r.stderr
    before = _messages_before(good, stop_at=third)
    assert said["messages"] == before and said["unreadable"] is None, said
    cut = said["not_read"]["cut"]
    assert [(c["byte"], c["bytes_held"]) for c in cut] == [(third if size > third else size, size - third)], cut
    if where == "inside a chunk":
        assert (f"the file ends inside chunk 3 at byte {third}, {size - third} of whose {length} bytes it "
                f"holds); it was not closed properly") in r.stdout, r.stdout
        assert (f"not read:  chunk 3 at byte {third}, cut short by the file's end (the file holds {size - third} "
                f"of its {length} bytes) with an unknown number of messages\n") in r.stdout, r.stdout
        assert said["not_read"]["messages"] is None and cut[0]["record"] == "chunk", said
    elif where == "inside a frame":
        assert f"the file ends inside a record's frame at byte {third}, 5 of whose 9 bytes it holds" in r.stdout
        assert f"not read:  a record at byte {third}, cut short by the file's end" in r.stdout, r.stdout
    else:
        assert f"the file ends at byte {third}, after a whole record); it was not closed" in r.stdout, r.stdout
        assert (f"not read:  no chunk: every chunk was read; the file ends at byte {third}, after a whole record\n"
                in r.stdout), r.stdout
        assert said["not_read"]["messages"] == 0 and said["not_read"]["messages_exact"], said


def _messages_before(path: Path, stop_at: int) -> int:
    """How many messages the chunks of ``path`` that end by byte ``stop_at`` hold."""
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    n = 0
    with open(path, "rb") as f:
        for rec in StreamReader(f, emit_chunks=True).records:
            if f.tell() > stop_at:
                break
            if isinstance(rec, Chunk):
                n += sum(isinstance(m, Message) for m in breakup_chunk(rec))
    return n


def test_a_summary_that_fails_its_crc_gives_no_count(tmp_path: Path) -> None:
    """The statistics' message count damaged to 10000: `gflow info`'s `not read:` line said "12 of the 10000
    messages the summary lists were read", and recover "recovered 12 messages of the 10000 its summary lists ...;
    the file was complete", from a summary whose CRC does not match. Now neither uses its counts, and each says
    why; the copy's summary is written anew and verifies."""
    import struct

    good = _frames_recorded(tmp_path / "good.mcap")
    data = bytearray(good.read_bytes())
    at = 8
    while data[at] != 0x0B:  # the statistics record
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    assert struct.unpack_from("<Q", data, at + 9)[0] == 12
    struct.pack_into("<Q", data, at + 9, 10000)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    r, said = _info(bad)
    assert r.returncode == 1 and "the 10000" not in r.stdout + r.stderr, r.stdout + r.stderr
    assert ("not read:  no chunk: every chunk was read; 12 messages read (no count of the summary's is used: its CRC "
            "does not match)\n") in r.stdout, r.stdout
    assert said["not_read"]["listed"] is None and said["not_read"]["summary_damaged"], said
    fixed = tmp_path / "fixed.mcap"
    c = cli_fork.run_command([*GFLOW, "recover", str(bad), str(fixed)], capture_output=True, text=True, timeout=60)
    assert c.returncode == 0 and "the 10000" not in c.stdout, c.stdout + c.stderr
    assert c.stdout.startswith("recovered 12 messages on 1 channels") and "its summary is damaged (its CRC does not " \
        "match) and is written anew" in c.stdout and "the file was complete" not in c.stdout, c.stdout
    from pipeline.recording.verify import verify

    assert verify(fixed).ok and verify(fixed).messages == 12


def test_info_of_a_damaged_torn_file_says_at_least(tmp_path: Path) -> None:
    """No summary (the file was cut) and a chunk's opcode damaged: the chunk itself says it held 2 messages,
    but what the cut-off end held cannot be known, so info says "at least", never a total."""
    good = _frames_recorded(tmp_path / "good.mcap")
    offset, _, _ = _second_chunk(good)
    bad = _damaged(good, tmp_path / "bad.mcap", {offset: 0x77}, cut=good.stat().st_size - 300)
    r, said = _info(bad)
    assert r.returncode == 1 and f"the recording is damaged at byte {offset} (" in r.stderr, r.stderr
    assert "at least 1 chunk with at least 2 messages not read)" in r.stderr, r.stderr
    assert f"not read:  at least 1 chunk (at byte {offset}) with at least 2 messages\n" in r.stdout, r.stdout
    assert said["not_read"] == {"chunks": 1, "more_chunks": True, "chunks_at": [{"file": str(bad), "byte": offset}],
                                "messages": 2, "messages_exact": False, "listed": None, "cut": [], "summary_damaged": False}, said


def test_whatever_the_damage_verify_and_recover_answer_and_what_is_kept_is_intact(small_recording: Path,  # noqa: F811
                                                                                  tmp_path: Path) -> None:
    """Random bytes flipped anywhere (and the file perhaps cut): verify gives a result, recover never raises,
    never saves more than the file held, and what it writes verifies as intact."""
    import shutil

    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from pipeline.recording.recover import recover
    from pipeline.recording.verify import verify

    data = small_recording.read_bytes()
    total = _total(small_recording)
    lost_any = []

    @settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(at=st.integers(8, len(data) - 1), n=st.integers(1, 64), xor=st.integers(1, 255),
           cut=st.one_of(st.none(), st.integers(9, len(data))))
    def damaged(at: int, n: int, xor: int, cut: int | None) -> None:
        d = bytearray(data)
        for i in range(at, min(at + n, len(d))):
            d[i] ^= xor
        work = tmp_path / "fuzz"
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir()
        bad = work / "bad.mcap"
        bad.write_bytes(bytes(d[:cut]))
        r = verify(bad)
        assert r.messages <= total
        got = recover(bad, work / "fixed.mcap")
        assert got.messages <= total
        lost_any.append(got.messages < total)
        if got.messages:
            assert verify(work / "fixed.mcap").ok, (at, n, xor, cut)
        else:
            assert not (work / "fixed.mcap").exists()

    damaged()
    assert any(lost_any)  # the damage did cost messages somewhere: the test reached the chunks


def _chunk_field(data: bytes, offset: int, field: str) -> int:
    """The byte where the 8-byte ``field`` of the chunk record at ``offset`` starts: the record's length (after its
    opcode), its uncompressed size, or its compressed size (after its compression's name)."""
    import struct

    name_len = struct.unpack_from("<I", data, offset + 9 + 28)[0]
    return {"record length": offset + 1, "uncompressed size": offset + 9 + 16,
            "compressed size": offset + 9 + 32 + name_len}[field]


@pytest.mark.parametrize("field, value, compression", [
    ("record length", 2**62, "lz4"), ("record length", 2**64 - 1, "lz4"), ("record length", "past", "lz4"),
    ("compressed size", 2**62, "lz4"), ("compressed size", 2**64 - 1, "zstd"), ("compressed size", 2**62, "none"),
    ("compressed size", "past", "lz4"),
    ("uncompressed size", 2**62, "lz4"), ("uncompressed size", 2**64 - 1, "zstd"), ("uncompressed size", 2**62, "none"),
])
def test_a_chunk_length_damaged_to_a_huge_value_is_damage_not_an_internal_error(
        tmp_path: Path, field: str, value: int | str, compression: str) -> None:
    """A chunk's record length, compressed size or uncompressed size damaged to 2**62 or 2**64 - 1 had `gflow info`
    and `gflow verify` ask the file for that many bytes (or zstd for that big a buffer): "internal error:
    MemoryError" (or OverflowError). "past": a length a few bytes past the end of the file. Now each command says
    the recording is damaged at the chunk's byte, and recover reads the chunk by its other, intact lengths: all 12
    messages, in a file that verifies."""
    import struct

    good = _frames_recorded(tmp_path / "good.mcap", compression)
    offset, _, _ = _second_chunk(good)
    data = bytearray(good.read_bytes())
    at = _chunk_field(bytes(data), offset, field)
    if value == "past":  # the record's end, or its data's, 5 bytes past the end of the file
        value = len(data) - (at + 8) + 5 if field == "compressed size" else len(data) - (offset + 9) + 5
    struct.pack_into("<Q", data, at, value)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    r, said = _info(bad)
    told = r.stdout + r.stderr
    assert "internal error" not in told and "MemoryError" not in told and "OverflowError" not in told, told
    assert r.returncode == 1 and said["unreadable"], told
    assert r.stderr.startswith(f"gflow info: {bad}: the recording is damaged at byte {offset} ("), r.stderr
    assert f"WARNING:   {bad}: recording is damaged" in r.stdout and f"byte {offset}" in r.stdout, r.stdout
    v = cli_fork.run_command([*GFLOW, "verify", str(bad)], capture_output=True, text=True, timeout=60)
    assert v.returncode == 1 and v.stderr == "", v.stdout + v.stderr
    assert v.stdout.startswith(f"{bad}: DAMAGED: ") and f"byte {offset}: " in v.stdout, v.stdout
    what = {"record length": "length says", "compressed size": f"its compressed size ({value} bytes) runs past the "
            f"end of its record", "uncompressed size": f"its uncompressed size says {value} bytes"}[field]
    assert what in v.stdout and "can salvage 12 messages" in v.stdout, v.stdout
    fixed = tmp_path / "fixed.mcap"
    c = cli_fork.run_command([*GFLOW, "recover", str(bad), str(fixed)], capture_output=True, text=True, timeout=60)
    assert c.returncode == 0 and c.stderr == "", c.stdout + c.stderr
    assert c.stdout.startswith("recovered 12 messages ") and "the file was complete" not in c.stdout, c.stdout
    assert f"read despite damage: chunk 2 at byte {offset}: " in c.stdout, c.stdout
    from pipeline.recording.verify import verify

    assert verify(fixed).ok and verify(fixed).messages == 12


@pytest.mark.parametrize("data_damaged", [False, True])
def test_a_zstd_chunk_whose_frame_states_no_size_is_not_decompressed_by_a_damaged_size(
        tmp_path: Path, monkeypatch, data_damaged: bool) -> None:
    """zstd data may leave its size out of its frame (streaming writers do); zstd then allocates the size the
    chunk states. Such a chunk's uncompressed size damaged to 2**40 had `gflow info` (and every command that reads
    messages) say "internal error: MemoryError", and recover leave the chunk out. Now the size is learnt from the
    data, decompressed as a stream: every reader reads all 12 messages, verify and info call the file damaged at the
    chunk's byte, and recover keeps all 12. With the data damaged too, the reading stops at that chunk, as at any
    chunk it cannot read, and recover keeps the other 10."""
    import struct

    import zstandard

    from pipeline.io import mcap_writer
    from pipeline.io.mcap_framing import _parse
    from pipeline.io.mcap_io import iter_records
    from pipeline.recording.verify import verify

    monkeypatch.setitem(mcap_writer.COMPRESSIONS, "zstd",
                        lambda d: zstandard.ZstdCompressor(write_content_size=False).compress(d))
    good = _frames_recorded(tmp_path / "good.mcap", "zstd")
    offset, index_at, _ = _second_chunk(good)
    data = bytearray(good.read_bytes())
    chunk = _parse(0x06, bytes(data[offset + 9:index_at]))
    assert zstandard.frame_content_size(chunk.data) == -1  # the frame states no size: zstd goes by the chunk's
    struct.pack_into("<Q", data, _chunk_field(bytes(data), offset, "uncompressed size"), 2**40)
    if data_damaged:
        start = index_at - len(chunk.data)
        data[start + 6:start + 40] = bytes(b ^ 0xFF for b in data[start + 6:start + 40])
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    r, said = _info(bad)
    told = r.stdout + r.stderr
    assert "internal error" not in told and "MemoryError" not in told, told
    read = 1 if data_damaged else 12
    assert r.returncode == 1 and said["messages"] == read, told
    assert r.stderr.startswith(f"gflow info: {bad}: the recording is damaged at byte {offset} ({read} "), r.stderr
    assert sum(1 for _ in iter_records(bad, on_truncated=lambda text: None)) == read
    v = cli_fork.run_command([*GFLOW, "verify", str(bad)], capture_output=True, text=True, timeout=60)
    assert v.returncode == 1 and f"chunk 2 at byte {offset}: its uncompressed size says {2**40} bytes" in v.stdout, \
        v.stdout + v.stderr
    assert (f"; they hold {chunk.uncompressed_size} (the size is damaged)" in v.stdout) is not data_damaged, v.stdout
    fixed = tmp_path / "fixed.mcap"
    c = cli_fork.run_command([*GFLOW, "recover", str(bad), str(fixed)], capture_output=True, text=True, timeout=60)
    assert c.returncode == 0 and c.stdout.startswith(f"recovered {10 if data_damaged else 12} messages "), c.stdout
    assert verify(fixed).ok


def test_no_length_damaged_anywhere_makes_a_reader_raise_what_damage_does_not(tmp_path: Path) -> None:
    """Any 8-byte length or size of any record of a recorder-written file set to a huge or a slightly too large
    value: verify, recover, info's count of what it did not read and the messages' reader answer (the reader by
    saying the recording is damaged), never with MemoryError or OverflowError, and recover keeps what verifies."""
    import shutil
    import struct

    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from mcap.stream_reader import StreamReader

    from pipeline.io.mcap_io import summarize
    from pipeline.recording.recover import recover
    from pipeline.recording.unread import not_read
    from pipeline.recording.verify import verify

    good = _frames_recorded(tmp_path / "good.mcap", "zstd")
    data = good.read_bytes()
    lengths, sizes, at = [], [], 8
    with open(good, "rb") as f:
        for _ in StreamReader(f, emit_chunks=True).records:
            lengths.append(at + 1)  # every record's length
            if data[at] == 0x06:
                sizes += [_chunk_field(data, at, "uncompressed size"), _chunk_field(data, at, "compressed size")]
            at = f.tell()

    @settings(max_examples=40, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(at=st.one_of(st.sampled_from(sizes), st.sampled_from(lengths)), value=st.one_of(
        st.sampled_from([2**62, 2**63, 2**64 - 1, 2**32 - 1, 2**31]), st.integers(len(data) - 8, len(data) + 64),
        st.integers(0, 2**64 - 1)))
    def damaged(at: int, value: int) -> None:
        d = bytearray(data)
        struct.pack_into("<Q", d, at, value)
        work = tmp_path / "fuzz"
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir()
        bad = work / "bad.mcap"
        bad.write_bytes(bytes(d))
        verify(bad)
        not_read(bad)
        summarize(bad)
        got = recover(bad, work / "fixed.mcap")
        assert got.messages <= 12
        if got.messages:
            assert verify(work / "fixed.mcap").ok, (at, value)

    damaged()
