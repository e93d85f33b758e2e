"""dcf's filter rate while the target's look changes (``rate_adapt``; gflow_core.dcf.rates)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.rates import adapted, recent
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER
from gflow_core.evaluation.metrics import centre_error
from gflow_core.tracker import FrameRng, step
from gflow_core.visibility import ChiSquare
from tests.core.test_dcf_tracker import Scene, _texture, _track


class Morph(Scene):
    """The scene's target, its texture turning into another between frames ``t0`` and ``t1``."""

    def __init__(self, path, t0: int, t1: int, seed: int = 0) -> None:
        super().__init__(path, seed)
        self.a, self.b = self.target.copy(), _texture(np.random.default_rng(seed + 100), 36, 30, 5.0)
        self.t0, self.t1 = t0, t1

    def frame(self, t: int) -> np.ndarray:
        f = min(max((t - self.t0) / (self.t1 - self.t0), 0.0), 1.0)
        self.target = (1.0 - f) * self.a + f * self.b
        return super().frame(t)


def _dist(mean: float) -> ChiSquare:
    return ChiSquare(mean, mean * mean + 0.01, 20)


def test_the_rate_rises_only_while_the_distance_runs_above_its_mean() -> None:
    """eta_t = max(eta, 1 - (1 - eta) rho_bar / S_t): eta at or below the mean, about 0.41 for a short-run
    mean of 0.86 against 0.52; the short-run mean starts from the target's mean; off, eta whatever S."""
    p = DCFParams(rate_adapt=0.5)
    t = _dist(0.52)
    assert adapted(p, 0.02, t, 0.52) == 0.02 and adapted(p, 0.02, t, 0.40) == 0.02
    assert adapted(p, 0.02, t, 0.86) == pytest.approx(1.0 - 0.98 * 0.52 / 0.86)
    assert adapted(DCFParams(), 0.02, t, 0.86) == 0.02
    # S_t = (1 - a) S_{t-1} + a rho_t, S_0 the target's mean
    assert recent(p, 0.0, t, 0.8) == pytest.approx(0.66)
    assert recent(p, 0.6, t, 0.8) == pytest.approx(0.7)


def test_a_target_whose_look_changes_fast_is_kept_with_the_adaptive_rate_and_judged_hidden_without() -> None:
    """The target's texture turns into another in six frames: at the fixed rate the filter's score on it
    falls and it is judged occluded with the box on it; with ``rate_adapt`` the filter learns the new look
    as it comes and every frame is tracked on the target."""
    sc = Morph(lambda t: (100.0 + 2.0 * t, 100.0), 30, 36)
    frames = [sc.frame(t) for t in range(44)]
    truth = np.array([sc.truth(t) for t in range(44)])
    _, fixed = _track(frames, sc.truth(0))
    assert any(e.target_state == "occluded" for e in fixed[30:])
    st, ests = _track(frames, sc.truth(0), DCFParams(rate_adapt=0.5))
    assert all(e.target_state == "tracked" for e in ests)
    assert centre_error(truth, np.array([e.box for e in ests])).max() < 4.0
    assert st.recent > 0.0


def test_with_the_adaptive_rate_the_state_goes_into_arrays_and_comes_back_bit_for_bit() -> None:
    sc = Morph(lambda t: (100.0 + 2.0 * t, 100.0), 8, 14)
    frames = [sc.frame(t) for t in range(16)]
    p = DCFParams(rate_adapt=0.5)
    st, _ = _track(frames[:10], sc.truth(0), p)
    arrays, values = to_arrays(st)
    back = from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), p)
    assert back.recent == st.recent > 0.0
    for t in range(10, 16):
        obs = TRACKER.observe(p, frames[t])
        st, e1 = step(TRACKER, p, st, obs, FrameRng(1, 7, t))
        back, e2 = step(TRACKER, p, back, obs, FrameRng(1, 7, t))
        assert e1 == e2


@pytest.mark.parametrize("v", [-0.1, 1.5, float("nan")])
def test_bad_values_are_refused(v) -> None:
    with pytest.raises(ValueError, match="rate_adapt must be in \\[0, 1\\]"):
        DCFParams(rate_adapt=v)
