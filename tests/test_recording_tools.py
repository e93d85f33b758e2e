"""Recording tools against real runs: re-execution bit for bit, seeking, diff, recovery after
SIGKILL, and an independent MCAP reader (@mcap/core, TypeScript) on the files."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest

import cli_fork
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.launcher import Launcher
from pipeline.io.mcap_io import iter_records
from pipeline.runtime.transport import ZenohSettings, free_port
from tests.conftest import read_mcap_js as _read_js

# crossing's first 80 frames (of 120): four filter snapshots (every 20 frames), the middle ones the
# tests restore from (60) and feed a late input to (30), and a third fewer frames for the many re-runs
FRAMES = 80


@pytest.fixture(scope="module")
def crossing_run(tmp_path_factory, gflow_cmd_module):
    """A real multi-process run of the chamfer tracker on crossing's first FRAMES frames, with filter snapshots
    every 20 frames."""
    from tests.conftest import data_dir
    from pipeline.recording.results import read_boxes

    seq = data_dir("crossing")
    tmp = tmp_path_factory.mktemp("crossing")
    init = ",".join(str(v) for v in read_boxes(seq / "groundtruth.csv")[0])
    graph = tmp / "chamfer.yaml"
    text = (Path(__file__).resolve().parent.parent / "pipeline" / "graphs" / "chamfer.yaml").read_text()
    assert "snapshot_every: 25" in text
    graph.write_text(text.replace("snapshot_every: 25", "snapshot_every: 20"))
    rec = tmp / "run.mcap"
    out = cli_fork.run_command([*gflow_cmd_module, "track", str(seq), "--init", init, "--out", str(tmp / "b.csv"),
                                "--record", str(rec), "--graph", str(graph), "--tracker", "chamfer", "-q",
                                # the topic names the tests look for (default: a run id)
                                "--stop", str(FRAMES), "--stream", "cam0"],
                               capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return rec


@pytest.fixture(scope="module")
def gflow_cmd_module():
    import sys

    return [sys.executable, "-m", "pipeline.cli.main"]


@pytest.mark.parametrize("stage", ["source", "preprocess", "proposal", "filter"])
def test_rerun_check_passes_for_every_stage(crossing_run, gflow_cmd, stage):
    out = cli_fork.run_command([*gflow_cmd, "rerun", str(crossing_run), "--stage", stage, "--check"],
                               capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "all identical bit for bit" in out.stdout


def test_rerun_from_a_middle_frame_matches_the_full_rerun(crossing_run, caplog):
    import logging

    from pipeline.recording.rerun import check_outputs, rerun_stage

    full = rerun_stage(crossing_run, "filter")
    with caplog.at_level(logging.WARNING, logger="gflow.host"):
        part = rerun_stage(crossing_run, "filter", from_seq=70)
    # the inputs the snapshot already consumed are not fed again (each would be an old_seq warning)
    assert not caplog.records, caplog.text
    assert part.restored_from == 60  # the nearest snapshot before frame 70
    assert part.steps < full.steps
    later = [(t, s, d) for t, s, d in full.outputs if s > 60]
    assert later and check_outputs(later, part.outputs, 60) == []


def test_changing_a_parameter_fails_the_check_and_names_the_first_frame(crossing_run, gflow_cmd, tmp_path):
    out = cli_fork.run_command([*gflow_cmd, "rerun", str(crossing_run), "--stage", "filter", "--set", "lam=0.5",
                                "--check", "--out", str(tmp_path / "lam.mcap")], capture_output=True, text=True,
                               timeout=300)
    assert out.returncode == 1, out.stdout
    assert "first difference at frame 1" in out.stdout and "gflow/cam0/particles seq 1: field alpha" in out.stdout
    diff = cli_fork.run_command([*gflow_cmd, "diff", str(crossing_run), str(tmp_path / "lam.mcap"),
                                 "--topics", "gflow/cam0/estimate"], capture_output=True, text=True, timeout=120)
    assert diff.returncode == 1 and "first divergence" in diff.stdout and "frame 1" in diff.stdout


def test_whole_graph_rerun_is_bit_exact(crossing_run, gflow_cmd, tmp_path):
    out = cli_fork.run_command([*gflow_cmd, "rerun", str(crossing_run), "--graph", "--check", "--out",
                                str(tmp_path / "g.mcap")], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr


def test_sigkilled_recorder_is_recovered(tmp_path, gflow_cmd):
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 150, "realtime": True, "fps": 30},
                                                        "filter": {"particles": 200}}))
    rec = tmp_path / "killed.mcap"
    launcher = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=str(rec),
                        progress=False)
    th = threading.Thread(target=launcher.run, daemon=True)
    th.start()
    # wait for a condition, not a time: until the file on disk (read as a truncated file) holds
    # at least 30 frames; whatever was on disk then must survive the kill and the recovery
    deadline = time.monotonic() + 120
    on_disk = 0
    while on_disk < 30:
        assert time.monotonic() < deadline, f"the recorder flushed only {on_disk} frames"
        time.sleep(0.1)
        try:
            on_disk = sum(1 for r in iter_records(rec) if r.topic == "gflow/demo/frames")
        except Exception:  # the file is being written; its header may not be complete yet
            on_disk = 0
    os.kill(launcher.pids["recorder"][0], signal.SIGKILL)
    th.join(120)
    fixed = tmp_path / "fixed.mcap"
    out = cli_fork.run_command([*gflow_cmd, "recover", str(rec), str(fixed)], capture_output=True, text=True,
                               timeout=120)
    assert out.returncode == 0, out.stderr
    assert "the writer was killed" in out.stdout
    frames = [r for r in iter_records(fixed) if r.topic == "gflow/demo/frames"]
    seqs = [r.seq for r in frames]
    assert seqs == list(range(len(seqs)))
    assert len(seqs) >= on_disk >= 30, (len(seqs), on_disk)
    assert len(seqs) < 150, "the recorder was killed before the end, so the file must end early"
    # metadata survived and an independent implementation reads the recovered file
    js = _read_js(fixed)
    assert js["topics"]["gflow/demo/frames"]["count"] == len(seqs)
    assert "gflow.config" in js["metadata"]


def test_one_reading_answers_what_the_readers_of_the_whole_file_do(crossing_run, tmp_path):
    """A finished run's recording is read once (read_run, for run_outcome and the benchmark's
    timing): the run's estimates and sessions, the frames sent, the frames reported in errors
    (of the run's stream only) and the tracking span equal those of the readers that each read
    the whole file, on a copy of a real run with error reports and an outsider's estimate added."""
    from gflow_msgs.messages import ErrorReport, Header, encode
    from pipeline.evaluation.sequence_benchmark import tracking_seconds
    from pipeline.io.mcap_io import read_metadata
    from pipeline.io.recorder import McapRecorder
    from pipeline.recording.results import read_run, reported_frames, run_estimates

    rec = tmp_path / "copy.mcap"
    with McapRecorder(rec, metadata=read_metadata(crossing_run)) as w:
        for r in iter_records(crossing_run):
            w.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, log_ns=r.log_ns, type_name=r.type,
                    source=r.source)
            if r.type == "Frame" and r.seq in (3, 17, 40):  # reported on the run's stream, and on another one
                stream = "cam0" if r.seq != 40 else "other"
                w.write(f"gflow/{stream}/errors", encode(ErrorReport(Header(stream, r.seq, 0), "filter", "late_input",
                                                                     "x")), r.seq, publish_ns=r.publish_ns,
                        type_name="ErrorReport", source=r.source)
            if r.type == "Estimate" and r.seq == 50:  # the same estimate from a session outside the run
                w.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, type_name=r.type, source="0badc0de")
    run = read_run(rec, frames_topic="gflow/cam0/frames", errors_stream="cam0")
    est, sessions = run_estimates(rec)
    assert run.estimates == est and len(est) == FRAMES and run.sessions == sessions and sessions.lines()
    assert run.sent == {r.seq for r in iter_records(rec, topics=["gflow/cam0/frames"]) if r.type == "Frame"}
    assert run.sent == set(range(FRAMES))
    assert run.reported == reported_frames(str(rec), "cam0") == {3, 17}
    assert read_run(rec).reported == reported_frames(str(rec)) == {3, 17, 40}
    assert run.tracking_seconds == tracking_seconds(rec) and run.tracking_seconds > 0


