"""Filter stages' snapshot() / restore(): restoring the state after frame m on a fresh stage
and feeding the inputs of frames m+1.. gives the same outputs, bit for bit, as a straight run.

Covers the K = 1 chamfer filter, the filter with a learned M2 contour model, and the patch
filter with a learned shuffle model, on the synthetic scene (no data folder needed).
"""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from gflow_core.m2 import training
from gflow_core.m2.learn import learn
from gflow_core.synthetic import SyntheticScene
from stages.base import StageContext
from gflow_msgs.messages import ColourFeatures, Estimate, Frame, Header, NDArray, Particles, decode, encode
from gflow_core.contour import state as wire
from stages.particle_filter import FilterParams, FilterStage
from stages.particle_proposal import ProposalParams, ProposalStage
from stages.patch_filter import PatchFilterParams, PatchFilterStage
from stages.preprocess import PreprocessParams, PreprocessStage

N_FRAMES = 14
SNAP_AT = 6
# the proposals of this frame are lost: the filter weighs its last posterior (restored state)
DROP = SNAP_AT + 1


@pytest.fixture(scope="module")
def scene_features():
    """Features of the synthetic scene (first frames) and its first truth box."""
    scene = SyntheticScene(width=160, height=120, n_frames=N_FRAMES, seed=3, noise=4.0)
    box = scene.truth_box(0)
    pre = PreprocessStage(PreprocessParams(calibrate_box=box, profile="quadratic", colour=True),
                          StageContext("preprocess", "s"))
    feats, frames = [], []
    for t in range(N_FRAMES):
        img = scene.render(t)
        if t in (9, 10):
            img = np.zeros_like(img)  # two blank frames: the filters coast over them
        frames.append(img)
        (_, f), = pre.step(t, {"frames": Frame(Header("s", t, t * 40_000_000), NDArray.of(img))})
        feats.append(f)
    return feats, frames, box, scene


def _run(filt, prop, feats, first: int, last_particles: Particles | None) -> tuple[list[bytes], Particles]:
    """Feed frames first..end; returns the encoded outputs and the last posterior."""
    out: list[bytes] = []
    parts = last_particles
    for t in range(first, len(feats)):
        if t == 0:
            res = filt.step(0, {"features": feats[0]})
        else:
            (_, proposals), = prop.step(t - 1, {"particles": parts})
            out.append(encode(proposals))
            res = filt.step(t, {"features": feats[t], "proposals": None if t == DROP else proposals})
        for port, msg in res:
            out.append(encode(msg))
            if port == "particles":
                parts = msg
    return out, parts  # type: ignore[return-value]


def _check_restore(make_filter, make_proposal, feats) -> list:
    straight, _ = _run(make_filter(), make_proposal(), feats, 0, None)
    # run to SNAP_AT, snapshot, and continue on fresh stage objects
    f1, p1 = make_filter(), make_proposal()
    head, parts = _run(f1, p1, feats[: SNAP_AT + 1], 0, None)
    fsnap, psnap = f1.snapshot(), p1.snapshot()
    assert isinstance(fsnap, bytes) and isinstance(psnap, bytes)
    f2, p2 = make_filter(), make_proposal()
    f2.restore(fsnap)
    p2.restore(psnap)
    tail, _ = _run(f2, p2, feats, SNAP_AT + 1, parts)
    assert head + tail == straight
    assert [k for k, _, _ in f2.drain_reports()] == ["missing_proposals"]
    return straight


