"""The search over sizes judges a candidate's place and size against clutter uniform over the volume searched
(``search_size_volume``): the area the candidate carries already sums the sizes searched, so the size's term
adds the size step alone, not the number of sizes again. Off (as recordings made before it), a candidate of
the wider search is favoured by that number's odds; with one size the option changes nothing."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf import tracker as tr
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.tracker import TRACKER
from dcf_scene import frame, hidden

_frame, _hidden = frame, hidden


def _offer(monkeypatch, rho: float, log_f: float) -> None:
    """The search's filter offers one placement, at (150, 100) and log-size change ``log_f``, at distance
    ``rho``; the area it carries is that of the sizes searched together (as :func:`.model.search`'s)."""
    def offered(model, image, grey, hold, margin, log_s, geom, p, sizes=(0.0,)):
        return [tm.Candidate(1.0 - rho, np.array([150.0, 100.0]), log_f, 8000.0 * len(sizes))]
    monkeypatch.setattr(tr.tm, "search", offered)


def _odds(p: DCFParams, rho: float, size_sd: float) -> float:
    """The odds P(visible) / P(hidden) the search gives the offered placement (it must be taken)."""
    st = _hidden(p)
    srch = tr._search(st, TRACKER.observe(p, _frame(False)), p, np.array([130.0, 100.0]), (10.0, 10.0), 25.0,
                      None, None, size_sd)
    assert srch.found is not None
    return srch.confidence / (1.0 - srch.confidence)


@pytest.mark.parametrize("size_sd, n_sizes", [(0.1, 3), (0.2, 5)])
def test_the_volume_counts_the_sizes_once(monkeypatch, size_sd: float, n_sizes: int) -> None:
    """Over three sizes (size_sd 0.1) and five (0.2) the old term favours the candidate by exactly the number of
    sizes in odds; the volume's does not."""
    off = DCFParams(colour_weight=0.0, search_sizes=5)
    on = dataclasses.replace(off, search_size_volume=True)
    _offer(monkeypatch, 0.72, 0.2)
    ratio = _odds(off, 0.72, size_sd) / _odds(on, 0.72, size_sd)
    assert ratio == pytest.approx(n_sizes, rel=1e-9)


def test_a_placement_the_old_term_takes_may_be_refused(monkeypatch) -> None:
    """A placement whose odds are above evens only by the sizes' number counted twice is taken with the option
    off and refused with it on."""
    off = DCFParams(colour_weight=0.0, search_sizes=5)
    on = dataclasses.replace(off, search_size_volume=True)
    # find a distance at which the option-off odds are between 1 and 5
    rho = next(r for r in np.arange(0.70, 0.80, 0.002) if _between(monkeypatch, off, float(r)))
    _offer(monkeypatch, rho, 0.2)
    st = _hidden(on)
    srch = tr._search(st, TRACKER.observe(on, _frame(False)), on, np.array([130.0, 100.0]), (10.0, 10.0), 25.0,
                      None, None, 0.2)
    assert srch.found is None


def _between(monkeypatch, p: DCFParams, rho: float) -> bool:
    _offer(monkeypatch, rho, 0.2)
    st = _hidden(p)
    srch = tr._search(st, TRACKER.observe(p, _frame(False)), p, np.array([130.0, 100.0]), (10.0, 10.0), 25.0,
                      None, None, 0.2)
    if srch.found is None:
        return False
    odds = srch.confidence / (1.0 - srch.confidence)
    return 1.2 < odds < 4.0


def test_one_size_is_judged_as_without_the_option(monkeypatch) -> None:
    """With search_sizes=1 (the default) no size is searched and the option changes no bit."""
    off = DCFParams(colour_weight=0.0)
    on = dataclasses.replace(off, search_size_volume=True)
    _offer(monkeypatch, 0.72, 0.0)
    assert _odds(off, 0.72, 0.2) == _odds(on, 0.72, 0.2)


def test_it_is_off_for_recordings_made_before_it() -> None:
    from gflow_core.params import as_recorded

    assert DCFParams().search_size_volume is False
    assert as_recorded(DCFParams, {}).get("search_size_volume", False) is False
    assert math.isfinite(DCFParams(search_size_volume=True).search_size_step)
