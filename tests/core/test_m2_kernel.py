"""Kernel parameters d, sigma from rho ~ sigma^2 chi^2_d (sec. 3.3.3, 4.2, eq. 10-11)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from gflow_core.m2.kernel import (MLE_D1_RATIO, PAPER_NOTE_RATIO, fit_kernels, log_kernel, mle, mle_objective,
                                  moments)


def chi2_samples(d: int, sigma: float, n: int, seed: int) -> np.ndarray:
    return sigma**2 * np.random.default_rng(seed).chisquare(d, size=n)


@pytest.mark.parametrize("d", [1, 2, 4, 10, 22])
def test_moments_recover_d_and_sigma(d: int) -> None:
    rho = chi2_samples(d, 1.7, 40_000, seed=d)
    d_hat, s_hat = moments(rho)
    assert d_hat == pytest.approx(d, rel=0.05)
    assert s_hat == pytest.approx(1.7, rel=0.03)


@pytest.mark.parametrize("d", [1, 2, 4, 10, 22])
def test_mle_recovers_integer_d_and_sigma(d: int) -> None:
    rho = chi2_samples(d, 0.6, 40_000, seed=100 + d)
    d_hat, s_hat = mle(rho)
    assert isinstance(d_hat, int)
    assert d_hat == d
    assert s_hat == pytest.approx(0.6, rel=0.02)


def test_mle_objective_is_the_profiled_gamma_log_likelihood() -> None:
    rho = chi2_samples(5, 2.0, 500, seed=7)
    ra, rg = rho.mean(), np.exp(np.log(rho).mean())
    for d in (1, 3, 5, 9):
        # sigma^2 = rho_a / d, Gamma(shape d/2, scale 2 sigma^2); L(d) = mean log-lik + log rho_g
        ll = stats.gamma.logpdf(rho, d / 2, scale=2 * ra / d).mean()
        assert mle_objective(np.array([d]), ra, rg)[0] == pytest.approx(ll + np.log(rg), rel=1e-10)


def two_point_samples(ratio: float) -> np.ndarray:
    """Samples {1, b} with rho_a / rho_g = ratio: (1 + b) / (2 sqrt(b)) = ratio."""
    r = ratio
    # with t = sqrt(b): (1 + t^2) / (2 t) = r  ->  t = r + sqrt(r^2 - 1)
    t = r + np.sqrt(r * r - 1)
    b = t * t
    rho = np.array([1.0, b] * 50)
    assert rho.mean() / np.exp(np.log(rho).mean()) == pytest.approx(ratio)
    return rho


def test_mle_gives_d1_when_arithmetic_over_geometric_mean_is_large() -> None:
    # chi^2_1 samples have rho_a / rho_g ~ 3.56, well above both thresholds
    rho = chi2_samples(1, 1.0, 20_000, seed=3)
    assert rho.mean() / np.exp(np.log(rho).mean()) > 4 / np.e
    assert mle(rho)[0] == 1
    # eq. 11 switches from d = 2 to d = 1 exactly at rho_a / rho_g = 2 pi / e
    assert mle(two_point_samples(MLE_D1_RATIO * 1.001))[0] == 1
    assert mle(two_point_samples(MLE_D1_RATIO * 0.999))[0] == 2
    # the paper's note 4.2.1(1) threshold 4/e, applied as a rule on request
    mid = two_point_samples(0.5 * (PAPER_NOTE_RATIO + MLE_D1_RATIO))
    assert mle(mid)[0] == 2
    assert mle(mid, trivial_ratio=PAPER_NOTE_RATIO)[0] == 1
    # L(1) > L(2) is equivalent to ratio > 2 pi / e
    for r in (1.9, 2.3, 2.4, 3.0):
        L = mle_objective(np.array([1.0, 2.0]), r, 1.0)
        assert (L[0] > L[1]) == (r > MLE_D1_RATIO)


def test_fit_kernels_per_cluster_and_pooled_fallback() -> None:
    rng = np.random.default_rng(11)
    rho = np.concatenate([2.0**2 * rng.chisquare(3, 20_000), 0.5**2 * rng.chisquare(12, 20_000), [1.0, 2.0]])
    labels = np.concatenate([np.zeros(20_000, int), np.ones(20_000, int), [2, 2]])
    for method in ("moments", "mle"):
        fit = fit_kernels(rho, labels, K=4, method=method, min_samples=4)
        assert fit.d[0] == pytest.approx(3, rel=0.05) and fit.sigma[0] == pytest.approx(2.0, rel=0.03)
        assert fit.d[1] == pytest.approx(12, rel=0.05) and fit.sigma[1] == pytest.approx(0.5, rel=0.03)
        assert fit.pooled.tolist() == [False, False, True, True]  # 2 samples, 0 samples
        assert fit.d[2] == fit.d[3] and fit.sigma[2] == fit.sigma[3]
        assert fit.n.tolist() == [20_000, 20_000, 2, 0]


def test_fit_kernels_clips_d_and_rejects_bad_input() -> None:
    fit = fit_kernels(np.array([1.0, 1.0, 1.0, 1.0, 2.0]), np.array([0, 0, 0, 0, 1]), K=2, min_samples=4)
    assert fit.d[0] == 1000.0  # zero variance -> d clipped to the top of d_range
    assert fit.sigma[0] == pytest.approx(np.sqrt(1.0 / 1000.0))
    with pytest.raises(ValueError, match="unknown kernel"):
        fit_kernels(np.ones(5), np.zeros(5, int), K=1, method="em")
    with pytest.raises(ValueError, match="at least 2"):
        fit_kernels(np.array([1.0]), np.array([0]), K=1)
    with pytest.raises(ValueError, match="labels"):
        fit_kernels(np.ones(5), np.full(5, 3), K=2)
    with pytest.raises(ValueError, match="non-negative"):
        moments(np.array([1.0, -1.0]))
    with pytest.raises(ValueError, match="positive"):
        mle(np.array([0.0, 0.0, 1.0]))


def test_log_kernel_is_eq7() -> None:
    rho = np.array([0.0, 1.0, 4.0])
    out = log_kernel(rho, np.array([1.0, 2.0, 0.5]), np.array([3.0, 3.0, 3.0]))
    assert out == pytest.approx([0.0, -1.0 / 8.0 - 3 * np.log(2.0), -8.0 - 3 * np.log(0.5)])
