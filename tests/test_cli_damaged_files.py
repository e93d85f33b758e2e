"""Damaged or malformed input files other than pictures, videos and recordings: model files, box and points CSVs,
landmark files, graph, security and router files. Each is refused in one line on stderr naming the file and what
is wrong, a non-zero exit, no traceback and no "internal error", before any work that it could be checked before.

Every case runs the CLI in a process of its own (``tests/cli_fork.py``) on small files written into tmp_path.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from test_cli_errors import assert_one_line_error, frames, gflow  # noqa: F401  (frames: a fixture)

#: bytes that are not UTF-8 text: a picture's or a recording's, given for a text file
NOT_TEXT = bytes(range(256))


@pytest.mark.parametrize("argv, what", [
    (["run", "bad.txt", "--inline"], "not a graph file"),
    (["run", "demo", "--inline", "--security", "bad.txt"], "not a security file"),
    (["run", "demo", "--inline", "--user", "u", "--password-file", "bad.txt"], "not a password file"),
    (["router", "bad.txt", "--print-config"], "not a router config"),
    (["router", "--listen", "tcp/127.0.0.1:0", "--users-file", "bad.txt", "--print-config"], "not a users file"),
])
def test_a_text_file_that_is_not_text_is_named(tmp_path: Path, argv: list[str], what: str) -> None:
    """A file of bytes given for a graph, a security file, a password file or a router's files: the decoder's
    words alone ("'utf-8' codec can't decode byte 0x80...") named no file."""
    (tmp_path / "bad.txt").write_bytes(NOT_TEXT)
    assert_one_line_error(gflow(*argv, cwd=tmp_path), "bad.txt", what, "byte 0x80 at offset 128")


def test_a_security_file_through_which_a_password_file_that_is_not_text_is_named(tmp_path: Path) -> None:
    (tmp_path / "pw.bin").write_bytes(NOT_TEXT)
    (tmp_path / "security.yaml").write_text("user: u\npassword_file: pw.bin\n")
    r = gflow("run", "demo", "--inline", "--security", "security.yaml", cwd=tmp_path)
    assert_one_line_error(r, "pw.bin", "not a password file")


#: a graph of one source stage; ``{}`` the place of a changed line
GRAPH = "name: g\nstream: s\nstages:\n  source:\n    kind: source\n    params: {kind: synthetic, frames: 2}\n"


@pytest.mark.parametrize("old, new, said", [
    ("kind: source", "kind: [source]", ":5: stage 'source': unknown stage kind ['source']"),
    ("kind: source", "kind: {a: 1}", ":5: stage 'source': unknown stage kind {'a': 1}"),
    ("params: {kind: synthetic, frames: 2}", "params: [1, 2]", ":6: stage 'source': params must be a mapping"),
    ("params: {kind: synthetic, frames: 2}", "params: 5", ":6: stage 'source': params must be a mapping"),
    ("name: g", "name: [g]", ":1: name must be a word or a number, got ['g']"),
    ("stream: s", "stream: {a: 1}", ":2: stream must be a word or a number"),
])
def test_a_graph_value_of_the_wrong_type_is_named_by_its_line(tmp_path: Path, old: str, new: str, said: str) -> None:
    """A list or a mapping where a graph has a name: "internal error: TypeError: unhashable type: 'list'" for a
    stage's kind, another for its params; a list for the graph's name named the run "['g']"."""
    (tmp_path / "g.yaml").write_text(GRAPH.replace(old, new))
    assert_one_line_error(gflow("run", "g.yaml", "--inline", "--no-record", cwd=tmp_path), "g.yaml" + said)
