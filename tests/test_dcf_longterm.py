"""The dcf long-term filter (``longterm``, :mod:`gflow_core.dcf.longterm`): it learns only on frames the
target is present, confident and reliable by its own learnt distributions, never while the target is
hidden; the search for a hidden target uses it as its template and takes the target back; it is kept
in a snapshot bit for bit, and a snapshot without one still restores."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gflow_core.dcf.longterm import LongTerm, reliable
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER
from gflow_core.tracker import FrameRng, step
from gflow_core.visibility import ChiSquare
from tests.test_dcf_search_clutter import HIDE, _frames  # a target hidden by background on frames [10, 30)

def _same(a: LongTerm, b: LongTerm) -> bool:
    return (np.array_equal(a.det, b.det) and a.target == b.target and a.clutter == b.clutter
            and a.sclutter == b.sclutter and a.updates == b.updates)


def test_the_long_term_filter_learns_only_while_the_target_is_seen_and_takes_it_back() -> None:
    sc, frames = _frames()
    p = DCFParams(longterm=True)
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    assert st.longterm is not None and st.longterm.updates == 0
    first = st.longterm.det
    trace = []
    for t in range(1, len(frames)):
        before = st.longterm
        st, est = step(TRACKER, p, st, TRACKER.observe(p, frames[t]), FrameRng(1, 7, t))
        lt = st.longterm
        assert lt is not None
        trace.append((t, est.target_state, st.hidden_run, lt.updates, lt.sclutter.n))
        if st.hidden_run > 0:
            # nothing of the long-term filter is learnt while the target is unseen
            assert np.array_equal(lt.det, before.det) and lt.updates == before.updates, trace[-3:]
        if t == HIDE[1] - 1:
            arrays, values = to_arrays(st)
            back = from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), p)
            assert back.longterm is not None and _same(back.longterm, lt)
            # the search's own clutter of the long-term filter was learnt while hidden
            assert lt.sclutter.n >= p.hidden_after, trace
            # and the adaptive filter's, slid first, beside it
            assert st.sclutter.n == lt.sclutter.n
    seen = [u for t, _, _, u, _ in trace if t < HIDE[0]]
    assert seen[-1] > 0, trace  # it learnt while the target was in view ...
    assert not np.array_equal(st.longterm.det, first)
    # ... and the target, back in view, is taken back by the search with it
    assert trace[-1][1] == "tracked" and trace[-1][2] == 0, trace[-8:]


def test_a_frame_teaches_the_long_term_filter_only_when_its_distance_is_the_targets() -> None:
    p = DCFParams(longterm=True)
    target, clutter = ChiSquare(), ChiSquare()
    for rho in (0.50, 0.55, 0.52, 0.58, 0.54, 0.51, 0.56, 0.53, 0.57, 0.55):
        target = target.update(rho, p.target_rate)
    for rho in (0.85, 0.88, 0.83, 0.86, 0.87, 0.84, 0.86, 0.85, 0.88, 0.84):
        clutter = clutter.update(rho, p.clutter_rate)
    lt = LongTerm(np.zeros(1), np.zeros((1, 1, 1), complex), target, clutter)
    assert reliable(lt, 0.54, p)
    assert not reliable(lt, 0.85, p)
    # a stricter level refuses what a looser one takes
    assert reliable(lt, 0.56, dataclasses.replace(p, longterm_level=1.0))
    assert not reliable(lt, 0.56, dataclasses.replace(p, longterm_level=-1.0))


def test_without_longterm_nothing_is_kept_and_an_old_snapshot_restores() -> None:
    sc, frames = _frames()
    off = DCFParams()
    st, _ = TRACKER.init(off, TRACKER.observe(off, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    st, _ = step(TRACKER, off, st, TRACKER.observe(off, frames[1]), FrameRng(1, 7, 1))
    assert st.longterm is None
    arrays, values = to_arrays(st)
    assert not any(k.startswith("lt_") for k in (*arrays, *values))
    # a snapshot made without it, restored with longterm on: made from the adaptive model on the next frame
    on = DCFParams(longterm=True)
    back = from_arrays(arrays, values, on)
    assert back.longterm is None
    nxt, est = step(TRACKER, on, back, TRACKER.observe(on, frames[2]), FrameRng(1, 7, 2))
    assert nxt.longterm is not None and est.target_state == "tracked"


def test_a_long_term_filter_of_the_wrong_shape_is_refused() -> None:
    sc, frames = _frames()
    p = DCFParams(longterm=True)
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    arrays, values = to_arrays(st)
    arrays = dict(arrays, lt_det=arrays["lt_det"][:-1])
    with pytest.raises(ValueError, match="long-term filter"):
        from_arrays(arrays, values, p)


def test_its_parameters_are_checked() -> None:
    for bad in ({"longterm_rate": 0.0}, {"longterm_outlier": 1.0}, {"longterm_level": float("nan")}):
        with pytest.raises(ValueError, match="longterm"):
            DCFParams(**bad)


def test_the_search_tries_other_sizes_only_as_the_sizes_prior_spreads(monkeypatch) -> None:
    import gflow_core.dcf.tracker as tr

    sc, frames = _frames()
    p = DCFParams(search_sizes=5, search_size_step=0.2)
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    obs = TRACKER.observe(p, frames[HIDE[0] + 2])
    tried: list[tuple[float, ...]] = []
    real = tr.tm.search

    def spy(*args, **kw):
        tried.append(tuple(args[-1]))
        return real(*args, **kw)

    monkeypatch.setattr(tr.tm, "search", spy)
    for size_sd, want in ((0.0, (0.0,)), (0.1, (0.0, -0.2, 0.2)), (1.0, (0.0, -0.2, 0.2, -0.4, 0.4))):
        tried.clear()
        tr._search(st, obs, p, st.centre, (5.0, 5.0), 0.0, None, None, size_sd)
        assert tried == [want], (size_sd, tried)
