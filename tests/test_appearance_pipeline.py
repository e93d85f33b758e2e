"""The appearance tracker (gflow track --tracker appearance) as stages: snapshot/restore bit for bit,
bad input coasts, and the real CLI on real video: multi-process = --inline byte for byte,
the recording re-runs bit for bit, and it beats a box that never moves."""

from __future__ import annotations

import json

import msgspec
import numpy as np
import pytest

from gflow_core.evaluation.metrics import score
from gflow_core.synthetic import SyntheticScene
from pipeline.recording.results import read_boxes
from stages.base import StageContext
from stages.registry import get_stage_class
from gflow_msgs.messages import Estimate, Frame, Header, NDArray, Particles, decode, encode
import cli_fork

# the two stages are made from the tracker's spec (stages.registry, stages.spec_box)
AppearanceFilterStage = get_stage_class("appearance.filter")
AppearanceFilterParams = AppearanceFilterStage.Params
AppearanceProposalStage = get_stage_class("appearance.proposal")
AppearanceProposalParams = AppearanceProposalStage.Params

N_FRAMES = 16
SNAP_AT = 6
DROP = SNAP_AT + 2  # proposals of this frame are lost: the filter reuses its posterior


@pytest.fixture(scope="module")
def scene():
    sc = SyntheticScene(width=160, height=120, n_frames=N_FRAMES, seed=5, noise=3.0)
    frames = []
    for t in range(N_FRAMES):
        img = sc.render(t)
        if t == 11:
            img = np.zeros_like(img)  # a blank frame: the filter coasts
        frames.append(Frame(Header("s", t, t * 40_000_000), NDArray.of(img)))
    return sc, frames


def _stages(box):
    filt = AppearanceFilterStage(AppearanceFilterParams(init=box, particles=100, seed=2), StageContext("filter", "s"))
    prop = AppearanceProposalStage(AppearanceProposalParams(init=box, particles=100, seed=2), StageContext("proposal", "s"))
    return filt, prop


def _run(filt, prop, frames, first: int, parts: Particles | None) -> list[bytes]:
    out: list[bytes] = []
    for t in range(first, len(frames)):
        if t == 0:
            res = filt.step(0, {"frames": frames[0]})
        else:
            (_, proposals), = prop.step(t - 1, {"particles": parts})
            out.append(encode(proposals))
            res = filt.step(t, {"frames": frames[t], "proposals": None if t == DROP else proposals})
        for port, msg in res:
            out.append(encode(msg))
            if port == "particles":
                parts = msg
    return out


def test_restore_is_bit_exact_and_bad_frames_coast(scene):
    sc, frames = scene
    box = sc.truth_box(0)
    full = _run(*_stages(box), frames, 0, None)
    filt, prop = _stages(box)
    straight = _run(filt, prop, frames[: SNAP_AT + 1], 0, None)
    snap = filt.snapshot()
    last = [m for m in map(decode, straight) if isinstance(m, Particles) and m.kind == "posterior"][-1]
    filt2, prop2 = _stages(box)
    filt2.restore(snap)
    resumed = _run(filt2, prop2, frames, SNAP_AT + 1, last)
    assert resumed == full[len(straight):]
    states = [m.state for m in map(decode, full) if isinstance(m, Estimate)]
    assert states[0] == "init" and states[11] == "coast" and set(states[1:11]) <= {"track", "occluded"}
    reports = [k for k, _, _ in filt2.drain_reports()]
    assert "missing_proposals" in reports and "blank_frame" in reports
    est = [m for m in map(decode, full) if isinstance(m, Estimate)]
    err = [np.hypot(e.box[0] + e.box[2] / 2 - (b[0] + b[2] / 2), e.box[1] + e.box[3] / 2 - (b[1] + b[3] / 2))
           for e, b in zip(est, (sc.truth_box(t) for t in range(N_FRAMES)))]
    assert np.mean(err) < 5.0


def test_a_snapshot_of_another_stage_is_refused(scene):
    sc, _ = scene
    filt, _ = _stages(sc.truth_box(0))
    with pytest.raises(ValueError, match="not an appearance.filter snapshot"):
        filt.restore(b"\x01\x02garbage")


def test_stage_parameters_are_the_core_parameters():
    from dataclasses import fields

    from gflow_core.appearance.params import AppearanceParams

    core = {f.name: f.default for f in fields(AppearanceParams)}
    for params in (AppearanceFilterParams(), AppearanceProposalParams()):
        stage = {k: v for k, v in msgspec.structs.asdict(params).items() if k not in ("init", "seed", "timed")}
        assert stage == core


