"""G-flow's lost guard: a candidate away from the experts re-seats them on a likelihood ratio of the
two places, the target against clutter (gflow_core/gflow/guard.py)."""

from __future__ import annotations

import numpy as np

from gflow_core.gflow import guard
from gflow_core.m2.lost import LostParams, LostState, Observation
from gflow_core.redetect import Candidate
from gflow_core.visibility import ChiSquare

P = LostParams()


def _learnt(values: list[float], rate: float) -> ChiSquare:
    m = ChiSquare()
    for _ in range(10):
        for v in values:
            m = m.update(v, rate)
    return m


# the edges: the target's distance about 0.30, the clutter's best about 0.60
EDGES = LostState(target=_learnt([0.25, 0.30, 0.35], P.rate), clutter=_learnt([0.55, 0.60, 0.65], P.clutter_rate),
                  found=30, lost_run=1)
# the first look's misfit: about 0.50 at the target on found frames, about 0.80 at the best beside it
LEVEL = _learnt([0.45, 0.50, 0.55], P.rate)
LOOK_CLUTTER = _learnt([0.77, 0.80, 0.83], P.clutter_rate)
RING = 400.0


def _wins(est_misfit: float, cand_misfit: float, level: ChiSquare = LEVEL) -> bool:
    # the edges alone: the estimate looks like clutter (0.62), the candidate like the target (0.30)
    seen = Observation(r=1.0 - 0.62, clutter=(0.4, RING))
    cand = Candidate(r=1.0 - 0.30, centre=np.array([100.0, 80.0]), log_f=0.0, area=RING)
    return guard._away_wins(seen, cand, EDGES, EDGES, RING, P, (est_misfit, cand_misfit), level, LOOK_CLUTTER)


def test_a_look_alike_of_the_first_look_does_not_take_the_experts_from_the_target_as_it_looks_now() -> None:
    # dollar: the second stack of bills fits the first look far better (0.20) than the opened one the
    # experts follow, which fits it as the target has lately (0.50): the experts stay
    assert not _wins(0.50, 0.20)
    # the estimate fits the first look as clutter does (0.82), the candidate as the target: re-seated
    assert _wins(0.82, 0.50)


def test_without_a_first_look_that_tells_target_from_clutter_the_edges_decide() -> None:
    # too few found frames to have learnt the first look's misfit at the target: the edges alone
    assert _wins(0.50, 0.20, level=ChiSquare().update(0.5, P.rate))
    # a first look that fits clutter as well as the target tells nothing either
    assert _wins(0.50, 0.20, level=_learnt([0.85, 0.90, 0.95], P.rate))


def test_first_look_clutter_is_the_best_fit_in_the_ring_around_the_box() -> None:
    """first_look_clutter's fits are first_look_fit's at the pose moved by each offset of the ring."""
    from gflow_core.gflow.guard import _correlations

    rng = np.random.default_rng(3)
    frame = rng.random((60, 80))
    mu = rng.random(12)
    pts = np.stack([rng.uniform(20, 40, 12), rng.uniform(20, 40, 12)], axis=1)
    shifts = np.array([[0.0, 0.0], [5.0, -3.0], [70.0, 0.0]])
    many = _correlations(mu, frame.reshape(-1), frame.shape, pts[None] + shifts[:, None, :])
    one = [float(_correlations(mu, frame.reshape(-1), frame.shape, (pts + s)[None])[0]) for s in shifts]
    assert np.allclose(many, one)
    # out of the frame: no fit (fewer than 3 points inside)
    assert many[2] == 0.0 and -1.0 <= many[0] <= 1.0
    # the correlation with itself: the frame's own values at the points fit perfectly
    own = np.array([frame[int(y), int(x)] for x, y in np.rint(pts)])
    exact = _correlations(own, frame.reshape(-1), frame.shape, np.rint(pts)[None])
    assert exact[0] > 0.999
