"""Credibility (eq. 17, 19), resampling (sec. 3.4) and posterior summaries."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import gflow_core.particles as particles
from gflow_core.gflow import credibility as cr
from gflow_core.gflow.geometry import make_pose, rotation_matrices


def test_log_evidence_is_the_log_mean_importance_weight() -> None:
    rng = np.random.default_rng(0)
    lw = rng.normal(-500.0, 20.0, (5, 7))  # far below exp underflow
    ev = cr.log_evidence(lw)
    # p(y_t | u_{1:t-1}, y_{1:t-1}) ~ sum_e w(d, e) / s    (eq. 19)
    m = lw.max(axis=1, keepdims=True)
    np.testing.assert_allclose(ev, m[:, 0] + np.log(np.mean(np.exp(lw - m), axis=1)), rtol=1e-12)
    assert np.isfinite(ev).all()


def test_credibility_is_normalised_and_shift_invariant() -> None:
    rng = np.random.default_rng(1)
    prior = np.log(rng.dirichlet(np.ones(6)))
    lik = rng.normal(-1e4, 30.0, 6)
    lc = cr.log_credibility(prior, lik)
    assert np.exp(lc).sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(lc, cr.log_credibility(prior, lik + 1234.5), atol=1e-9)
    # eq. 17: proportional to prior x likelihood
    np.testing.assert_allclose(lc - lc[0], (prior + lik) - (prior[0] + lik[0]), atol=1e-9)
    with pytest.raises(ValueError):
        cr.log_credibility(prior, np.full(6, np.nan))


def test_shared_particle_helpers_are_used() -> None:
    assert cr.ess is particles.ess
    assert cr.systematic_resample is particles.systematic_resample


def test_resampling_draws_parents_by_credibility_and_children_from_parent_samples() -> None:
    rng = np.random.default_rng(2)
    W = np.array([0.5, 0.3, 0.2, 0.0])
    lw = np.log(np.array([[0.9, 0.1, 0.0], [0.0, 0.0, 1.0], [0.5, 0.5, 0.0], [1.0, 0.0, 0.0]]) + 1e-300)
    counts = np.zeros((4, 3))
    for _ in range(4000):
        parents, picks = cr.resample_experts(np.log(W + 1e-300), lw, rng)
        assert parents.shape == picks.shape == (4,)
        np.add.at(counts, (parents, picks), 1)
    freq = counts / counts.sum()
    expected = W[:, None] * np.exp(lw)
    np.testing.assert_allclose(freq, expected, atol=0.01)
    assert counts[3].sum() == 0 and counts[0, 2] == 0 and counts[1, :2].sum() == 0


def test_posterior_mean_pose_and_spread() -> None:
    R1 = Rotation.from_rotvec([0.0, 0.2, 0.0])
    R2 = Rotation.from_rotvec([0.0, -0.2, 0.0])
    poses = np.stack([make_pose(R1.as_rotvec(), [10.0, 0.0], [2.0]), make_pose(R2.as_rotvec(), [20.0, 4.0], [4.0])])
    mean = cr.posterior_mean_pose(poses, np.log([0.5, 0.5]))
    np.testing.assert_allclose(rotation_matrices(mean), np.eye(3), atol=1e-12)  # chordal mean
    np.testing.assert_allclose(mean[3:], [15.0, 2.0, 3.0])
    spread = cr.pose_spread(poses, np.log([0.5, 0.5]), mean)
    np.testing.assert_allclose(spread, [0.0, 0.2, 0.0, 5.0, 2.0, 1.0], atol=1e-12)
    # weights are respected and identical poses give themselves
    lopsided = cr.posterior_mean_pose(poses, np.array([0.0, -np.inf]))
    np.testing.assert_allclose(lopsided, poses[0], atol=1e-12)
