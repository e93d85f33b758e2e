"""Learning exemplars (sec. 4.1): minimax datum, alignment by direct descent, k-medoids (eq. 8-9)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core import similarity
from gflow_core.m2.align import align_to_reference, pattern_search
from gflow_core.m2.curves import Curves
from gflow_core.m2.distances import ChamferMetric, L2Metric
from gflow_core.m2.exemplars import (evenly_spaced_centres, kmedoids, learn_exemplars, minimax_index,
                                     spaced_walk)


def sqdist(x: np.ndarray) -> np.ndarray:
    return ((x[:, None, :] - x[None, :, :]) ** 2).sum(-1)


def planted(rng: np.random.Generator, n_per: int = 30) -> tuple[np.ndarray, np.ndarray]:
    centres = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    x = np.concatenate([c + rng.normal(0, 1.0, (n_per, 2)) for c in centres])
    return x, np.repeat(np.arange(4), n_per)


def purity(labels: np.ndarray, truth: np.ndarray) -> float:
    return sum(np.bincount(truth[labels == k]).max() for k in np.unique(labels)) / labels.size


def test_minimax_of_points_on_a_line_is_the_middle() -> None:
    x = np.arange(11.0)[:, None]
    D = sqdist(x)
    assert minimax_index(D) == 5
    assert minimax_index(D, np.array([0, 1, 2, 9])) in (1, 2)  # max distance 64 from 1, 49 from 2
    assert minimax_index(D, np.array([0, 1, 2, 9])) == 2
    assert minimax_index(D, np.array([7])) == 7


def test_evenly_spaced_centres_gives_exactly_k_along_the_sequence() -> None:
    # items on a line in time order: centres should be spread evenly
    x = np.linspace(0, 100, 201)[:, None]
    D = np.abs(x - x.T)
    for K in (1, 2, 5, 17, 201):
        c, rho_c = evenly_spaced_centres(D, K)
        assert c.size == K and np.unique(c).size == K
        if 2 <= K < 201:
            gaps = np.diff(x[c, 0])
            assert gaps.max() < 2.5 * gaps.min() + 1e-9
    c, rho_c = evenly_spaced_centres(D, 5)
    assert len(spaced_walk(D, rho_c)) >= 5


def test_kmedoids_finds_planted_clusters() -> None:
    rng = np.random.default_rng(0)
    x, truth = planted(rng)
    D = sqdist(x)
    init, _ = evenly_spaced_centres(D, 4)  # items come in cluster order, like a video
    res = kmedoids(D, init)
    assert res.converged
    assert purity(res.labels, truth) == 1.0
    assert sorted(res.sizes.tolist()) == [30, 30, 30, 30]
    # each medoid is the minimax member of its cluster (eq. 9)
    for k, m in enumerate(res.medoids):
        assert m == minimax_index(D, np.nonzero(res.labels == k)[0])


def test_kmedoids_recovers_from_a_bad_start() -> None:
    rng = np.random.default_rng(1)
    x, truth = planted(rng)
    D = sqdist(x)
    res = kmedoids(D, np.array([0, 1, 2, 3]))  # all four starts in the first cluster
    assert purity(res.labels, truth) >= 0.95


def asymmetric_shape() -> np.ndarray:
    """An 'L' with a dot: no rotational or mirror symmetry, points every 0.5 px."""
    s = np.arange(0, 40, 0.5)
    a = np.stack([np.zeros_like(s), s], 1)
    b = np.stack([s[:40], np.full(40, 39.5)], 1)
    c = np.stack([10 + 3 * np.cos(s[:20]), 10 + 3 * np.sin(s[:20])], 1)
    pts = np.concatenate([a, b, c])
    return pts - pts.mean(axis=0)


@pytest.mark.parametrize("symmetric", [True, False])
def test_alignment_recovers_known_transforms(symmetric: bool) -> None:
    z0 = asymmetric_shape()
    truth = np.array([[0.0, 0.0, 0.0, 1.0], [3.0, -2.0, 0.05, 1.05], [-4.0, 1.5, -0.1, 0.93], [1.0, 5.0, 0.15, 1.1]])
    items = Curves.from_list([similarity.apply(a, z0) for a in truth])
    alpha, rho = align_to_reference(ChamferMetric(upsample=4), items, Curves.from_list([z0]), 0, symmetric=symmetric)
    assert np.abs(alpha[:, :2] - truth[:, :2]).max() < 0.3
    assert np.abs(alpha[:, 2] - truth[:, 2]).max() < 0.01
    assert np.abs(np.log(alpha[:, 3] / truth[:, 3])).max() < 0.01
    assert rho.max() < 0.05


def test_pattern_search_minimises_a_quadratic_in_bounds() -> None:
    target = np.array([[1.0, -2.0], [0.3, 0.7], [5.0, 5.0]])

    def obj(idx: np.ndarray, x: np.ndarray) -> np.ndarray:
        return ((x - target[idx, None, :]) ** 2).sum(-1)

    x, f = pattern_search(obj, np.zeros((3, 2)), np.array([0.5, 0.5]), -3.0, 3.0, min_step_ratio=1e-4)
    assert x[:2] == pytest.approx(target[:2], abs=1e-3)
    assert x[2] == pytest.approx([3.0, 3.0])  # clipped to the box
    assert f[2] == pytest.approx(8.0)


def shapes_sequence(rng: np.random.Generator) -> tuple[list[np.ndarray], np.ndarray]:
    t = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    circle = np.stack([20 * np.cos(t), 20 * np.sin(t)], 1)
    u = np.linspace(-1, 1, 30, endpoint=False)
    square = np.concatenate([np.stack([18 * u, -18 + 0 * u], 1), np.stack([18 + 0 * u, 18 * u], 1),
                             np.stack([-18 * u, 18 + 0 * u], 1), np.stack([-18 + 0 * u, -18 * u], 1)])
    bar = np.stack([np.concatenate([u * 5, u * 5]), np.concatenate([-25 + 0 * u, 25 + 0 * u])], 1)
    sides = np.stack([np.concatenate([-5 + 0 * u, 5 + 0 * u]), np.concatenate([25 * u, 25 * u])], 1)
    bar = np.concatenate([bar, sides])
    shapes = [circle, square, bar]
    truth = np.repeat([0, 1, 2, 0, 1], 8)
    items = [shapes[s] + rng.normal(0, 0.5, shapes[s].shape) for s in truth]
    return items, truth


def test_learn_exemplars_clusters_shapes() -> None:
    rng = np.random.default_rng(5)
    items, truth = shapes_sequence(rng)
    calls: list[str] = []
    fit = learn_exemplars(ChamferMetric(), items, K=3, progress=lambda s, d, t: calls.append(s))
    assert purity(fit.clusters.labels, truth) == 1.0
    assert fit.pi == pytest.approx(np.bincount(fit.clusters.labels, minlength=3) / truth.size)
    assert fit.pi.sum() == pytest.approx(1.0)
    assert len(fit.exemplars) == 3
    assert fit.alpha_star.shape == (truth.size, 4)
    assert {"datum", "align", "distances", "kmedoids"} <= set(calls)
    # aligned items stay close to where they were: the shapes are centred already
    assert np.abs(fit.alpha_star[:, :2]).max() < 3.0


def test_learn_exemplars_bad_input() -> None:
    rng = np.random.default_rng(0)
    items = [rng.normal(size=(10, 2)) for _ in range(4)]
    with pytest.raises(ValueError, match="no training"):
        learn_exemplars(ChamferMetric(), [], K=1)
    with pytest.raises(ValueError, match="single"):
        learn_exemplars(ChamferMetric(), items[:1], K=1)
    with pytest.raises(ValueError, match="K=5"):
        learn_exemplars(ChamferMetric(), items, K=5)
    with pytest.raises(ValueError, match="positive integer"):
        learn_exemplars(ChamferMetric(), items, K=0)
    with pytest.raises(ValueError, match=r"\(P, 2\)"):
        learn_exemplars(ChamferMetric(), [np.zeros((0, 2)), np.zeros((3, 2))], K=1)
    with pytest.raises(ValueError, match="no patches"):
        learn_exemplars(L2Metric(), np.zeros((0, 4, 4)), K=1)

