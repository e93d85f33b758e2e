"""A re-detection checked by the first frame's filter (gflow_core.dcf.verify, ``verify``): a search that offers
something else at another size takes it back as the hidden target; with ``verify`` the anchor, which never
learnt it, refuses it, and still takes the target itself back; what the search finds at the held size is
judged as before. The roll at detection is refused
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
    """The background with each patch (h, w) centred at its (x, y), plus a little noise."""
    img = BG.copy()
    for patch, (cx, cy) in patches:
        h, w = patch.shape
        x, y = int(round(cx - (w - 1) / 2.0)), int(round(cy - (h - 1) / 2.0))
        img[y:y + h, x:x + w] = patch
    img += np.random.default_rng([5, t]).normal(0.0, 3.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _usual(mean: float, sd: float, n: int = 30) -> ChiSquare:
    return ChiSquare(mean, mean * mean + sd * sd, n)


def _hidden(p: DCFParams) -> tuple[tr.DCFState, np.ndarray]:
    """A hidden target held at (130, 100): its filter's distances usual at 0.5 (the clutter's far from it), the
    anchor's about its distance at the target on the first frame (the spread as learnt on the stress cases,
    0.08-0.11)."""
    first = TRACKER.observe(p, _frame([(TARGET, (130.0, 100.0))], 0))
    st = tr.initialise(first, (115.5, 82.5, *BOX), p, np.random.default_rng(0))
    rho_t, rho_away = conservative(st.model, first.image, first.grey, (130.0, 100.0), 0.0, 0.0, st.geom, p)
    st = dataclasses.replace(st, target=_usual(0.5, 0.05), clutter=_usual(0.9, 0.03), hidden_run=5,
                             vtarget=_usual(rho_t, 0.08), vclutter=_usual(rho_away, 0.05))
    return st, np.array([130.0, 100.0])


def _grown(patch: np.ndarray, log_f: float) -> np.ndarray:
    h, w = patch.shape
    return cv2.resize(patch, (int(round(w * np.exp(log_f))), int(round(h * np.exp(log_f)))), interpolation=cv2.INTER_CUBIC)


def _offer(monkeypatch, log_f: float) -> None:
    """The search's filter offers, at the held size, nothing like the target, and at ``log_f`` a placement at
    (170, 100) scoring as the target usually does (what a filter that learnt something else would offer)."""
    def offered(model, image, grey, hold, margin, log_s, geom, p, sizes=(0.0,)):
        return [tm.Candidate(0.05, np.array(hold, dtype=float), 0.0, 40000.0),
                tm.Candidate(0.5, np.array([170.0, 100.0]), log_f, 40000.0)]
    monkeypatch.setattr(tr.tm, "search", offered)


def _search(st: tr.DCFState, frame: np.ndarray, p: DCFParams, pred: np.ndarray) -> tr.Search:
    return tr._search(st, TRACKER.observe(p, frame), p, pred, (10.0, 10.0), 25.0, None, None, 0.2)


def test_a_placement_at_another_size_is_refused_unless_the_first_filter_sees_the_target(monkeypatch) -> None:
    """Another object, 1.22 times the target's size, offered at that size 40 px from the held box: taken
    without ``verify``, refused with it (the anchor scores it as clutter); the target itself grown as much and
    offered so is taken with ``verify`` too."""
    off = DCFParams(colour_weight=0.0, search_sizes=5)
    on = dataclasses.replace(off, verify=2.0)
    st, pred = _hidden(off)
    _offer(monkeypatch, 0.2)
    other = _frame([(_grown(OTHER, 0.2), (170.0, 100.0))], 2)
    found = _search(st, other, off, pred).found
    assert found is not None and found.log_f == 0.2
    assert _search(st, other, on, pred).found is None
    target = _frame([(_grown(TARGET, 0.2), (170.0, 100.0))], 3)
    found = _search(st, target, on, pred).found
    assert found is not None and found.log_f == 0.2


def test_a_placement_at_the_held_size_is_judged_as_without_verify(monkeypatch) -> None:
    """What the default's search would take (the held size) is not checked: the other object offered at the
    held size is taken with ``verify`` as without (the first filter refuses a target come back looking
    otherwise as readily as an impostor, so only what the wider search adds is checked)."""
    on = DCFParams(colour_weight=0.0, search_sizes=5, verify=2.0)
    st, pred = _hidden(on)
    _offer(monkeypatch, 0.0)
    found = _search(st, _frame([(OTHER, (170.0, 100.0))], 2), on, pred).found
    assert found is not None and found.log_f == 0.0 and found.centre[0] == 170.0


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