def test_independent_reader_reads_recordings(crossing_run):
    from pipeline.io.mcap_io import summarize

    ours = summarize(crossing_run)
    for stream in (False, True):
        js = _read_js(crossing_run, stream)
        for topic, s in ours.topics.items():
            assert js["topics"][topic]["count"] == s.count
            assert js["topics"][topic]["encoding"] == "msgpack"
        assert "gflow.Estimate" in js["topics"]["gflow/cam0/estimate"]["schemas"]
        assert {"gflow.graph", "gflow.config"} <= set(js["metadata"])


def _copy_recording(src: Path, dst: Path, records) -> None:
    from pipeline.io.mcap_io import read_metadata
    from pipeline.io.recorder import McapRecorder

    with McapRecorder(dst, metadata=dict(read_metadata(src))) as rec:
        for r in records:
            rec.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, log_ns=r.log_ns, type_name=r.type)


@dataclasses.dataclass
class LateFeatures:
    """crossing_run's records with frame 30's features come late: after the filter, live, would have
    stepped frame 30 without them; and the filter's outputs re-run on a copy where they never come
    (what a live filter that gave them up made)."""

    late: object  # frame 30's features
    at: int  # where they come in ``moved``: after the proposals of frame 31
    moved: list
    never: list[tuple[str, int, bytes]]  # the filter's outputs without them


