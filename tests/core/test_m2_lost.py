"""The lost-target guard of the contour particle filter (gflow_core.m2.lost): verification
against the initial box, the lost decision, re-detection over a window, and, on the filter
stage, a target that jumps beyond the reach of the proposals is found again (the paper's
filter, with the guard off, stays behind); with the frame's colour the search refuses a look-alike
of another colour that the edges alone would take back."""

from __future__ import annotations

from dataclasses import replace

import cv2
import msgspec
import numpy as np
import pytest

from gflow_core import colour
from gflow_core.m2 import lost
from gflow_core.evaluation.metrics import centre_error
from gflow_core.visibility import ChiSquare
from stages.base import StageContext
from gflow_msgs.messages import ColourFeatures, Frame, Header, NDArray
from stages.particle_filter import FilterParams, FilterStage
from stages.particle_proposal import ProposalParams, ProposalStage
from stages.preprocess import PreprocessParams, PreprocessStage

from test_appearance import Scene

P = lost.LostParams()


class FramedScene(Scene):
    """The target pasted inside a plain 10 px frame, so its neighbourhood (which the local
    normalisation of the channels sees) is the same wherever it goes."""

    def grey(self, t: int) -> np.ndarray:
        img = Scene.grey(self, t).astype(np.float32)
        x, y, w, h = self.truth(t)
        x0, y0 = int(round(x)), int(round(y))
        inner = img[y0:y0 + int(round(h)), x0:x0 + int(round(w))].copy()
        img[max(y0 - 10, 0):y0 + int(round(h)) + 10, max(x0 - 10, 0):x0 + int(round(w)) + 10] = 128.0
        img[y0:y0 + inner.shape[0], x0:x0 + inner.shape[1]] = inner
        return np.clip(img, 0, 255).astype(np.uint8)


def _jump_path(t: int):
    # still, then 80 px to the right at frame 12 (the chamfer proposals move ~1 px a frame)
    return (100.0 if t < 12 else 180.0), 120.0, 1.0


def test_verify_search_and_the_lost_decision() -> None:
    scene = FramedScene(_jump_path, 20)
    box0 = scene.truth(0)
    ch0 = lost.channels(scene.grey(0))
    anchor = lost.anchor_of(ch0, box0, P)
    assert lost.verify(ch0, anchor, box0) > 0.9
    ch = lost.channels(scene.grey(15))
    # the target left the box: r is low there, and the clutter around it is sampled
    obs = lost.observe(ch, anchor, box0, P)
    assert obs.r < 0.3 and obs.clutter is not None and obs.clutter[1] > 0
    # a box whose centre left the frame does not verify
    assert lost.verify(ch, anchor, (-80.0, 10.0, 30.0, 40.0)) == -1.0
    # the decision: found frames set the target's distribution, clutter-like r is lost and holds
    st = lost.LostState()
    for i in range(P.warmup + 5):
        st, vis, is_lost = lost.judge(st, lost.Observation(0.8 + 0.02 * (i % 3), (0.25 + 0.03 * (i % 2), 900.0)),
                                      (1.0, 2.0, 3.0, 4.0, float(i)), P)
        assert not is_lost
    assert vis.visible > 0.5
    st, vis, is_lost = lost.judge(st, lost.Observation(0.2, (0.25, 900.0)), (9.0, 9.0, 9.0, 9.0, 9.0), P)
    assert is_lost and vis.hidden > 0.5 and st.held == (1.0, 2.0, 3.0, 4.0, float(P.warmup + 4)) and st.lost_run == 1
    # while lost, a half-way r (better than clutter, not the target's look) does not bring it back
    st, vis, is_lost = lost.judge(st, lost.Observation(0.5, (0.25, 900.0)), (9.0, 9.0, 9.0, 9.0, 9.0), P)
    assert is_lost and st.lost_run == 2
    # the search over a widening window finds the target 80 px (2.7 box widths) away, once the
    # window reaches it, and judges it visible
    found = []
    for _ in range(20):
        cand, cvis, covers = lost.search(ch, anchor, box0, st, P, (1.0,), 900.0)
        found.append(cand is not None and cand.r > 0.8 and cvis is not None and cvis.visible > 0.5)
        st = lost.LostState(target=st.target, clutter=st.clutter, found=st.found, lost_run=st.lost_run + 1, held=st.held)
    assert not found[0] and found[-1], found
    truth = scene.truth(15)
    assert np.hypot(*(cand.centre - (truth[0] + (truth[2] - 1) / 2, truth[1] + (truth[3] - 1) / 2))) < 2.0
    with pytest.raises(ValueError, match="lost guard"):
        lost.LostParams(rate=1.5)


