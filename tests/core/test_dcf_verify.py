"""A re-detection checked by the first frame's filter (gflow_core.dcf.verify, ``verify``): a filter that has
learnt the look of something else takes that thing back as the hidden target; with ``verify`` the anchor,
which never learnt it, refuses it, and still takes the target itself back. The roll at detection is refused
the same way; the anchor's distances are learnt on confident frames and kept in a snapshot; the option is
checked in one line."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf import tracker as tr
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.rotation import detect
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER
from gflow_core.dcf.verify import accepted, conservative
from gflow_core.tracker import FrameRng, step
from gflow_core.visibility import ChiSquare

H, W = 200, 260
BOX = (30.0, 36.0)


def _texture(rng: np.random.Generator, h: int, w: int, cell: float) -> np.ndarray:
    small = rng.uniform(0, 255, size=(max(2, int(h / cell)), max(2, int(w / cell)))).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


_RNG = np.random.default_rng(3)
BG = _texture(_RNG, H, W, 10.0)
TARGET = _texture(_RNG, 36, 30, 5.0)
OTHER = _texture(_RNG, 36, 30, 5.0)


def _frame(patches: list[tuple[np.ndarray, tuple[float, float]]], t: int) -> np.ndarray:
    """The background with each patch (36 x 30) centred at its (x, y), plus a little noise."""
    img = BG.copy()
    for patch, (cx, cy) in patches:
        x, y = int(round(cx - 14.5)), int(round(cy - 17.5))
        img[y:y + 36, x:x + 30] = patch
    img += np.random.default_rng([5, t]).normal(0.0, 3.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _usual(mean: float, sd: float, n: int = 30) -> ChiSquare:
    return ChiSquare(mean, mean * mean + sd * sd, n)


def _hidden(p: DCFParams, polluted: bool) -> tuple[tr.DCFState, np.ndarray]:
    """A hidden target held at (130, 100), its anchor the target's; with ``polluted`` its adaptive filter has
    learnt another object (its running filter is the filter of OTHER). The filter's distance distribution
    is as it learnt it (about its own distance at what it learnt; the clutter far from it), the anchor's about
    its distance at the target on the first frame (the spread as learnt on the stress cases, 0.08-0.11)."""
    first = TRACKER.observe(p, _frame([(TARGET, (130.0, 100.0))], 0))
    st = tr.initialise(first, (115.5, 82.5, *BOX), p, np.random.default_rng(0))
    seen = first
    if polluted:
        seen = TRACKER.observe(p, _frame([(OTHER, (130.0, 100.0))], 1))
        mdl = tm.init_model(seen.image, seen.grey, seen.is_grey, (130.0, 100.0), st.geom, p)
        st = dataclasses.replace(st, model=dataclasses.replace(st.model, det=mdl.det, train=mdl.train))
    r = tm.respond(st.model, seen.image, seen.grey, (130.0, 100.0), 0.0, st.geom, p)
    rho = 1.0 - float(r.at(np.array([[130.0, 100.0]]), "cf")[0])
    rho_t, rho_away = conservative(st.model, first.image, first.grey, (130.0, 100.0), 0.0, 0.0, st.geom, p)
    st = dataclasses.replace(st, target=_usual(rho, 0.05), clutter=_usual(0.9, 0.03), hidden_run=5,
                             vtarget=_usual(rho_t, 0.08), vclutter=_usual(rho_away, 0.05))
    return st, np.array([130.0, 100.0])


def _search(st: tr.DCFState, frame: np.ndarray, p: DCFParams, pred: np.ndarray) -> tr.Search:
    return tr._search(st, TRACKER.observe(p, frame), p, pred, (10.0, 10.0), 25.0, None)


def _at(found, xy: tuple[float, float]) -> bool:
    return found is not None and abs(found.centre[0] - xy[0]) < 4 and abs(found.centre[1] - xy[1]) < 4


def test_what_the_adaptive_filter_learnt_is_refused_by_the_anchor_and_the_target_still_taken() -> None:
    """The other object shown 40 px from the held box: the polluted filter scores it as the target and the
    search takes it; with ``verify`` the anchor scores it as clutter and nothing is taken. The target itself
    shown there to a filter that learnt it is taken back with ``verify`` as without."""
    off = DCFParams(colour_weight=0.0)
    on = dataclasses.replace(off, verify=2.0)
    st, pred = _hidden(off, polluted=True)
    other = _frame([(OTHER, (170.0, 100.0))], 2)
    assert _at(_search(st, other, off, pred).found, (170.0, 100.0))
    assert _search(st, other, on, pred).found is None
    st, pred = _hidden(off, polluted=False)
    target = _frame([(TARGET, (170.0, 100.0))], 3)
    assert _at(_search(st, target, off, pred).found, (170.0, 100.0))
    assert _at(_search(st, target, on, pred).found, (170.0, 100.0))


def test_accepted_needs_the_level_and_the_likelihood_ratio() -> None:
    p = DCFParams(verify=2.0)
    vt, vc = _usual(0.3, 0.05), _usual(0.8, 0.05)
    assert accepted(vt, vc, 0.32, p)
    assert not accepted(vt, vc, 0.45, p)  # beyond mean + 2 sd
    wide = _usual(0.6, 0.12)  # a target the anchor always scored poorly: the level is lax ...
    assert not accepted(wide, vc, 0.8, p)  # ... but the clutter explains 0.8 better
    assert accepted(wide, vc, 0.8, DCFParams())  # without verify, everything


def test_a_rolled_window_refused_by_verify_keeps_the_held_roll() -> None:
    """``detect`` with a check that refuses every rolled window returns the held roll and its response, where
    without the check it takes the roll that explains the look."""
    p = DCFParams(roll_step=10.0, roll_explain=0.0, roll_detect=True, colour_weight=0.0)
    img = _frame([(TARGET, (130.0, 100.0))], 0)
    g = img.astype(np.float32)
    geom = tm.geometry(BOX, p)
    mdl = tm.init_model(img, g, True, (130.0, 100.0), geom, p)
    rolled = cv2.warpAffine(img, cv2.getRotationMatrix2D((130.0, 100.0), -20.0, 1.0), (W, H),
                            borderMode=cv2.BORDER_REFLECT)

    def respond(a: float) -> tm.Response:
        return tm.respond(mdl, rolled, rolled.astype(np.float32), (130.0, 100.0), 0.0, geom, p, angle=a)

    r0 = respond(0.0)
    far = _usual(0.05, 0.02)  # every look is unusual: the gate is open
    _, a = detect(r0, respond, 0.0, far, p)
    assert a != 0.0
    r, a = detect(r0, respond, 0.0, far, p, lambda r, a: False)
    assert a == 0.0 and r is r0


def test_the_anchors_distances_are_learnt_with_verify_only_and_kept_in_a_snapshot() -> None:
    frames = [_frame([(TARGET, (100.0 + 2 * t, 100.0))], t) for t in range(6)]
    for p, learnt in ((DCFParams(verify=2.0), True), (DCFParams(), False)):
        st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), (85.5, 82.5, *BOX), FrameRng(1, 7, 0), {})
        for t, f in enumerate(frames[1:], start=1):
            st, _ = step(TRACKER, p, st, TRACKER.observe(p, f), FrameRng(1, 7, t))
        assert (st.vtarget.n > p.prior_count) == learnt and (st.vclutter.n > p.prior_count) == learnt
        arrays, values = to_arrays(st)
        back = from_arrays(arrays, values, p)
        assert back.vtarget == st.vtarget and back.vclutter == st.vclutter
        assert ("vtarget" in values) == learnt  # a state without them is stored as before the option


def test_its_parameter_is_checked() -> None:
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="verify"):
            DCFParams(verify=bad)
