"""The correlation-filter tracker through the pipeline (its stages made from its spec, stages/spec_box.py,
graph ``dcf``): stage processes and ``--inline`` write the same bytes, a recording re-runs bit for bit
(from the start and from a snapshot), ``gflow.Tracker("dcf")`` gives the recorded estimates, and the
filter stage restores its snapshot bit for bit, coasts over bad frames and refuses another stage's
snapshot."""

from __future__ import annotations

import sys

import cv2
import msgspec
import numpy as np
import pytest

from gflow import Tracker
from gflow_core.evaluation.metrics import score
from gflow_core.synthetic import SyntheticScene
from pipeline.io.frame_readers import folder_frames
from pipeline.io.mcap_io import iter_records
from pipeline.recording.results import read_boxes
from stages.base import StageContext
from stages.registry import get_stage_class
from gflow_msgs.messages import Estimate, Frame, Header, NDArray, Particles, decode, encode
import cli_fork

# the tracker's stages, made from its spec (stages.registry, stages.spec_box)
DCFFilterStage, DCFProposalStage = get_stage_class("dcf.filter"), get_stage_class("dcf.proposal")
DCFFilterParams, DCFProposalParams = DCFFilterStage.Params, DCFProposalStage.Params

N_FRAMES = 16
SNAP_AT = 6


@pytest.fixture(scope="module")
def frames():
    sc = SyntheticScene(width=160, height=120, n_frames=N_FRAMES, seed=5, noise=3.0)
    out = []
    for t in range(N_FRAMES):
        img = sc.render(t)
        if t == 11:
            img = np.zeros_like(img)  # a blank frame: the filter coasts
        out.append(Frame(Header("s", t, t * 40_000_000), NDArray.of(img)))
    return sc, out


def _stages(box):
    return (DCFFilterStage(DCFFilterParams(init=box, particles=64, seed=2), StageContext("filter", "s")),
            DCFProposalStage(DCFProposalParams(init=box, particles=64, seed=2), StageContext("proposal", "s")))


def _run(filt, prop, frames, first, parts):
    out: list[bytes] = []
    for t in range(first, len(frames)):
        if t == 0:
            res = filt.step(0, {"frames": frames[0]})
        else:
            (_, proposals), = prop.step(t - 1, {"particles": parts})
            out.append(encode(proposals))
            res = filt.step(t, {"frames": frames[t], "proposals": None if t == SNAP_AT + 2 else proposals})
        for port, msg in res:
            out.append(encode(msg))
            if port == "particles":
                parts = msg
    return out


def test_restore_is_bit_exact_and_bad_frames_coast(frames):
    sc, fr = frames
    box = sc.truth_box(0)
    full = _run(*_stages(box), fr, 0, None)
    filt, prop = _stages(box)
    straight = _run(filt, prop, fr[: SNAP_AT + 1], 0, None)
    snap = filt.snapshot()
    last = [m for m in map(decode, straight) if isinstance(m, Particles) and m.kind == "posterior"][-1]
    filt2, prop2 = _stages(box)
    filt2.restore(snap)
    assert _run(filt2, prop2, fr, SNAP_AT + 1, last) == full[len(straight):]
    est = [m for m in map(decode, full) if isinstance(m, Estimate)]
    assert est[0].state == "init" and est[11].state == "coast"
    reports = [k for k, _, _ in filt2.drain_reports()]
    assert "missing_proposals" in reports and "blank_frame" in reports
    err = [np.hypot(e.box[0] + e.box[2] / 2 - (b[0] + b[2] / 2), e.box[1] + e.box[3] / 2 - (b[1] + b[3] / 2))
           for e, b in zip(est, (sc.truth_box(t) for t in range(N_FRAMES)))]
    assert np.mean(err) < 5.0


def test_a_frame_of_another_size_coasts_and_is_said_as_every_tracker_says_it(frames):
    """The frame-size rule is every tracker's (stages.base.Stage.same_size): a frame of another size than
    the first is reported naming both sizes, and the filter coasts over it."""
    sc, fr = frames
    filt, prop = _stages(sc.truth_box(0))
    (_, parts), _ = filt.step(0, {"frames": fr[0]})
    (_, proposals), = prop.step(0, {"particles": parts})
    small = Frame(Header("s", 1, 40_000_000), NDArray.of(np.ascontiguousarray(fr[1].image.array()[:100, :150])))
    out = dict(filt.step(1, {"frames": small, "proposals": proposals}))
    assert out["estimate"].state == "coast"
    assert filt.drain_reports() == [("bad_frame", "frame 1: size 150x100 differs from the 160x120 frames the "
                                                  "tracker started on; frame skipped; coasting", 1)]