def _track(scene: Scene, guard: bool) -> tuple[np.ndarray, list[str]]:
    box0 = scene.truth(0)
    ctx = lambda name: StageContext(name, "s")  # noqa: E731
    pre = PreprocessStage(PreprocessParams(calibrate_box=box0), ctx("preprocess"))
    prop = ProposalStage(ProposalParams(seed=1), ctx("proposal"))
    filt = FilterStage(FilterParams(init=box0, seed=1, particles=300, lost_guard=guard, lost_window=3.0),
                       ctx("filter"))
    boxes, states, parts = [], [], None
    for t in range(scene.n):
        img = scene.grey(t)
        (_, feat), = pre.step(t, {"frames": Frame(Header("s", t, t * 40_000_000), NDArray.of(img))})
        if t == 0:
            out = filt.step(0, {"features": feat})
        else:
            (_, proposals), = prop.step(t - 1, {"particles": parts})
            out = filt.step(t, {"features": feat, "proposals": proposals})
        for port, msg in out:
            if port == "particles":
                parts = msg
            else:
                boxes.append(msg.box)
                states.append(msg.state)
    return np.array(boxes), states


def test_the_filter_finds_a_target_that_jumped_beyond_its_proposals() -> None:
    scene = FramedScene(_jump_path, 30)
    truth = np.array([scene.truth(t) for t in range(scene.n)])
    boxes, states = _track(scene, guard=True)
    err = centre_error(truth, boxes)
    assert "redetect" in states[12:]
    assert err[20:].max() < 4.0, err
    # the paper's filter (no guard) does not follow the jump
    boxes0, states0 = _track(scene, guard=False)
    assert centre_error(truth, boxes0)[20:].mean() > 20.0
    assert "redetect" not in states0 and "lost" not in states0


def test_redetect_at_several_sizes_finds_a_grown_target() -> None:
    """A textured square that grew by 15% and moved is re-found at the larger size."""
    import cv2

    rng = np.random.default_rng(3)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (40, 40)).astype(np.float32), (0, 0), 1.5)

    def frame(cx: float, cy: float, size: float) -> np.ndarray:
        img = np.full((160, 200), 128, np.float32)
        t = cv2.resize(tex, (int(round(size)), int(round(size))), interpolation=cv2.INTER_LINEAR)
        x0, y0 = int(round(cx - size / 2)), int(round(cy - size / 2))
        img[y0 : y0 + t.shape[0], x0 : x0 + t.shape[1]] = t
        return img

    p = lost.LostParams(window=1.5)
    box0 = (60.0, 50.0, 40.0, 40.0)
    anchor = lost.anchor_of(lost.channels(frame(79.5, 69.5, 40)), box0, p)
    ch = lost.channels(frame(95.0, 75.0, 46))
    st = lost.LostState(lost_run=1)
    c1, _, _ = lost.search(ch, anchor, box0, st, p, (1.0,), None)
    c, _, _ = lost.search(ch, anchor, box0, st, p, (1.0, 0.87, 1.15), None)
    assert c1 is not None and c is not None
    assert np.isclose(np.exp(c.log_f), 1.15) and c.r > c1.r + 0.05 and c1.log_f == 0.0
    assert np.hypot(*(c.centre - [95.0, 75.0])) < 3.0


