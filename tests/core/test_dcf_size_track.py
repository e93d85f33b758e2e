"""A placement at another size than the held one taken only as a candidate track (``search_size_track``): the
search over sizes offers it, one frame's P(visible) does not take it, the candidate track does once it has held
over its frames; a placement at the held size is judged as without the option, and off the option changes
nothing."""

from __future__ import annotations

import dataclasses

import numpy as np

from gflow_core.dcf import model as tm
from gflow_core.dcf import tracker as tr
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.tracker import TRACKER
from gflow_core.params import as_recorded
from dcf_scene import frame, hidden

def _hidden(p: DCFParams) -> tr.DCFState:
    """Hidden for 40 frames: its log size's std 0.2 at the default growth, so five sizes are searched."""
    return hidden(p, run=40)


def _offer(monkeypatch, log_f: float) -> None:
    """The search's filter offers one placement at (140, 100), log-size change ``log_f``, scoring as the target
    usually does."""
    def offered(model, image, grey, hold, margin, log_s, geom, p, sizes=(0.0,)):
        return [tm.Candidate(0.5, np.array([140.0, 100.0]), log_f, 8000.0 * len(sizes))]
    monkeypatch.setattr(tr.tm, "search", offered)


def _unseen(st: tr.DCFState, p: DCFParams) -> tuple[tr.Search, object]:
    """One unseen frame's search and its candidate track."""
    srch, _, track = tr._unseen(st, TRACKER.observe(p, frame(False)), p, np.array([130.0, 100.0]), (10.0, 10.0),
                                None, None, st.hidden_run, 1.0, 1.0)
    return srch, track


def test_another_size_is_taken_at_once_without_the_option(monkeypatch) -> None:
    p = DCFParams(colour_weight=0.0, search_sizes=5)
    _offer(monkeypatch, 0.2)
    srch, _ = _unseen(_hidden(p), p)
    assert srch.found is not None and srch.found.log_f == 0.2


def test_another_size_is_taken_only_once_its_track_holds(monkeypatch) -> None:
    """With the option the first frame takes nothing and starts a candidate track on the placement; the same
    placement on the next frame is taken, at its size, with the track's probability."""
    p = DCFParams(colour_weight=0.0, search_sizes=5, search_size_track=True)
    _offer(monkeypatch, 0.2)
    st = _hidden(p)
    srch, track = _unseen(st, p)
    assert srch.found is None and srch.top is not None and srch.top[0].log_f == 0.2
    assert track is not None and track.n == 1
    srch, track = _unseen(dataclasses.replace(st, track=track, hidden_run=st.hidden_run + 1), p)
    assert srch.found is not None and srch.found.log_f == 0.2 and srch.confidence >= p.search_track


def test_the_held_size_is_judged_as_without_the_option(monkeypatch) -> None:
    off = DCFParams(colour_weight=0.0, search_sizes=5)
    on = dataclasses.replace(off, search_size_track=True)
    _offer(monkeypatch, 0.0)
    a, _ = _unseen(_hidden(off), off)
    b, _ = _unseen(_hidden(on), on)
    assert a.found is not None and b.found is not None
    assert a.confidence == b.confidence and a.found.log_f == b.found.log_f == 0.0


def test_it_is_off_for_recordings_made_before_it() -> None:
    assert DCFParams().search_size_track is False
    assert as_recorded(DCFParams, {}).get("search_size_track", False) is False