def test_bad_parameters_are_refused_before_anything_runs():
    with pytest.raises(ValueError, match="n_scales"):
        AppearanceFilterParams(init=(1, 1, 5, 5), n_scales=2)
    with pytest.raises(ValueError, match="positive"):
        AppearanceFilterParams(init=(1, 1, 0, 5))
    with pytest.raises(ValueError, match="scale_anchor_weight"):
        AppearanceFilterParams(init=(1, 1, 5, 5), scale_anchor_weight=1.5)
    with pytest.raises(ValueError, match="scale_search"):
        AppearanceFilterParams(init=(1, 1, 5, 5), scale_search=-1)


def test_size_options_of_gflow_track():
    """The default searches scale; --fixed-size turns the search off; --track-scale puts the
    scale in the particle state instead (and turns the search off)."""
    from argparse import Namespace

    from pipeline.cli.trackers import appearance as cli

    base = dict(init=[1.0, 2.0, 30.0, 40.0], seed=1, particles=None)
    _, default = cli.overrides(Namespace(**base))
    assert "scale_search" not in default["tracker"] and AppearanceFilterParams().scale_search > 0
    _, fixed = cli.overrides(Namespace(**base, fixed_size=True))
    assert fixed["tracker"]["scale_search"] == 0  # the graph's tracker block: both stages take it
    _, state = cli.overrides(Namespace(**base, track_scale=True))
    assert state["tracker"]["scale_search"] == 0 and state["tracker"]["n_scales"] == 3
    assert state["tracker"]["std_log_s"] > 0
    assert "scale_search" not in state["filter"] and "std_log_s" not in state["proposal"]


@pytest.mark.slow
def test_crossing_processes_equal_inline_and_rerun_is_bit_exact(crossing, tmp_path, gflow_cmd):
    gt = read_boxes(crossing / "groundtruth.csv")
    init = ",".join(str(v) for v in gt[0])
    outs = {}
    for mode in ("mp", "inline"):
        csv = tmp_path / f"{mode}.csv"
        cmd = [*gflow_cmd, "track", str(crossing), "--tracker", "appearance", "--init", init, "--seed", "1", "--out",
               str(csv), "--record", str(tmp_path / f"{mode}.mcap"), "-q", "--stop", "60"]
        r = cli_fork.run_command(cmd + (["--inline"] if mode == "inline" else []), capture_output=True, text=True,
                                 timeout=300)
        assert r.returncode == 0, r.stderr
        outs[mode] = csv.read_bytes()
    assert outs["mp"] == outs["inline"]
    pred = read_boxes(tmp_path / "mp.csv")
    assert len(pred) == 60
    sc = score({k: gt[k] for k in pred}, pred)
    still = score({k: gt[k] for k in pred}, {k: gt[0] for k in pred})
    assert sc.cle < still.cle / 5 and sc.success > 0.9
    r = cli_fork.run_command([*gflow_cmd, "rerun", str(tmp_path / "mp.mcap"), "--stage", "filter", "--check"],
                             capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "differ" not in r.stdout.replace("no output differs", "")


def test_channels_prepared_ahead_on_a_second_thread_give_the_same_bytes(scene):
    """As a process, the host computes the channels of a frame on its second thread as soon as
    the frame arrives (Stage.prepare); the step then takes them. The outputs are the bytes of
    a host that prepares nothing (--inline), and at most AHEAD_LIMIT results wait at once."""
    import threading

    from pipeline.runtime.stage_host import AHEAD_LIMIT, StageHost

    sc, frames = scene
    runs = {}
    for ahead in (False, True):
        filt, prop = _stages(sc.truth_box(0))
        threads: list[int] = []
        real = filt.prepare
        filt.prepare = lambda port, msg: threads.append(threading.get_ident()) or real(port, msg)  # type: ignore[method-assign]
        out: list[tuple[str, bytes]] = []
        hf = StageHost(filt, {"frames": "f", "proposals": "q"}, {"particles": "p", "estimate": "e"}, "err",
                       lambda t, b, s, n="": out.append((t, b)), ahead=ahead)
        hp = StageHost(prop, {"particles": "p"}, {"proposals": "q"}, "err",
                       lambda t, b, s, n="": out.append((t, b)), ahead=ahead)
        for fr in frames:  # every frame first, as a source running ahead sends them
            hf.deliver("f", encode(fr))
            assert len(filt.ahead) <= AHEAD_LIMIT
        sent = 0
        while sent < len(out):  # then the particle -> proposal -> filter cycle
            topic, payload = out[sent]
            sent += 1
            (hp if topic == "p" else hf).deliver(topic, payload)
        hf.close()
        runs[ahead] = [b for t, b in out if t in ("p", "e")]
        assert hf.stats.steps == N_FRAMES
        if ahead:
            assert threads and threading.get_ident() not in threads and not filt.ahead
        else:
            assert set(threads) == {threading.get_ident()}
    assert runs[True] == runs[False]
