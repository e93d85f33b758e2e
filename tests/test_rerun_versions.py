"""A recording names the versions it was computed with, and `gflow rerun` says when its own differ.

The trackers carry the last bits of floating point into their outputs, and another release of numpy or
OpenCV (or another kind of machine) rounds some of them otherwise, so a re-run's differences need not
be a fault: the check says so, naming the versions that differ (pipeline/runtime/run_metadata.py).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from pipeline.runtime.versions import versions
from pipeline.io.mcap_io import iter_records, read_metadata
from pipeline.io.recorder import McapRecorder
from pipeline.runtime.run_metadata import VERSIONS, versions_differ
import cli_fork


def _with_versions(src: Path, out: Path, changed: dict[str, str] | None) -> Path:
    """``src`` copied to ``out`` record by record, its ``gflow.versions`` changed (None: left out)."""
    md = read_metadata(src)
    if changed is None:
        md.pop(VERSIONS)
    else:
        md[VERSIONS] = {**md[VERSIONS], **changed}
    with McapRecorder(out, metadata=md) as w:
        for r in iter_records(src):
            w.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, log_ns=r.log_ns, type_name=r.type)
    return out


def _rerun(path: Path) -> subprocess.CompletedProcess:
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "rerun", str(path), "--stage", "filter", "--check"],
                                capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)


def test_a_recording_names_the_versions_it_ran_with(demo8):
    recorded = read_metadata(demo8)[VERSIONS]
    assert recorded == versions()
    assert versions_differ(recorded) == []


def test_rerun_says_which_versions_differ_and_still_checks(demo8, tmp_path):
    other = _with_versions(demo8, tmp_path / "other.mcap", {"opencv": "0.0.1 contrib", "numpy": "0.0.2"})
    r = _rerun(other)
    assert r.returncode == 0, r.stdout + r.stderr  # the same machine and libraries: still identical
    note = [ln for ln in r.stdout.splitlines() if "other versions" in ln]
    here = versions()
    assert len(note) == 1, r.stdout
    assert f"numpy 0.0.2 -> {here['numpy']}" in note[0] and f"opencv 0.0.1 -> {here['opencv'].split()[0]}" in note[0]
    assert "all identical bit for bit" in r.stdout


def test_no_version_note_where_they_agree_or_the_recording_does_not_say(demo8, tmp_path):
    same, silent = _rerun(demo8), _rerun(_with_versions(demo8, tmp_path / "old.mcap", None))
    for r in (same, silent):
        assert r.returncode == 0, r.stdout + r.stderr
        assert "other versions" not in r.stdout and "all identical bit for bit" in r.stdout


def test_a_contrib_build_of_the_same_opencv_is_the_same_opencv():
    here = versions()
    assert versions_differ({**here, "opencv": here["opencv"].split()[0] + " contrib"}, here) == []
    assert versions_differ({**here, "simd": "SIMD native"}, here) == [f"simd SIMD native -> {here['simd']}"]