def _two_lookalikes(cover: bool, t: int, dx: int = 75) -> tuple[np.ndarray, np.ndarray]:
    """A reddish target at (40, 60) and, ``dx`` px to its right, a bluish look-alike whose block pattern
    differs in 9 of 30 blocks, on a background of coloured blocks; ``cover``: a patch of other
    blocks hides the target. Returns the BGR frame (H, W, 3) and its grey levels (H, W)."""
    rng = np.random.default_rng(3)
    blocks = rng.integers(0, 2, (6, 5))
    other = blocks.copy()
    other.flat[rng.choice(30, 9, replace=False)] ^= 1
    bg = np.kron(rng.uniform(60, 200, (20, 30, 3)), np.ones((8, 8, 1)))
    noise = np.random.default_rng(t)
    img = bg.copy()
    for (x, y), pattern, tint in (((40, 60), blocks, (0.35, 0.45, 1.0)), ((40 + dx, 60), other, (1.0, 0.6, 0.35))):
        tex = np.kron(pattern, np.ones((6, 6))) * 150 + 60
        img[y:y + 36, x:x + 30] = tex[..., None] * np.array(tint)
    if cover:
        x1 = min(80, 40 + dx - 2)  # up to the look-alike, not over it
        img[50:106, 30:x1] = np.kron(noise.uniform(60, 200, (7, 7, 3)), np.ones((8, 8, 1)))[:56, :x1 - 30]
    img = (img + noise.normal(0, 8, img.shape)).clip(0, 255).astype(np.uint8)
    return img, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


@pytest.mark.parametrize("with_colour", [False, True])
def test_colour_keeps_the_search_off_a_lookalike_of_another_colour(with_colour: bool) -> None:
    """With the frame's colour bins the guard weighs each candidate's colour histogram against the
    initial box's: a look-alike whose edges the edges alone take for the target partly seen is
    refused, and the target itself is taken back once it is uncovered. (A clutter ring of one box size:
    the look-alike is then refused by its colour alone, not by the wider clutter sample of the default.)"""
    P = replace(lost.LostParams(), ring=1.0)  # noqa: N806 - the module's P, narrowed
    box = (40.0, 60.0, 30.0, 36.0)
    img, grey = _two_lookalikes(False, 0)
    bins = colour.bins(img) if with_colour else None
    anchor = lost.anchor_of(lost.channels(grey), box, P, bins)
    st = lost.LostState()
    for t in range(P.warmup + 10):
        img, grey = _two_lookalikes(False, t)
        obs = lost.observe(lost.channels(grey), anchor, box, P, colour.bins(img) if with_colour else None)
        st, vis, is_lost = lost.judge(st, obs, (*box, 0.0), P)
        assert not is_lost
    assert (st.ctarget.n > 0) == with_colour
    assert obs.clutter is not None
    img, grey = _two_lookalikes(True, 100)
    ch, bins = lost.channels(grey), colour.bins(img) if with_colour else None
    st, vis, is_lost = lost.judge(st, lost.observe(ch, anchor, box, P, bins), (*box, 0.0), P)
    assert is_lost
    st = replace(st, lost_run=st.lost_run + 16)  # the window has widened past the look-alike
    cand, cvis, _ = lost.search(ch, anchor, box, st, P, (1.0,), obs.clutter[1], bins)
    assert cand is not None and cvis is not None and abs(cand.centre[0] - 129.5) < 3  # the look-alike
    assert cvis.present != with_colour, cvis
    # uncovered, the target is found again (with or without colour)
    img, grey = _two_lookalikes(False, 101)
    ch, bins = lost.channels(grey), colour.bins(img) if with_colour else None
    cand, cvis, _ = lost.search(ch, anchor, box, st, P, (1.0,), obs.clutter[1], bins)
    assert cand is not None and cvis is not None and cvis.visible >= 0.5 and abs(cand.centre[0] - 54.5) < 3


