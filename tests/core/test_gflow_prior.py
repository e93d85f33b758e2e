"""The pose transition prior p(u_t | u_{t-1}): a random walk, optionally with the rotation of its
mean decaying toward the identity (pose_opinion.prior_mean)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.gflow import paper_config, make_pose
from gflow_core.gflow.geometry import TRANS, COEF, rotation_angle_deg
from gflow_core.gflow.pose_opinion import log_pose_prior, prior_mean


def test_without_decay_the_mean_is_the_previous_pose_itself() -> None:
    prev = np.stack([make_pose([0.1, -0.2, 0.3], [10.0, 20.0], [50.0]), make_pose(None, [1.0, 2.0], [3.0])])
    assert prior_mean(prev, 1.0) is prev


def test_decay_shrinks_the_rotation_angle_and_keeps_the_rest() -> None:
    rng = np.random.default_rng(0)
    prev = np.stack([make_pose(rng.normal(0, 0.5, 3), rng.normal(0, 50, 2), [rng.uniform(10, 90)]) for _ in range(6)])
    ident = prev.copy()
    ident[:, :3] = 0.0
    m = prior_mean(prev, 0.9)
    # angle(identity, r_m) = a * angle(identity, r_{t-1}), about the same axis
    assert np.allclose(rotation_angle_deg(ident, m), 0.9 * rotation_angle_deg(ident, prev))
    assert np.allclose(rotation_angle_deg(m, prev), 0.1 * rotation_angle_deg(ident, prev))
    assert np.array_equal(m[:, TRANS], prev[:, TRANS]) and np.array_equal(m[:, COEF], prev[:, COEF])


def test_the_prior_density_peaks_at_its_mean() -> None:
    prev = make_pose([0.0, 0.6, 0.0], [5.0, 5.0], [40.0])[None]
    std = paper_config(prior_std_rotation=0.05).prior_std(1)
    m = prior_mean(prev, 0.95)
    cands = np.stack([m[0], prev[0], make_pose([0.0, 0.55, 0.0], [5.0, 5.0], [40.0])])[None]
    lp = log_pose_prior(m, cands, std)[0]
    assert lp[0] > lp[2] > lp[1]


@pytest.mark.parametrize("a", [0.0, -0.5, 1.5, float("nan")])
def test_decay_outside_its_range_is_refused(a: float) -> None:
    with pytest.raises(ValueError, match="prior_rotation_decay"):
        paper_config(prior_rotation_decay=a)
