"""The dcf search's memory of places (``search_negatives``, :mod:`gflow_core.dcf.negatives`): where the search
kept putting its best placement while the target was hidden is remembered with the distances there; a
candidate at such a place that scores as the clutter there did is refused, one elsewhere or scoring as
the target does is judged as without the memory; the memory is emptied once the target is seen and is
kept in a snapshot."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gflow_core.dcf import negatives as neg
from gflow_core.dcf.model import Candidate
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER, _dists, _judge
from gflow_core.tracker import FrameRng, step
from tests.core.test_dcf_tracker import Scene
from tests.test_dcf_search_clutter import HIDE, hidden_frames

HALF = (15.0, 18.0)


def _places(n: int, rho: float = 0.8) -> tuple[neg.Place, ...]:
    """``n`` hidden frames whose best placement is about (100, 90) (within a few px) at distance about ``rho``."""
    rng = np.random.default_rng(0)
    places: tuple[neg.Place, ...] = ()
    for _ in range(n):
        c = np.array([100.0, 90.0]) + rng.uniform(-4.0, 4.0, 2)
        places = neg.learn(places, c, rho + rng.uniform(-0.02, 0.02), HALF, 0.05)
    return places


def test_a_place_is_learnt_where_the_search_keeps_finding_clutter() -> None:
    places = _places(12)
    assert len(places) == 1 and places[0].rho.n == 12
    assert abs(places[0].centre[0] - 100.0) < 3.0 and abs(places[0].centre[1] - 90.0) < 3.0
    # a placement more than half a box away starts a place of its own
    places = neg.learn(places, np.array([160.0, 90.0]), 0.7, HALF, 0.05)
    assert len(places) == 2 and places[1].rho.n == 1
    at = np.array([104.0, 95.0])
    # at the place: a distance like the clutter's there is likely, a target's (0.55) is not
    assert neg.log_pdf(places, at, 0.8, HALF, 5, 0.02) > neg.log_pdf(places, at, 0.55, HALF, 5, 0.02) + 10.0
    # away from every place, or at a place of too few frames: no density
    assert neg.log_pdf(places, np.array([100.0, 150.0]), 0.8, HALF, 5, 0.02) == -math.inf
    assert neg.log_pdf(places, np.array([160.0, 90.0]), 0.7, HALF, 5, 0.02) == -math.inf
    # at most MAX_PLACES: the place of fewest frames makes way, the one of many stays
    for i in range(neg.MAX_PLACES + 2):
        places = neg.learn(places, np.array([30.0 * i, 300.0]), 0.7, HALF, 0.05)
    assert len(places) == neg.MAX_PLACES and places[0].rho.n == 12
    # a snapshot's array and back, bit for bit
    assert neg.from_array(neg.to_array(places)) == places
    assert neg.from_array(neg.to_array(())) == ()
    with pytest.raises(ValueError, match="negative places"):
        neg.from_array(np.zeros((2, 4)))


def _state(p: DCFParams):
    sc = Scene(lambda t: (110.0 + 1.5 * t, 95.0), seed=3)
    st, _ = TRACKER.init(p, TRACKER.observe(p, sc.frame(0)), sc.truth(0), FrameRng(1, 7, 0), {})
    return st


def test_a_candidate_at_a_remembered_place_is_refused_and_one_elsewhere_is_not() -> None:
    p = DCFParams(search_negatives=5)
    st = _state(p)
    ds = _dists(st, None)
    rho = 0.6  # between the target's 0.55 and the window clutter's 0.8 (the priors): taken back without the memory
    st = dataclasses.replace(st, negatives=_places(12, rho))
    at = Candidate(r=1.0 - rho, centre=np.array([102.0, 92.0]), log_f=0.0, area=20000.0)
    away = dataclasses.replace(at, centre=np.array([102.0, 150.0]))
    place = 6.0  # a place the motion prior likes
    without = _judge(st, ds, at, 1.0, place, p)
    assert without >= 0.5
    assert _judge(st, ds, at, 1.0, place, p, st.negatives) < 0.5
    assert _judge(st, ds, away, 1.0, place, p, st.negatives) == _judge(st, ds, away, 1.0, place, p)
    # the target back at the place, scoring far better than the clutter did there (0.45 against 0.6): judged
    # as without the memory
    back = dataclasses.replace(at, r=0.55)
    assert _judge(st, ds, back, 1.0, place, p, st.negatives) == _judge(st, ds, back, 1.0, place, p) >= 0.5
    # too few frames at the place: no memory yet
    few = dataclasses.replace(p, search_negatives=20)
    assert _judge(st, ds, at, 1.0, place, few, st.negatives) == without


def test_the_tracker_remembers_places_while_hidden_and_forgets_them_when_seen() -> None:
    sc, frames = hidden_frames(lambda t: (110.0 + 1.5 * t, 95.0), HIDE, 42)
    p = DCFParams(search_negatives=3)
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    most, last = 0, None
    for t in range(1, len(frames)):
        st, last = step(TRACKER, p, st, TRACKER.observe(p, frames[t]), FrameRng(1, 7, t))
        if st.hidden_run == 0:
            assert st.negatives == ()
        most = max(most, sum(pl.rho.n for pl in st.negatives))
        if t == HIDE[1] - 1:
            arrays, values = to_arrays(st)
            assert "negatives" in arrays
            assert from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), p).negatives == st.negatives
    assert most >= p.hidden_after
    assert st.hidden_run == 0 and last is not None and last.target_state == "tracked"
    # off (the default): nothing remembered, no array in the snapshot
    off = DCFParams()
    assert off.search_negatives == 0
    with pytest.raises(ValueError, match="search_negatives"):
        DCFParams(search_negatives=-1)
