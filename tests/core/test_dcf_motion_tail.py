"""A motion prior with heavy tails (``motion_tail``; gflow_core.dcf.heavytail): off, the prior is the
Gaussian bit for bit; on, it is the bivariate Student-t, a density (its mass within radius R the closed
form's), the Gaussian in the limit of many degrees of freedom, and far from the prediction much cheaper
than the Gaussian; a negative or infinite nu is refused. The mixture of the two is a density too, and its
weight, learnt by online EM from the innovations, falls to its floor on innovations the Gaussian explains
and rises on jolts; in the tracker it is learnt on a target that moves smoothly and one that jolts, each
the way its motion says, and goes into a snapshot and back."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from gflow_core.dcf import heavytail
from gflow_core.dcf.params import DCFParams
from tests.core.test_dcf_tracker import Scene, _resumed, _track


def test_off_the_prior_is_the_gaussian_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    dx, dy = rng.normal(0, 20, 50), rng.normal(0, 30, 50)
    sx, sy = 11.3, 17.9
    want = -(dx ** 2 / (2.0 * sx * sx) + dy ** 2 / (2.0 * sy * sy))
    assert np.array_equal(heavytail.log_kernel(dx, dy, sx, sy, 0.0), want)


@pytest.mark.parametrize("nu", [1.0, 3.0])
def test_the_t_is_a_density_whose_mass_within_r_is_the_closed_forms(nu: float) -> None:
    sx, sy = 4.0, 6.0
    R = 5.0  # in units of the scale: the ellipse (dx / sx)^2 + (dy / sy)^2 <= R^2

    def ring(r: float) -> float:
        # the density on the ellipse of radius r, times its circumference element 2 pi r sx sy
        return math.exp(heavytail.log_density(r * sx, 0.0, sx, sy, nu)) * 2.0 * math.pi * r * sx * sy

    mass, _ = integrate.quad(ring, 0.0, R)
    # P(d <= R) = 1 - (1 + R^2 / nu)^(-nu / 2) for the bivariate t
    assert abs(mass - (1.0 - (1.0 + R * R / nu) ** (-nu / 2.0))) < 1e-8


def test_many_degrees_of_freedom_give_the_gaussian_and_few_a_cheap_far_tail() -> None:
    d = np.array([0.0, 1.0, 2.0, 3.0])
    gauss = heavytail.log_kernel(d, 0 * d, 1.0, 1.0, 0.0)
    assert np.allclose(heavytail.log_kernel(d, 0 * d, 1.0, 1.0, 1e7), gauss, atol=1e-5)
    # 5 standard deviations away: exp(-12.5) under the Gaussian, (1 + 25)^(-1.5) = exp(-4.9) under nu = 1
    far = heavytail.log_kernel(np.array([5.0]), np.array([0.0]), 1.0, 1.0, 1.0)[0]
    assert abs(far + 1.5 * math.log(26.0)) < 1e-12 and far > -12.5 + 7.0


def test_a_tail_with_a_second_motion_mode_is_refused_not_ignored() -> None:
    for other in ({"motion_switch": 0.1}, {"flow_mix": 0.1}):
        with pytest.raises(ValueError, match="motion_tail shapes the one-mode prior"):
            DCFParams(motion_tail=1.0, **other)


@pytest.mark.parametrize("bad", [-1.0, float("inf"), float("nan")])
def test_a_negative_or_infinite_nu_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="motion_tail"):
        DCFParams(motion_tail=bad)



@pytest.mark.parametrize("pi", [0.05, 0.5])
def test_the_mixture_is_a_density_and_its_ends_are_its_parts(pi: float) -> None:
    nu, R = 1.0, 4.0

    def ring(r: float) -> float:
        return math.exp(heavytail.log_density(r * 3.0, 0.0, 3.0, 5.0, nu, pi)) * 2.0 * math.pi * r * 3.0 * 5.0

    mass, _ = integrate.quad(ring, 0.0, R)
    # (1 - pi) P_N(d <= R) + pi P_t(d <= R), P_N(d <= R) = 1 - exp(-R^2 / 2)
    want = (1.0 - pi) * (1.0 - math.exp(-R * R / 2.0)) + pi * (1.0 - (1.0 + R * R / nu) ** (-nu / 2.0))
    assert abs(mass - want) < 1e-8
    d = np.linspace(-20.0, 20.0, 41)
    assert np.array_equal(heavytail.log_kernel(d, d, 3.0, 5.0, nu, 0.0), heavytail.log_kernel(d, d, 3.0, 5.0, 0.0))
    assert np.array_equal(heavytail.log_kernel(d, d, 3.0, 5.0, nu, 1.0), heavytail.log_kernel(d, d, 3.0, 5.0, nu))


def test_the_weight_falls_on_what_the_gaussian_explains_and_rises_on_jolts() -> None:
    rng = np.random.default_rng(2)
    calm = jolts = 0.3
    for _ in range(300):
        calm = heavytail.learn(calm, rng.normal(0.0, [4.0, 6.0]), 4.0, 6.0, 1.0, 0.05)
        # a jump of 5 to 8 deviations, one way or the other
        jolts = heavytail.learn(jolts, rng.choice([-1.0, 1.0], 2) * rng.uniform(5.0, 8.0, 2) * [4.0, 6.0],
                                4.0, 6.0, 1.0, 0.05)
    assert calm < 0.05 and jolts > 0.95, (calm, jolts)
    assert heavytail.TAIL_MIN <= calm and jolts <= 1.0 - heavytail.TAIL_MIN


def _learning() -> DCFParams:
    return DCFParams(motion_tail=1.0, motion_tail_weight=0.05, motion_tail_rate=0.1)


def test_the_tracker_learns_the_weight_each_motion_asks_for_and_keeps_it_in_a_snapshot() -> None:
    smooth = Scene(lambda t: (80.0 + 3.0 * t, 100.0 + 1.0 * t), seed=3)
    # right and back by 24 px every frame, drifting 1 px down a frame
    jolting = Scene(lambda t: (110.0 + 24.0 * (t % 2), 100.0 + 1.0 * t), seed=3)
    st_smooth, _ = _track([smooth.frame(t) for t in range(30)], smooth.truth(0), _learning())
    frames = [jolting.frame(t) for t in range(30)]
    st_jolt, _ = _track(frames, jolting.truth(0), _learning())
    st_off, _ = _track(frames, jolting.truth(0), DCFParams(motion_tail=1.0))
    assert st_off.tail == 0.0  # held (no rate): nothing learnt
    # from 0.05: down on the smooth motion, up (to 0.18) on the jolts
    assert st_smooth.tail < 0.05 and st_jolt.tail > 0.1, (st_smooth.tail, st_jolt.tail)
    st, _ = _track(frames[:16], jolting.truth(0), _learning())
    assert _resumed(st, frames, 16, _learning()).tail == st.tail > 0.0
