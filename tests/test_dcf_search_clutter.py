"""The dcf search's own clutter (``search_clutter``): the distances of the search's best placements on
the frames the target stayed hidden are learnt, emptied once the target is seen again, kept in a
snapshot, and may only lower a candidate's density under "hidden", never raise it."""

from __future__ import annotations

import dataclasses

import numpy as np

from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER, _hidden_log_pdf
from gflow_core.tracker import FrameRng, step
from gflow_core.visibility import ChiSquare
from tests.core.test_dcf_tracker import Scene

HIDE = (10, 30)  # frames [10, 30): a patch of background covers the target


def hidden_frames(path, hide: tuple[int, int], n: int):
    """The scene of a target moving along ``path`` and its ``n`` frames, a patch of background over the
    target on frames [hide[0], hide[1])."""
    sc = Scene(path, seed=3)
    frames = []
    for t in range(n):
        img = sc.frame(t)
        if hide[0] <= t < hide[1]:
            x, y, w, h = (int(round(v)) for v in sc.truth(t))
            img[y - 4:y + h + 4, x - 4:x + w + 4] = sc.bg[y - 4:y + h + 4, x - 4:x + w + 4].astype(np.uint8)
        frames.append(img)
    return sc, frames


def _frames():
    return hidden_frames(lambda t: (110.0 + 1.5 * t, 95.0), HIDE, 42)


def test_the_search_learns_its_clutter_while_the_target_is_hidden_and_forgets_it_when_seen() -> None:
    sc, frames = _frames()
    p = DCFParams()
    assert p.search_clutter
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    seen_while_hidden, states = 0, []
    for t in range(1, len(frames)):
        st, est = step(TRACKER, p, st, TRACKER.observe(p, frames[t]), FrameRng(1, 7, t))
        states.append((t, st.hidden_run, st.sclutter.n, est.target_state))
        if st.hidden_run == 0:
            assert st.sclutter.n == 0  # seen (or taken back): emptied
        seen_while_hidden = max(seen_while_hidden, st.sclutter.n)
        if t == HIDE[1] - 1:
            arrays, values = to_arrays(st)
            back = from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), p)
            assert back.sclutter == st.sclutter
    assert seen_while_hidden >= p.hidden_after, states
    # the target is back in view and taken back by the end
    assert states[-1][1] == 0 and states[-1][3] == "tracked", states[-8:]
    # off: nothing is learnt
    off = dataclasses.replace(p, search_clutter=False)
    st, _ = TRACKER.init(off, TRACKER.observe(off, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    for t in range(1, HIDE[1]):
        st, _ = step(TRACKER, off, st, TRACKER.observe(off, frames[t]), FrameRng(1, 7, t))
        assert st.sclutter.n == 0


def test_the_search_clutter_only_ever_lowers_the_hidden_density() -> None:
    p = DCFParams()
    sc, frames = _frames()
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    learnt = ChiSquare()
    for rho in (0.82, 0.81, 0.83, 0.82, 0.80, 0.82, 0.81, 0.83, 0.82, 0.81, 0.80, 0.82):
        learnt = learnt.update(rho, p.clutter_rate)
    assert learnt.n >= p.search_min
    with_sc = dataclasses.replace(st, sclutter=learnt)
    off = dataclasses.replace(p, search_clutter=False)
    lower = 0
    for rho in np.linspace(0.3, 1.0, 36):
        window = _hidden_log_pdf(st, float(rho), 2.5, off)
        assert _hidden_log_pdf(with_sc, float(rho), 2.5, off) == window  # off: the window's clutter alone
        both = _hidden_log_pdf(with_sc, float(rho), 2.5, p)
        assert both <= window
        lower += both < window
    # a placement far better than every one the search gave while hidden is far less likely clutter
    assert _hidden_log_pdf(with_sc, 0.66, 2.5, p) < _hidden_log_pdf(st, 0.66, 2.5, p) - 5.0
    assert lower > 0
    # fewer than search_min searches: the window's clutter alone (a handful of placements, a few
    # thousandths apart, would make the distribution too narrow to judge by)
    few = ChiSquare()
    for rho in (0.82, 0.81, 0.83):
        few = few.update(rho, p.clutter_rate)
    young = dataclasses.replace(st, sclutter=few)
    assert _hidden_log_pdf(young, 0.66, 2.5, p) == _hidden_log_pdf(st, 0.66, 2.5, p)
    # ... which the search_min of the previous default (3) would have judged by
    assert _hidden_log_pdf(young, 0.66, 2.5, dataclasses.replace(p, search_min=3)) < \
        _hidden_log_pdf(st, 0.66, 2.5, p) - 5.0