@pytest.fixture(scope="module")
def late_features(crossing_run, tmp_path_factory) -> LateFeatures:
    """The filter re-run without frame 30's features, once for the two tests of an input given up as late.

    In a run on a quiet machine the preprocess is frames ahead of the filter (frame 30's features come
    before the proposals of frame 27); on a busy one it may not be, and the fixture does not depend on
    it. Late, frame 30's features come after the proposals of frame 31, which the proposal makes from
    the filter's step of frame 30: the filter had frame 30's proposals, waited for its features, gave
    them up and stepped. The features of the frames after 30 that came before (if any did) are moved
    behind them, in order, as the preprocess publishes them: one arriving after a later frame's would
    be dropped by the join itself (its port had moved past frame 30), so a re-run that ignored the
    late_input report would give up frame 30 too and the tests could not tell."""
    from pipeline.recording.rerun import rerun_stage

    recs = list(iter_records(crossing_run))
    feats, props = "gflow/cam0/features", "gflow/cam0/proposals"
    [late] = [r for r in recs if r.topic == feats and r.seq == 30]
    stepped = next(i for i, r in enumerate(recs) if r.topic == props and r.seq == 31)
    behind = [r for r in recs[:stepped] if r.topic == feats and r.seq >= 30]  # frame 30's and those after it
    kept = [r for r in recs[:stepped + 1] if not (r.topic == feats and r.seq >= 30)]
    moved = kept + behind + recs[stepped + 1:]
    at = len(kept)
    assert moved[at] is late, [r.seq for r in behind]
    # frame 30's features before every later frame's, so the join would take them if nothing gave them up
    order = [r.seq for r in moved if r.topic == feats]
    assert order == sorted(order) and sorted(map(id, moved)) == sorted(map(id, recs))
    assert any(r.topic == props and r.seq == 30 for r in moved[:at])  # the filter had the rest of frame 30
    never = tmp_path_factory.mktemp("late") / "never.mcap"
    _copy_recording(crossing_run, never, [r for r in recs if r is not late])
    return LateFeatures(late, at, moved, rerun_stage(never, "filter").outputs)


