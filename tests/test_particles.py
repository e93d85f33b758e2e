"""Particle primitives against closed-form answers."""

import numpy as np
import pytest

from gflow_core.particles import LogWeights, ess, log_normalize, systematic_resample


def test_ess_of_equal_weights_is_n_and_of_one_particle_is_1():
    assert ess(np.zeros(100)) == pytest.approx(100.0)
    lw = np.full(100, -np.inf)
    lw[7] = 0.0
    assert ess(lw) == pytest.approx(1.0)


def test_ess_closed_form_for_two_weights():
    w = np.array([0.8, 0.2])
    assert ess(np.log(w) + 123.0) == pytest.approx(1.0 / (0.64 + 0.04))


def test_log_weights_survive_underflow():
    # exp(-2000) underflows to 0 in float64; the log-space normalisation must not
    lw = np.array([-2000.0, -2001.0, -2002.0])
    W = LogWeights(lw).W
    assert np.isclose(W.sum(), 1.0)
    assert W[0] / W[1] == pytest.approx(np.e)


def test_log_normalize_rejects_nan_and_all_zero():
    with pytest.raises(ValueError, match="NaN"):
        log_normalize(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="zero weight"):
        log_normalize(np.full(3, -np.inf))


def test_systematic_resampling_counts_are_within_one_of_n_w():
    rng = np.random.default_rng(3)
    w = rng.dirichlet(np.ones(50))
    n = 1000
    idx = systematic_resample(np.log(w), rng, n)
    counts = np.bincount(idx, minlength=50)
    # systematic resampling: each count is floor(n w_i) or ceil(n w_i)
    assert np.all(np.abs(counts - n * w) < 1.0 + 1e-9)


def test_systematic_resampling_is_deterministic_given_rng():
    lw = np.log(np.array([0.1, 0.2, 0.7]))
    a = systematic_resample(lw, np.random.default_rng([1, 2, 3]))
    b = systematic_resample(lw, np.random.default_rng([1, 2, 3]))
    assert np.array_equal(a, b)


def test_weight_histogram_counts_relative_weights():
    from gflow_core.particles import weight_histogram

    # N = 4, W = (0.7, 0.1, 0.1, 0.1): relative weights 2.8, 0.4, 0.4, 0.4
    h = weight_histogram(np.log([0.7, 0.1, 0.1, 0.1]))
    assert h["[0.1, 0.5)"] == 3 and h["[2, 5)"] == 1 and sum(h.values()) == 4
