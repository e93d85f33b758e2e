"""Learning dynamics (sec. 4.3): Markov matrix by histogramming, AR(1) by Yule-Walker."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.m2.dynamics import from_beta, random_walk, sample_markov
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


def test_at_resolution_scales_the_angle_and_scale_noise_of_a_larger_target_only() -> None:
    from gflow_core.m2.dynamics import ARDynamics, at_resolution

    A = np.diag([1.0, 1.0, 0.5, 0.7])
    B = np.array([[2.0, 0, 0, 0], [0.3, 2.5, 0, 0], [0.01, 0.0, 0.15, 0], [0.0, 0.02, 0.01, 0.16]])
    dyn = ARDynamics(A=A, mean=np.array([100.0, 50.0, 0.0, 0.1]), B=B)
    half = at_resolution(dyn, 2.0)
    # rows of theta and log s over 2; translation noise, A and the mean unchanged
    assert np.allclose(half.B[2:], B[2:] / 2) and np.array_equal(half.B[:2], B[:2])
    assert np.array_equal(half.A, A) and np.array_equal(half.mean, dyn.mean)
    # a target within the training sizes keeps the learned process, bit for bit
    assert at_resolution(dyn, 1.0) is dyn and at_resolution(dyn, 0.5) is dyn
    # sampled: the spread of log s halves, that of the centre does not
    rng = np.random.default_rng(0)
    alpha = np.tile([100.0, 50.0, 0.0, 1.1], (20000, 1))
    a, b = dyn.predict(alpha, rng), half.predict(alpha, np.random.default_rng(0))
    assert np.std(np.log(b[:, 3])) == pytest.approx(np.std(np.log(a[:, 3])) / 2, rel=1e-6)
    assert np.array_equal(a[:, :2], b[:, :2])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="scale ratio"):
            at_resolution(dyn, bad)


def test_proposal_dynamics_carries_the_noise_to_the_target_size() -> None:
    """A model learned on targets up to 1.25 of its reference box, placed on a box 2.5 times it: the
    angle and scale noise is halved; on a box within the training sizes the learned process is used."""
    from dataclasses import replace

    from gflow_core.contour.dynamics import proposal_dynamics
    from gflow_core.m2.curves import Curves
    from gflow_core.m2.model import M2Model

    rng = np.random.default_rng(0)
    m = M2Model(metric="chamfer", kernel="moments", exemplars=Curves.from_list([rng.normal(0, 5, (20, 2))]),
                d=np.array([4.0]), sigma=np.array([1.0]), pi=np.array([1.0]), markov=np.ones((1, 1)),
                dynamics=random_walk(2.0, 0.1, 0.1), ref_size=np.array([20.0, 40.0]), train_scale=1.25)
    _, big, _ = proposal_dynamics(m, (0.0, 0.0, 50.0, 100.0), None)  # s0 = 2.5, r = 2
    _, same, _ = proposal_dynamics(m, (0.0, 0.0, 20.0, 40.0), None)  # s0 = 1
    assert np.allclose(np.diag(big.B), [2.0, 2.0, 0.05, 0.05]) and np.allclose(np.diag(same.B), [2.0, 2.0, 0.1, 0.1])
    _, old, _ = proposal_dynamics(replace(m, train_scale=float("inf")), (0.0, 0.0, 50.0, 100.0), None)
    assert np.allclose(np.diag(old.B), [2.0, 2.0, 0.1, 0.1])  # a file without train_scale: as learned
