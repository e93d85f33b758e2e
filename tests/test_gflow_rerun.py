"""The determinism checks on a real multi-process G-flow run (david_indoor): every stage
re-runs bit for bit, --from a middle snapshot matches, and a changed parameter is caught."""

from __future__ import annotations

import pytest

import cli_fork
from conftest import data_dir
from pipeline.recording.results import read_boxes

# david_indoor's first 35 frames: the snapshot at frame 25 (the graph's snapshot_every) before the frame FROM
# the tests start from, and frames after FROM to step on to
FRAMES = 35
FROM = 30


@pytest.fixture(scope="module")
def gflow_run(tmp_path_factory):
    import sys

    seq = data_dir("david_indoor")
    tmp = tmp_path_factory.mktemp("gflow")
    init = ",".join(str(v) for v in read_boxes(seq / "groundtruth.csv")[0])
    rec = tmp / "gflow.mcap"
    cmd = [sys.executable, "-m", "pipeline.cli.main", "track", str(seq), "--tracker", "gflow", "--init", init,
           "--stop", str(FRAMES), "--experts", "6", "--samples", "4", "--background", "--out", str(tmp / "b.csv"),
           "--record", str(rec), "-q"]
    out = cli_fork.run_command(cmd, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return rec


@pytest.mark.parametrize("stage", ["preprocess", "proposal", "filter"])
def test_every_gflow_stage_reruns_bit_for_bit(gflow_run, gflow_cmd, stage):
    out = cli_fork.run_command([*gflow_cmd, "rerun", str(gflow_run), "--stage", stage, "--check"],
                               capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "all identical bit for bit" in out.stdout


@pytest.mark.parametrize("stage", ["proposal", "filter"])
def test_gflow_rerun_from_a_snapshot(gflow_run, gflow_cmd, stage):
    out = cli_fork.run_command([*gflow_cmd, "rerun", str(gflow_run), "--stage", stage, "--from", str(FROM), "--check"],
                               capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "from the snapshot at frame" in out.stdout and "all identical" in out.stdout
    # the inputs the snapshot already consumed (the state port joins frame t + 1) are not fed again
    assert "old_seq" not in out.stderr and "WARNING" not in out.stderr, out.stderr


def test_gflow_changed_parameter_is_caught(gflow_run, gflow_cmd):
    out = cli_fork.run_command([*gflow_cmd, "rerun", str(gflow_run), "--stage", "filter", "--set", "seed=7", "--check"],
                               capture_output=True, text=True, timeout=600)
    assert out.returncode == 1 and "first difference at frame" in out.stdout


def test_gflow_proposal_steps_on_after_a_jump(gflow_run):
    """The proposal's state port joins frame t + 1: after a jump to a snapshot at S, the
    recorded state of frame S is still fed (it is frame S + 1's input)."""
    from pipeline.recording.stepper import Stepper

    st = Stepper(gflow_run, "proposal")
    assert st.jump(FROM).startswith("from the snapshot at frame")
    assert not st.errors, st.errors  # the frames stepped to reach FROM had their state
    views = [st.next() for _ in range(3)]
    assert all(v is not None for v in views)
    for v in views:
        assert v is not None and not v.errors, v.errors
        assert v.inputs["state"] != "(missing)", v.seq