def test_a_snapshot_of_another_stage_is_refused(frames):
    sc, _ = frames
    filt, _ = _stages(sc.truth_box(0))
    with pytest.raises(ValueError, match="not a dcf.filter snapshot"):
        filt.restore(b"\x01\x02garbage")
    with pytest.raises(ValueError, match="dcf.filter snapshot version 9"):
        filt.restore(msgspec.msgpack.encode({"version": 9, "initialised": False}))


def test_stage_parameters_are_the_core_parameters_and_are_checked():
    from dataclasses import fields

    from gflow_core.dcf.params import DCFParams

    core = {f.name: f.default for f in fields(DCFParams)}
    for params in (DCFFilterParams(), DCFProposalParams()):
        assert {k: v for k, v in msgspec.structs.asdict(params).items() if k not in ("init", "seed", "timed")} == core
    with pytest.raises(ValueError, match="scales must be odd"):
        DCFFilterParams(init=(1, 1, 5, 5), scales=2)
    with pytest.raises(ValueError, match="positive width and height"):
        DCFProposalParams(init=(1, 1, 0, 5))


@pytest.mark.data
@pytest.mark.slow
def test_processes_equal_inline_the_api_agrees_and_rerun_is_bit_exact(crossing, tmp_path, gflow_cmd):
    """crossing, frames 0-39, seed 1: the boxes CSV of the stage processes and of --inline are the same
    bytes; gflow rerun of the filter (from the start and from its snapshot at frame 25) and of the whole
    graph reproduces the recording bit for bit; gflow.Tracker("dcf") gives the recorded estimates."""
    gt = read_boxes(crossing / "groundtruth.csv")
    init = ",".join(str(v) for v in gt[0])
    outs = {}
    for mode in ("mp", "inline"):
        csv = tmp_path / f"{mode}.csv"
        cmd = [*gflow_cmd, "track", str(crossing), "--tracker", "dcf", "--init", init, "--seed", "1", "--out",
               str(csv), "--record", str(tmp_path / f"{mode}.mcap"), "-q", "--stop", "40"]
        r = cli_fork.run_command(cmd + (["--inline"] if mode == "inline" else []), capture_output=True, text=True,
                                 timeout=300)
        assert r.returncode == 0, r.stderr
        outs[mode] = csv.read_bytes()
    assert outs["mp"] == outs["inline"]
    pred = read_boxes(tmp_path / "mp.csv")
    assert len(pred) == 40
    sc = score({k: gt[k] for k in pred}, pred)
    still = score({k: gt[k] for k in pred}, {k: gt[0] for k in pred})
    assert sc.cle < still.cle / 5 and sc.success > 0.9
    for extra in (["--stage", "filter"], ["--stage", "filter", "--from", "30"], ["--graph"]):
        r = cli_fork.run_command([*gflow_cmd, "rerun", str(tmp_path / "mp.mcap"), *extra, "--check"], capture_output=True,
                                 text=True, timeout=300)
        assert r.returncode == 0, r.stdout + r.stderr
        assert "all identical bit for bit" in r.stdout
    recorded = {r.seq: decode(r.data) for r in iter_records(tmp_path / "mp.mcap") if r.type == "Estimate"}
    t = Tracker("dcf", seed=1)
    files = folder_frames(crossing / "frames")[:40]
    api = [t.init(cv2.imread(str(files[0][1])), gt[0])] + [t.update(cv2.imread(str(f))) for _, f in files[1:]]
    assert [(e.box, e.confidence, e.target_state, e.phase) for e in api] == [
        (tuple(m.box), m.confidence, m.target_state, m.state) for _, m in sorted(recorded.items())]


def test_gflow_info_and_track_name_the_tracker(gflow_cmd, tmp_path, frames):
    r = cli_fork.run_command([*gflow_cmd, "info", "dcf"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "DCFParams" in r.stdout and "padding" in r.stdout
    folder = tmp_path / "frames"
    folder.mkdir()
    for t in range(3):
        cv2.imwrite(str(folder / f"{t:06d}.png"), frames[1][t].image.array())
    r = cli_fork.run_command([*gflow_cmd, "track", str(folder), "--tracker", "dcf", "--init", "1,1,5,5", "--set",
                              "tracker.scales=4", "--inline", "--no-record", "--stop", "3", "--out", str(tmp_path / "b.csv")],
                             capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "scales must be odd" in r.stderr and "Traceback" not in r.stderr


def test_it_is_the_default_of_gflow_track_and_of_the_api():
    from pipeline.cli.commands.track import track_args

    assert track_args(["x", "--init", "1,1,5,5", "--out", "b.csv"]).tracker == "dcf"
    t = Tracker()
    assert t.name == "dcf" and type(t.params).__name__ == "DCFParams"
    assert sys.modules["gflow_core.dcf.tracker"].TRACKER.name == "dcf"
