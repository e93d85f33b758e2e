"""Learning dynamics (sec. 4.3): Markov matrix by histogramming, AR(1) by Yule-Walker."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.m2.dynamics import from_beta, sample_markov
from gflow_core.m2.learn_dynamics import learn_ar, learn_markov, split_runs, transition_counts, yule_walker


def simulate_ar(A: np.ndarray, mean: np.ndarray, B: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    x = np.empty((n, A.shape[0]))
    x[0] = mean
    w = rng.standard_normal((n, A.shape[0]))
    for t in range(1, n):
        x[t] = mean + A @ (x[t - 1] - mean) + B @ w[t]
    return x


def test_yule_walker_recovers_known_ar_coefficients() -> None:
    rng = np.random.default_rng(0)
    A = np.array([[0.8, 0.1], [-0.2, 0.5]])
    B = np.array([[0.5, 0.0], [0.2, 0.3]])
    mean = np.array([3.0, -1.0])
    x = simulate_ar(A, mean, B, 40_000, rng)
    A_hat, m_hat, Q_hat = yule_walker([x])
    assert A_hat == pytest.approx(A, abs=0.02)
    assert m_hat == pytest.approx(mean, abs=0.05)
    assert Q_hat == pytest.approx(B @ B.T, abs=0.01)


def test_yule_walker_pools_runs_without_bridging_them() -> None:
    rng = np.random.default_rng(1)
    A = np.array([[0.9]])
    runs = [simulate_ar(A, np.zeros(1), np.array([[1.0]]), 2000, rng) + 0.0 for _ in range(10)]
    A_hat, _, Q_hat = yule_walker(runs)
    assert A_hat[0, 0] == pytest.approx(0.9, abs=0.02)
    assert Q_hat[0, 0] == pytest.approx(1.0, rel=0.05)


def test_learn_ar_on_beta() -> None:
    rng = np.random.default_rng(2)
    A = np.diag([0.95, 0.9, 0.7, 0.8])
    B = np.diag([1.0, 0.5, 0.02, 0.01])
    mean = np.array([100.0, 50.0, 0.0, np.log(1.2)])
    beta = simulate_ar(A, mean, B, 30_000, rng)
    dyn = learn_ar([from_beta(beta)], translation="ar", noise_floor=np.zeros(4))
    assert np.diag(dyn.A) == pytest.approx(np.diag(A), abs=0.02)
    # off-diagonal couplings vanish once the components' scales are taken out
    sd = beta.std(axis=0)
    off = (dyn.A - np.diag(np.diag(dyn.A))) * sd[None, :] / sd[:, None]
    assert np.abs(off).max() < 0.05
    assert np.sqrt(np.diag(dyn.B @ dyn.B.T)) == pytest.approx(np.diag(B), rel=0.05)
    assert dyn.mean[2:] == pytest.approx(mean[2:], abs=0.01)
    # translation as a random walk: identity rows, noise from the increments
    rw = learn_ar([from_beta(beta)], translation="random_walk", noise_floor=np.zeros(4))
    assert rw.A[:2] == pytest.approx(np.eye(4)[:2])
    assert rw.A[2:, 2:] == pytest.approx(np.diag([0.7, 0.8]), abs=0.02)
    assert np.sqrt(np.diag(rw.B @ rw.B.T))[2:] == pytest.approx([0.02, 0.01], rel=0.05)


def test_learn_ar_floors_constant_components() -> None:
    rng = np.random.default_rng(3)
    beta = np.zeros((50, 4))
    beta[:, 0] = np.cumsum(rng.normal(0, 2.0, 50))
    dyn = learn_ar([from_beta(beta)])  # theta and log s constant: noise from the floor only
    std = np.sqrt(np.diag(dyn.B @ dyn.B.T))
    assert std[2] == pytest.approx(0.005) and std[3] == pytest.approx(0.005)
    assert np.isfinite(dyn.A).all()
    with pytest.raises(ValueError, match="transitions"):
        learn_ar([from_beta(beta[:2])])
    with pytest.raises(ValueError, match="translation"):
        learn_ar([from_beta(beta)], translation="spline")  # type: ignore[arg-type]


def test_markov_rows_sum_to_one_and_unseen_transitions_stay_possible() -> None:
    runs = [np.array([0, 0, 1, 1, 2, 0]), np.array([1, 1, 1])]
    M = learn_markov(runs, K=4, prior=0.5)
    assert M.shape == (4, 4)
    assert M.sum(axis=1) == pytest.approx(np.ones(4))
    assert (M > 0).all()
    assert M[3] == pytest.approx(np.full(4, 0.25))  # never visited: uniform
    n = transition_counts(runs, 4)
    assert n[1, 1] == 3 and n[0, 1] == 1 and n.sum() == 7  # no transition across runs (0 -> 1 at the join)
    # M_ij = (n_ij + a) / (n_i + K a)
    assert M[1, 1] == pytest.approx((3 + 0.5) / (4 + 4 * 0.5))
    # with a vanishing prior the histogram frequencies come back
    M0 = learn_markov(runs, K=4, prior=1e-9)
    assert M0[0] == pytest.approx([0.5, 0.5, 0.0, 0.0], abs=1e-6)


def test_markov_learned_from_simulation_matches_truth() -> None:
    rng = np.random.default_rng(4)
    M = np.array([[0.8, 0.2, 0.0], [0.1, 0.6, 0.3], [0.5, 0.0, 0.5]])
    k = np.zeros(20_000, dtype=np.int64)
    for t in range(1, k.size):
        k[t] = sample_markov(k[t - 1 : t], M, rng)[0]
    M_hat = learn_markov([k], K=3, prior=1.0)
    assert M_hat == pytest.approx(M, abs=0.02)
    assert (M_hat[0, 2] > 0) and (M_hat[2, 1] > 0)


def test_split_runs_breaks_at_gaps_and_sequences() -> None:
    runs = split_runs(np.array([0, 1, 2, 5, 6, 0, 1]), np.array([0, 0, 0, 0, 0, 1, 1]))
    assert [r.tolist() for r in runs] == [[0, 1, 2], [3, 4], [5, 6]]
    with pytest.raises(ValueError, match="prior"):
        learn_markov(runs, K=2, prior=0.0)
    with pytest.raises(ValueError, match="labels"):
        learn_markov([np.array([0, 3])], K=2)
