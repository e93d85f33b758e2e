"""G-flow as real processes on loopback zenoh: two proposal processes and a filter process give
exactly the estimates and states of the inline run with one proposal stage, and the CLI runs it."""

from __future__ import annotations


import numpy as np

from gflow_scenes import SYNTH, payloads, plan_for, pose_estimates, render_folder
from pipeline.runtime.inline import run_inline
from pipeline.runtime.launcher import Launcher
from pipeline.recording.results import read_boxes
from pipeline.runtime.transport import ZenohSettings, free_port
import cli_fork

FRAMES = 12


def test_processes_with_two_shards_equal_inline_with_one(tmp_path) -> None:
    seq, _ = render_folder(tmp_path / "frames", FRAMES)
    params = dict(SYNTH, background=True, seed=1)
    mp = tmp_path / "mp.mcap"
    res = Launcher(plan_for(tmp_path / "frames", seq.box, shards=2, **params),
                   zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=str(mp), progress=False,
                   startup_timeout=60).run()
    assert res.ok, res.exits
    pids = {n: p[0] for n, p in res.pids.items()}
    assert {"proposal0", "proposal1", "filter"} <= set(pids) and len(set(pids.values())) == len(pids)
    inline = tmp_path / "inline.mcap"
    run_inline(plan_for(tmp_path / "frames", seq.box, shards=1, **params), recording=str(inline))
    a, b = payloads(mp), payloads(inline)
    assert len(a) == 2 * FRAMES
    diff = sorted(k for k in a if a[k] != b.get(k))
    assert not diff and set(a) == set(b), f"{len(diff)} messages differ, first {diff[:3]}"
    # the recording carries every expert's projected vertices (the paper's figure 2)
    est = pose_estimates(mp)
    pts = est[FRAMES - 1].expert_points.array()
    assert pts.shape == (SYNTH["n_experts"], seq.model.n_vertices, 2) and np.isfinite(pts).all()


def test_gflow_track_command(tmp_path, gflow_cmd) -> None:
    seq, _ = render_folder(tmp_path / "frames", 8)
    init = ",".join(f"{v:.2f}" for v in seq.box)
    out = cli_fork.run_command([*gflow_cmd, "track", str(tmp_path / "frames"), "--tracker", "gflow", "--init", init,
                                "--out", str(tmp_path / "b.csv"), "--record", str(tmp_path / "r.mcap"), "--inline",
                                "-q", "--experts", "6", "--samples", "4", "--alpha", "0.5", "--no-background",
                                "--gflow-set", "psi_v=1e-5", "--model", "ellipsoid"], capture_output=True, text=True,
                               timeout=120)
    assert out.returncode == 0, out.stderr
    boxes = read_boxes(tmp_path / "b.csv")
    assert sorted(boxes) == list(range(8))
    assert np.allclose(boxes[0], seq.box, atol=0.01)  # frame 0: the box the model was fitted into
