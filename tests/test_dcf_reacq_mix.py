"""dcf's ``search_clutter_mix``: under "hidden" a search candidate's distance has the density of an even
mixture of the window clutter's (the best of as many draws as the search covered) and the search's own
clutter's (its best placements on the frames the target stayed hidden), where the default takes the
lower of the two. A placement as good as the ones the search kept giving while the target was hidden
(a look-alike it keeps finding) is then likely under "hidden"; one far better than both is not."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.reacquire import log_mix
from gflow_core.dcf.tracker import TRACKER, _hidden_log_pdf
from gflow_core.tracker import FrameRng
from gflow_core.visibility import ChiSquare
from tests.test_dcf_search_clutter import hidden_frames


def test_log_mix_is_the_log_of_the_mean_density() -> None:
    for a, b in ((-3.0, -3.0), (0.5, -20.0), (-700.0, -2.0), (4.0, 1.0)):
        m = log_mix(a, b)
        assert math.isclose(m, math.log((math.exp(a) + math.exp(b)) / 2.0), rel_tol=1e-12, abs_tol=1e-12)
        assert min(a, b) <= m <= max(a, b)
    assert log_mix(-1e6, 0.0) == -math.log(2.0)  # one density nil: half the other's


def _state_with_search_clutter(p: DCFParams):
    sc, frames = hidden_frames(lambda t: (110.0 + 1.5 * t, 95.0), (10, 30), 2)
    st, _ = TRACKER.init(p, TRACKER.observe(p, frames[0]), sc.truth(0), FrameRng(1, 7, 0), {})
    learnt = ChiSquare()
    # a look-alike the search kept finding while the target was hidden, at distance 0.68-0.71
    for rho in (0.70, 0.69, 0.71, 0.70, 0.68, 0.70, 0.69, 0.71, 0.70, 0.69, 0.70, 0.71):
        learnt = learnt.update(rho, p.clutter_rate)
    assert learnt.n >= p.search_min
    # the window's clutter learnt on the frames the target was tracked: its best half a box away at 0.83-0.89
    clutter = ChiSquare()
    for rho in (0.86, 0.84, 0.88, 0.85, 0.87, 0.83, 0.89, 0.86, 0.85, 0.87) * 3:
        clutter = clutter.update(rho, p.clutter_rate)
    return dataclasses.replace(st, sclutter=learnt, clutter=clutter)


def test_the_mixture_lies_between_the_two_clutters_and_keeps_a_far_better_placement_unlikely() -> None:
    p = DCFParams()
    mix = dataclasses.replace(p, search_clutter_mix=True)
    assert not p.search_clutter_mix  # off by default
    st = _state_with_search_clutter(p)
    window_only = dataclasses.replace(p, search_clutter=False)
    raised = 0
    for rho in np.linspace(0.3, 1.0, 36):
        r = float(rho)
        low, w = _hidden_log_pdf(st, r, 2.5, p), _hidden_log_pdf(st, r, 2.5, window_only)
        m = _hidden_log_pdf(st, r, 2.5, mix)
        ls = st.sclutter.log_pdf(min(r, st.sclutter.mode(p.min_std)), p.min_std)
        assert low <= m + 1e-12 and m <= max(w, ls) + 1e-12
        raised += m > low + 1.0
    # the look-alike's own distance: far likelier under "hidden" with the mixture than by the lower density
    assert _hidden_log_pdf(st, 0.69, 2.5, mix) > _hidden_log_pdf(st, 0.69, 2.5, p) + 5.0
    # a placement far better than every one the search gave stays unlikely under "hidden" either way
    assert _hidden_log_pdf(st, 0.35, 2.5, mix) < _hidden_log_pdf(st, 0.69, 2.5, mix) - 5.0
    assert raised > 0
    # fewer than search_min searches: the window's clutter alone, mixed or not
    few = dataclasses.replace(st, sclutter=ChiSquare().update(0.7, p.clutter_rate))
    assert _hidden_log_pdf(few, 0.69, 2.5, mix) == _hidden_log_pdf(few, 0.69, 2.5, window_only)
