"""The application layer (pipeline/app/): a TrackRequest, its plan, and the estimates its run yields.

Real frames (crossing), the real dcf tracker, inline (one process, every message encoded and
decoded as over zenoh), real MCAP files.
"""

from __future__ import annotations

import tempfile

import pytest

from conftest import data_dir

from pipeline.app import RequestError, TrackRequest, plan_track, run, track
from pipeline.cli.trackers import TRACKERS
from pipeline.recording.results import estimates, read_track
import cli_fork

INIT = (204.0, 150.0, 17.0, 50.0)


def _request(**kw) -> TrackRequest:
    base = dict(source=str(data_dir("crossing")), init=INIT, tracker="dcf", seed=1, stop=6, inline=True, quiet=True)
    return TrackRequest(**{**base, **kw})


def test_no_record_writes_no_mcap_and_yields_the_recorded_estimates(tmp_path, monkeypatch) -> None:
    """The run's estimates come from the run itself: with no_record no recorder runs and no MCAP
    file is written anywhere (not in the working folder, not in TMPDIR), and the estimates it
    yields are those a recorded run of the same request writes to its recording, bit for bit."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    import pipeline.runtime.inline as inline

    opened: list[str] = []  # every MCAP file an inline run opens for writing, even one removed at its end

    class Spy(inline.McapRecorder):
        def open(self):
            opened.append(str(self.path))
            return super().open()

    monkeypatch.setattr(inline, "McapRecorder", Spy)
    plan = plan_track(_request(no_record=True), TRACKERS["dcf"])
    got = list(run(plan))
    assert [e.header.seq for e in got] == list(range(6))
    assert opened == [] and "recorder" not in plan.plan.stages
    assert list(tmp_path.rglob("*.mcap")) == [], list(tmp_path.rglob("*"))

    rec = tmp_path / "r.mcap"
    result = track(plan_track(_request(record=str(rec)), TRACKERS["dcf"]))
    assert opened == [str(rec)]  # the spy sees a recording when there is one
    assert result.recording == str(rec) and result.kept == str(rec)
    recorded = estimates(rec)
    assert list(result.estimates) == list(recorded) == list(range(6))
    assert [msg_bytes(e) for e in got] == [msg_bytes(recorded[k]) for k in range(6)]

    # the CSV from the estimates is the CSV of gflow track
    result.write_csv(tmp_path / "b.csv")
    rows = read_track(tmp_path / "b.csv")
    assert rows.boxes == {k: tuple(round(v, 2) for v in recorded[k].box) for k in range(6)}


def msg_bytes(msg) -> bytes:
    from gflow_msgs.messages import encode

    return encode(msg)


def test_a_bad_request_says_what_is_wrong_before_anything_runs(tmp_path) -> None:
    with pytest.raises(RequestError, match="source not found"):
        plan_track(_request(source=str(tmp_path / "nowhere")), TRACKERS["dcf"])
    with pytest.raises(RequestError, match="--reconnect is an option of live sources"):
        plan_track(_request(reconnect=1.0), TRACKERS["dcf"])
    with pytest.raises(RequestError, match=r"--set expects stage\.param=value"):
        plan_track(_request(sets=("particles=3",)), TRACKERS["dcf"])


def test_run_yields_each_estimate_while_the_source_still_reads(tmp_path, monkeypatch) -> None:
    """The estimates come while the run goes on: the source holds its last frame until the consumer
    has its first estimate (a run that yielded only at its end would read every frame first), and
    what it yields is what the run recorded, frame by frame."""
    import threading

    import pipeline.runtime.inline as inline

    first_taken = threading.Event()
    read: list[int] = []  # the frames the source has read
    real = inline.open_reader

    def held(params, base_dir="."):
        for raw in real(params, base_dir):
            if len(read) == 29:  # the last frame waits for the consumer (a guard of 120 s, should it never come)
                first_taken.wait(timeout=120)
            read.append(raw.index)
            yield raw

    monkeypatch.setattr(inline, "open_reader", held)
    rec = tmp_path / "r.mcap"
    gen = run(plan_track(_request(stop=30, record=str(rec)), TRACKERS["dcf"]))
    first = next(gen)
    read_then = len(read)
    first_taken.set()
    rest = list(gen)
    assert first.header.seq == 0 and read_then < 30, read_then
    recorded = estimates(rec)
    assert [msg_bytes(e) for e in [first, *rest]] == [msg_bytes(recorded[k]) for k in range(30)]


def _recording_is_read(rec) -> None:
    import sys

    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "info", str(rec)], capture_output=True, text=True,
                             timeout=120)
    assert r.returncode == 0 and "estimate" in r.stdout, r.stdout + r.stderr


@pytest.mark.parametrize("inline", [True, False], ids=["inline", "processes"])
def test_stopping_early_stops_the_run_and_keeps_a_valid_recording(tmp_path, inline) -> None:
    """Closing run()'s generator after three estimates stops the run: no stage process is left,
    the recording is closed properly (gflow info reads it) and holds the frames tracked, from 0."""
    import contextlib

    import psutil

    caviar1 = data_dir("caviar1")
    rec = tmp_path / "early.mcap"
    plan = plan_track(_request(source=str(caviar1), init=(129.0, 71.0, 30.0, 79.0), stop=None, record=str(rec),
                               inline=inline), TRACKERS["dcf"])
    me = psutil.Process()
    before = {p.pid for p in me.children(recursive=True)}
    with contextlib.closing(run(plan)) as gen:
        got = [next(gen).header.seq for _ in range(3)]
        stages = [p for p in me.children(recursive=True) if p.pid not in before]
    from pipeline.runtime.zygote import held_pid

    stages = [p for p in stages if p.pid != held_pid()]  # the zygote the run leased is kept for the next run
    assert got == [0, 1, 2]
    assert inline or stages, "the stages run as processes"
    _, alive = psutil.wait_procs(stages, timeout=30)
    assert not alive, f"stage processes left running: {alive}"
    _recording_is_read(rec)
    kept = estimates(rec)
    assert 3 <= len(kept) < plan.total and sorted(kept) == list(range(len(kept)))