@pytest.mark.parametrize("ring", [1.0, 1.5])
def test_the_clutter_ring_reaches_a_lookalike_beside_the_target(ring: float) -> None:
    """The clutter is sampled as far as the search's first window reaches (``ring`` 1.5 box sizes, the
    default): a look-alike 1.2 box widths beside the target is then part of the clutter model, and once
    the target is covered the search does not take it for the target (edges alone). Sampled within one
    box size, it never was, and the search takes it."""
    p = replace(P, ring=ring)
    box = (40.0, 60.0, 30.0, 36.0)
    _, grey = _two_lookalikes(False, 0, dx=36)
    anchor = lost.anchor_of(lost.channels(grey), box, p)
    st = lost.LostState()
    for t in range(p.warmup + 20):
        _, grey = _two_lookalikes(False, t, dx=36)
        obs = lost.observe(lost.channels(grey), anchor, box, p)
        st, _, is_lost = lost.judge(st, obs, (*box, 0.0), p)
        assert not is_lost
    assert obs.clutter is not None
    _, grey = _two_lookalikes(True, 100, dx=36)
    ch = lost.channels(grey)
    st, _, is_lost = lost.judge(st, lost.observe(ch, anchor, box, p), (*box, 0.0), p)
    assert is_lost
    cand, cvis, _ = lost.search(ch, anchor, box, st, p, (1.0,), obs.clutter[1])
    assert cand is not None and cvis is not None and abs(cand.centre[0] - (76 + 14.5)) < 3  # the look-alike
    assert cvis.present == (ring == 1.0), (st.clutter.mean(), cand.r, cvis)


def test_a_colour_cue_that_does_not_tell_target_from_clutter_is_left_out() -> None:
    """The hypotheses read a distance one-sidedly (closer than usual is the target): a colour cue whose
    target distances are not below its clutter's (a face that walked from a dark room into the light,
    far from its first box's colours) would call any patch of the first box's colours the target. It
    is left out, and the decision is the edges' alone."""
    edges = dict(target=ChiSquare(0.2, 0.045, 30), clutter=ChiSquare(0.7, 0.5, 30), found=30)
    informative = lost.LostState(**edges, ctarget=ChiSquare(0.1, 0.0125, 30),
                                 cclutter=ChiSquare(0.5, 0.26, 30))
    inverted = lost.LostState(**edges, ctarget=ChiSquare(0.8, 0.65, 30), cclutter=ChiSquare(0.3, 0.1, 30))
    seen = lost.Observation(0.55, (0.3, 900.0), lost.ColourSeen(0.05, (0.3, 900.0)))
    alone = lost.judge(lost.LostState(**edges), replace(seen, colour=None), (0.0, 0.0, 1.0, 1.0), P)[1]
    assert lost.judge(inverted, seen, (0.0, 0.0, 1.0, 1.0), P)[1] == alone
    assert lost.judge(informative, seen, (0.0, 0.0, 1.0, 1.0), P)[1].visible > alone.visible


def test_colour_bins_of_the_wrong_shape_are_reported_and_the_guard_weighs_the_edges() -> None:
    """A features message whose colour bins do not fit its grey image is reported (``bad_features``)
    and the filter goes on with the edges alone, as on a frame with no bins."""
    img, grey = _two_lookalikes(False, 0)
    box = (40.0, 60.0, 30.0, 36.0)
    pre = PreprocessStage(PreprocessParams(calibrate_box=box, colour=True), StageContext("preprocess", "s"))
    filt = FilterStage(FilterParams(init=box, seed=1, particles=100), StageContext("filter", "s"))
    prop = ProposalStage(ProposalParams(seed=1), StageContext("proposal", "s"))
    (_, feat), = pre.step(0, {"frames": Frame(Header("s", 0, 0), NDArray.of(img))})
    assert isinstance(feat, ColourFeatures)
    out = filt.step(0, {"features": feat})
    parts = next(m for p, m in out if p == "particles")
    (_, feat1), = pre.step(1, {"frames": Frame(Header("s", 1, 40_000_000), NDArray.of(img))})
    bad = msgspec.structs.replace(feat1, bins=NDArray.of(np.zeros((5, 5), np.uint8)))
    (_, proposals), = prop.step(0, {"particles": parts})
    out = filt.step(1, {"features": bad, "proposals": proposals})
    assert any(p == "estimate" for p, _ in out)
    assert [k for k, _, _ in filt.drain_reports()] == ["bad_features"]