def test_chamfer_filter_restore_is_bit_exact(scene_features) -> None:
    feats, _, box, _ = scene_features
    ctx = StageContext("filter", "s")
    outs = _check_restore(lambda: FilterStage(FilterParams(init=box, particles=200, lam=0.2, seed=4), ctx),
                          lambda: ProposalStage(ProposalParams(seed=4), StageContext("proposal", "s")), feats)
    assert len(outs) > 2 * N_FRAMES
    # the lost guard weighed colour (the scene is in colour), and its colour model was restored
    assert isinstance(feats[0], ColourFeatures) and feats[0].bins is not None
    f = FilterStage(FilterParams(init=box, particles=200, lam=0.2, seed=4), ctx)
    _run(f, ProposalStage(ProposalParams(seed=4), StageContext("proposal", "s")), feats[: SNAP_AT + 1], 0, None)
    g = FilterStage(FilterParams(init=box, particles=200, lam=0.2, seed=4), ctx)
    g.restore(f.snapshot())
    assert f.state is not None and g.state is not None and f.state.anchor is not None and g.state.anchor is not None
    assert f.state.lost.ctarget.n > 0 and g.state.lost.ctarget == f.state.lost.ctarget
    assert np.array_equal(g.state.anchor.colour, f.state.anchor.colour)
    # a version-3 snapshot (before the colour cue) restores with a guard that weighs the edges alone
    snap = wire.decode(f.snapshot())
    old = msgspec.structs.replace(snap, version=3, anchor_colour=None, lost_ctarget=(0.0, 0.0, 0),
                                  lost_cclutter=(0.0, 0.0, 0))
    h = FilterStage(FilterParams(init=box, particles=200, lam=0.2, seed=4), ctx)
    h.restore(wire.encode(old))
    assert h.state is not None and h.state.anchor is not None and h.state.anchor.colour is None
    assert h.state.lost.target == f.state.lost.target and h.state.lost.ctarget.n == 0
    # a snapshot before the first frame restores to an uninitialised filter
    fresh = FilterStage(FilterParams(init=box, particles=200, lam=0.2, seed=4), ctx)
    again = FilterStage(FilterParams(init=box, particles=200, lam=0.2, seed=4), ctx)
    again.restore(fresh.snapshot())
    assert again.state is None and again.required(0) == {"features"}


@pytest.fixture(scope="module")
def contour_model(scene_features):
    _, frames, _, scene = scene_features
    boxes = np.array([scene.truth_box(t) for t in range(N_FRAMES)])
    ts = training.curves_from_boxes(frames, boxes, max_points=60)
    return learn(ts, "chamfer", K=3)


def test_learned_filter_restore_is_bit_exact(scene_features, contour_model) -> None:
    feats, _, box, _ = scene_features
    res = {"model": contour_model}
    make_f = lambda: FilterStage(FilterParams(init=box, particles=150, seed=2, model="m.npz"),  # noqa: E731
                                 StageContext("filter", "s", res))
    make_p = lambda: ProposalStage(ProposalParams(seed=2, model="m.npz"), StageContext("proposal", "s", res))  # noqa: E731
    _check_restore(make_f, make_p, feats)
    # the blank frames coast; the others are weighed
    f = make_f()
    _run(f, make_p(), feats[:10], 0, None)
    assert f.last["state"] == "coast"
    # a K = 1 snapshot cannot be restored into a filter with a learned model
    k1 = FilterStage(FilterParams(init=box, particles=150, seed=2), StageContext("filter", "s"))
    _run(k1, ProposalStage(ProposalParams(seed=2), StageContext("proposal", "s")), feats[:2], 0, None)
    with pytest.raises(ValueError, match="without a learned model"):
        make_f().restore(k1.snapshot())
    with pytest.raises(ValueError, match="not a particle.filter snapshot"):
        make_f().restore(b"\x01\x02")


def test_patch_filter_restore_is_bit_exact(scene_features) -> None:
    feats, frames, _, _ = scene_features
    ts = training.patches_from_frames(frames, (24, 32))
    model = learn(ts, "shuffle", K=3)
    res = {"model": model}
    make_f = lambda: PatchFilterStage(PatchFilterParams(model="m.npz", particles=100, seed=1),  # noqa: E731
                                      StageContext("filter", "s", res))
    make_p = lambda: ProposalStage(ProposalParams(seed=1, model="m.npz"), StageContext("proposal", "s", res))  # noqa: E731
    outs = _check_restore(make_f, make_p, feats)
    ks = [m.k for m in map(decode, outs) if isinstance(m, Estimate)]
    assert len(ks) == N_FRAMES and all(0 <= k < 3 for k in ks)
    # proposals of a patch model keep alpha (no alpha transform, sec. 5.2)
    f, p = make_f(), make_p()
    (_, parts), _ = f.step(0, {"features": feats[0]})
    (_, prop), = p.step(0, {"particles": parts})
    assert np.array_equal(prop.alpha.array(), parts.alpha.array())


