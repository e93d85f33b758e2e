"""Extensions of the M2 particle filter: blocked weighing gives the same likelihoods."""

from __future__ import annotations

import numpy as np

from gflow_core.m2 import tracking
from gflow_core.m2.dynamics import random_walk


def test_weigh_in_blocks_equals_weigh_at_once() -> None:
    rng = np.random.default_rng(0)
    K, P, N = 5, 40, 1000
    ex = tracking.ContourExemplars(curves=rng.normal(0, 15, (K, P, 2)), n_points=rng.integers(10, P + 1, K),
                                   sigma=rng.uniform(0.5, 2, K), d=rng.uniform(2, 12, K), pi=np.full(K, 1 / K),
                                   markov=np.full((K, K), 1 / K), dynamics=random_walk(2, 0.01, 0.01))
    gam = rng.uniform(0, 100, (120, 160)).astype(np.float32)
    cloud = tracking.init_particles(np.array([80.0, 60.0, 0.0, 1.0]), 0, N, np.array([30.0, 30.0, 0.2, 0.2]), rng)
    cloud = tracking.ParticleCloud(cloud.alpha, rng.integers(0, K, N), cloud.log_w)
    ll0, rho0 = tracking.weigh(cloud, ex, gam, chunk=0)
    for chunk in (1, 7, 256, 5000):
        ll, rho = tracking.weigh(cloud, ex, gam, chunk=chunk)
        assert np.array_equal(rho, rho0) and np.array_equal(ll, ll0)
    # some particles fall partly off the image and get the default outside value
    assert (rho0 > 0).all() and np.isfinite(ll0).all()