def test_an_input_given_up_as_late_is_given_up_again_by_the_rerun(crossing_run, late_features, tmp_path):
    """A live filter that gave up frame 30's features as late stepped frame 30 without them and
    dropped them when they came. In the recording they come later and the filter's late_input
    report names them: the re-run must step frame 30 without them too, as if they had never come."""
    from pipeline.recording.rerun import check_outputs, rerun_stage
    from gflow_msgs.messages import ErrorReport, Header, encode

    late, at, moved = late_features.late, late_features.at, late_features.moved
    feats = "gflow/cam0/features"
    report = ErrorReport(header=Header("cam0", 30, 0), stage="filter", kind="late_input", topic=feats,
                         message="frame 30: no features after 3.0 s while the stream is ahead; going on without")
    rep = dataclasses.replace(late, topic="gflow/cam0/errors", type="ErrorReport", data=encode(report))
    with_report = moved[:at] + [rep] + moved[at:]  # the report, before the features came
    _copy_recording(crossing_run, tmp_path / "late.mcap", with_report)
    _copy_recording(crossing_run, tmp_path / "moved.mcap", moved)

    replayed = rerun_stage(tmp_path / "late.mcap", "filter").outputs
    never = late_features.never
    used = rerun_stage(tmp_path / "moved.mcap", "filter").outputs
    assert check_outputs(never, replayed) == []
    # without the report the re-run waits for the features and uses them: frame 30's outputs differ
    differ = check_outputs(never, used)
    assert [m.seq for m in differ][:1] == [30]
    assert any(m.seq == 30 and not m.topic.endswith("/errors") for m in differ), differ[:3]


def test_rerun_check_passes_on_a_run_whose_filter_gave_an_input_up(crossing_run, late_features, gflow_cmd, tmp_path):
    """The recording a live filter makes when it gives frame 30's features up as late: its outputs
    are those of stepping without them, its errors topic has its late_input and missing_features
    reports. `gflow rerun --check` re-makes the missing_features report; reports are diagnostics,
    left out of the comparison on both sides, so the check passes (it failed on such a run when
    the re-run's reports were compared against a recording whose reports were not)."""
    from pipeline.recording.rerun import recorded_plan
    from pipeline.io.recorder import peek_type
    from gflow_msgs.messages import ErrorReport, Header, encode

    plan = recorded_plan(crossing_run)
    outs = set(plan.stages["filter"].outputs.values()) | {plan.snapshot_topic("filter")}
    late, at, moved = late_features.late, late_features.at, late_features.moved
    feats = "gflow/cam0/features"
    report = ErrorReport(header=Header("cam0", 30, 0), stage="filter", kind="late_input", topic=feats,
                         message="frame 30: no features after 3.0 s while the stream is ahead; going on without")
    rep = dataclasses.replace(late, topic=plan.error_topic, type="ErrorReport", data=encode(report))
    inputs = [r for r in moved[:at] + [rep] + moved[at:] if r.topic not in outs]
    stepped = late_features.never  # the live filter's outputs
    assert any(t == plan.error_topic for t, _, _ in stepped), "stepping without features is reported"
    ns = inputs[-1].log_ns
    made = [dataclasses.replace(late, topic=t, seq=q, data=d, type=peek_type(d), log_ns=ns + i + 1,
                                publish_ns=ns + i + 1) for i, (t, q, d) in enumerate(stepped)]
    _copy_recording(crossing_run, tmp_path / "live.mcap", inputs + made)
    out = cli_fork.run_command([*gflow_cmd, "rerun", str(tmp_path / "live.mcap"), "--stage", "filter", "--check"],
                               capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "all identical bit for bit" in out.stdout