def test_the_patch_protocol_steps_as_the_stages_do(scene_features) -> None:
    """M2 with a patch model on the protocol (gflow_core.m2.patch_protocol.PATCH: observe, init,
    propose, update) gives the patch filter stage's posterior and estimates bit for bit, blank frames
    (coasting) included."""
    from gflow_core.m2.patch_protocol import PATCH, PatchParams
    from gflow_core.tracker import FrameRng
    from gflow_core.tracker import stream_hash

    feats, frames, _, _ = scene_features
    model = learn(training.patches_from_frames(frames, (24, 32)), "shuffle", K=3)
    res, params = {"model": model}, PatchParams(particles=100)
    f = PatchFilterStage(PatchFilterParams(model="m.npz", particles=100, seed=1), StageContext("filter", "s", res))
    p = ProposalStage(ProposalParams(seed=1, model="m.npz"), StageContext("proposal", "s", res))
    rng = lambda t: FrameRng(1, stream_hash("s"), t)  # noqa: E731
    obs = lambda t: PATCH.observe(params, feats[t].grey.array())  # noqa: E731
    st, est = PATCH.init(params, obs(0), None, rng(0), {"model": model.to_patch_exemplars()})
    (_, parts), (_, e) = f.step(0, {"features": feats[0]})
    phases = []
    for t in range(N_FRAMES):
        if t > 0:
            (_, prop), = p.step(t - 1, {"particles": parts})
            (_, parts), (_, e) = f.step(t, {"features": feats[t], "proposals": prop})
            st, est = PATCH.update(params, st, PATCH.propose(params, st, None, rng(t)), obs(t), rng(t))
        assert np.array_equal(parts.k.array(), st.k) and e.box == est.box
        assert (e.k, e.state, e.ess, e.log_evidence) == (est.extras["k"], est.phase, est.extras["ess"],
                                                          est.extras["log_evidence"])
        phases.append(est.phase)
    assert phases[0] == "init" and phases[9:11] == ["coast", "coast"] and phases.count("track") == N_FRAMES - 3


def test_appearance_filter_restore_is_bit_exact_and_starts_on_the_box(scene_features) -> None:
    """Chamfer x appearance likelihood with a busy online bank (added every 2 frames, bound 3):
    restore is bit exact, and frame 0's estimate is the init box itself."""
    from gflow_core.features import to_grey

    feats, frames, box, scene = scene_features
    boxes = np.array([scene.truth_box(t) for t in range(N_FRAMES)])
    ts = training.curves_from_boxes(frames, boxes, max_points=60)
    model = learn(ts, "chamfer", K=3, frames=[to_grey(frames[int(t)]) for t in ts.frame_index])
    assert model.appearance is not None and model.appearance.patches.shape[0] == 3
    res = {"model": model}
    params = FilterParams(init=box, particles=150, seed=2, model="m.npz", online=3, online_every=2, confident_r=-1.0)
    make_f = lambda: FilterStage(params, StageContext("filter", "s", res))  # noqa: E731
    make_p = lambda: ProposalStage(ProposalParams(seed=2, model="m.npz", init=box),  # noqa: E731
                                   StageContext("proposal", "s", res))
    outs = _check_restore(make_f, make_p, feats)
    first = next(m for m in map(decode, outs) if isinstance(m, Estimate))
    assert first.box == tuple(float(v) for v in box) and first.state == "init"
    f = make_f()
    _run(f, make_p(), feats, 0, None)
    assert f.state is not None and f.state.bank is not None and f.state.bank.n == 3 and f.state.bank.frame[0] == 0


def test_proposal_reverts_log_s_to_the_start_box(contour_model) -> None:
    """With init, the AR(1) on log s reverts to the start box's scale, not the training mean."""
    box = (40.0, 30.0, 11.0, 23.0)
    res = {"model": contour_model}
    p = ProposalStage(ProposalParams(seed=1, model="m.npz", init=box), StageContext("proposal", "s", res))
    learned = ProposalStage(ProposalParams(seed=1, model="m.npz"), StageContext("proposal", "s", res))
    assert p.propose.dynamics.mean[3] == pytest.approx(np.log(contour_model.alpha_from_box(box)[3]))
    assert np.array_equal(p.propose.dynamics.mean[:3], contour_model.dynamics.mean[:3])
    assert np.array_equal(learned.propose.dynamics.mean, contour_model.dynamics.mean)
    with pytest.raises(ValueError, match="positive width"):
        ProposalParams(init=(0.0, 0.0, 0.0, 5.0))
