"""End to end: learn() on synthetic video (sec. 4), and tracking with the learned model (sec. 5)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gflow_core.features import chamfer_image, edge_map, to_grey
from gflow_core.m2 import patch_tracking, tracking, training
from gflow_core.m2.learn import learn, learn_detailed
from gflow_core.m2.model import M2Model


def gait_frames(n: int, seed: int, x0: float = 25.0) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 1, size=(10, 16))
    bg = np.clip(60 + 40 * cv2.resize(noise, (150, 90), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)
    frames, centres, widths = [], [], []
    for t in range(n):
        f = cv2.cvtColor(bg, cv2.COLOR_GRAY2BGR)
        c = (int(round(x0 + 3.0 * t)), 45)
        a = int(round(10 + 4 * np.sin(2 * np.pi * t / 8)))
        cv2.ellipse(f, c, (a, 22), 0, 0, 360, (220, 210, 200), -1)
        frames.append(f)
        centres.append(c)
        widths.append(a)
    return frames, np.array(centres, dtype=np.float64), np.array(widths)


def test_learn_curves_from_video_end_to_end() -> None:
    frames, centres, widths = gait_frames(32, seed=0)
    ts = training.curves_from_background(frames, max_points=100)
    stages: list[tuple[str, int, int]] = []
    res = learn_detailed(ts, "chamfer", K=4, kernel="moments", progress=lambda s, d, t: stages.append((s, d, t)))
    m = res.model
    assert m.K == 4 and m.metric == "chamfer" and len(m.exemplars) == 4
    assert np.array_equal(m.exemplar_frame, ts.frame_index[res.exemplar_fit.clusters.medoids])
    assert (m.d > 0).all() and (m.sigma > 0).all() and m.pi.sum() == pytest.approx(1.0)
    assert m.markov.sum(axis=1) == pytest.approx(np.ones(4)) and (m.markov > 0).all()
    names = [s for s, _, _ in stages]
    order = ["datum", "align", "distances", "kmedoids", "validation", "kernel", "dynamics"]
    assert [n for n in dict.fromkeys(names)] == order
    assert all(d <= t for _, d, t in stages) and stages[-1] == ("dynamics", 1, 1)
    # exemplars separate the gait phases: items of one cluster have similar widths
    for k in range(4):
        w = widths[res.states_k == k]
        assert w.max() - w.min() <= 4
    # the state series places the exemplars where the ellipse was
    assert np.abs(res.states_alpha[:, :2] - centres).max() < 3.0
    # translation is a random walk whose noise covers the 3 px/frame walk
    std = np.sqrt(np.diag(m.dynamics.B @ m.dynamics.B.T))
    assert m.dynamics.A[:2] == pytest.approx(np.eye(4)[:2])
    assert 2.0 < std[0] < 4.5
    # the validation distances are directed chamfer distances at the refined alpha
    v = res.validation
    assert (v.rho[~v.is_validation] == 0).all() and (v.rho[v.is_validation] >= 0).all()
    # the MLE variant gives integer d
    m2 = learn(ts, "chamfer", K=4, kernel="mle")
    assert np.array_equal(m2.d, np.round(m2.d)) and (m2.d >= 1).all()
    # the largest training item's scale is kept: the resolution the dynamics' noise was learned at
    assert m.train_scale == pytest.approx(float(ts.placement[:, 3].max())) and m.train_scale >= 1.0
    # round trip and tracking on a frame not seen in training
    m = M2Model.from_arrays(m.to_arrays())
    test_frames, test_centres, test_widths = gait_frames(40, seed=0, x0=20.0)
    t = 37
    gam = chamfer_image(edge_map(to_grey(test_frames[t])), "quadratic")
    ex = m.to_contour_exemplars()
    # the exemplar that training assigned to frames of the same gait phase wins, at its scale
    same_phase = np.nonzero(widths == test_widths[t])[0]
    k_true = int(np.bincount(res.states_k[same_phase]).argmax())
    cx, cy = test_centres[t]
    scales = np.linspace(0.8, 1.25, 19)
    alphas = np.array([[cx, cy, 0.0, s] for k in range(4) for s in scales])
    ks = np.repeat(np.arange(4), scales.size)
    cloud = tracking.ParticleCloud(alpha=alphas, k=ks, log_w=np.zeros(ks.size))
    ll, rho = tracking.weigh(cloud, ex, gam)
    best = int(np.argmin(rho))
    assert ks[best] == k_true
    # and moving the winner off the target costs distance
    off = cloud.alpha[[best, best, best]] + np.array([[6.0, 0, 0, 0], [0, -5.0, 0, 0], [-4.0, 4.0, 0, 0]])
    _, rho_off = tracking.weigh(tracking.ParticleCloud(alpha=off, k=ks[[best] * 3], log_w=np.zeros(3)), ex, gam)
    assert rho_off.min() > 2.0 * rho[best]


def mouth_patches(n_per_block: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    base = []
    for _ in range(3):
        small = rng.uniform(0, 255, size=(4, 5))
        base.append(cv2.resize(small, (20, 16), interpolation=cv2.INTER_CUBIC))
    base = np.array(base)
    truth = np.repeat([0, 1, 2, 1, 0, 2], n_per_block)
    items = []
    for s in truth:
        dx, dy = rng.integers(-1, 2, size=2)
        p = np.roll(base[s], (dy, dx), axis=(0, 1)) + rng.normal(0, 4.0, size=(16, 20))
        items.append(p)
    return np.array(items), truth, base


def test_learn_patches_and_track_mouth_states() -> None:
    items, truth, base = mouth_patches(8, seed=3)
    m = learn(training.patches_from_frames(list(items.astype(np.float32) / 255.0)), "shuffle", K=3,
              metric_params={"radius": 1})
    assert m.metric == "shuffle" and m.exemplars.shape == (3, 16, 20)
    assert (m.d > 0).all() and (m.sigma > 0).all()
    pe = m.to_patch_exemplars()
    # the exemplars are the three patterns
    obs = [np.clip(base[s] + np.random.default_rng(10 + s).normal(0, 4.0, (16, 20)), 0, 255) for s in range(3)]
    best = [int(np.argmax(patch_tracking.exemplar_log_likelihood(pe, o)[0])) for o in obs]
    assert sorted(best) == [0, 1, 2]
    # particles follow the exact forward filter over k
    rng = np.random.default_rng(0)
    k = patch_tracking.init_k(20_000, pe, rng)
    p = pe.pi.copy()
    seq = [0, 0, 1, 1, 2]
    for s in seq:
        k = patch_tracking.propose_k(k, pe, rng)
        ll, rho = patch_tracking.weigh_patches(k, pe, obs[s])
        post = patch_tracking.patch_posterior(k, ll, pe.K, rng)
        p = patch_tracking.forward_step(p, pe, obs[s])
        assert post.k_hist == pytest.approx(p, abs=0.02)
        assert post.map_k == best[s] and int(np.argmax(p)) == best[s]
        k = post.resampled
    with pytest.raises(ValueError, match="out of range"):
        patch_tracking.weigh_patches(np.array([5]), pe, obs[0])


def test_learn_l2_patches_without_alignment() -> None:
    # poses A B C B A C: the paper's spaced walk starts two centres in A and none in B, and
    # minimax k-medoids cannot recover; init="best" adds a maximin start and keeps the better
    items, truth, _ = mouth_patches(6, seed=4)
    res = learn_detailed(items, "l2", K=3)
    assert np.array_equal(res.exemplar_fit.alpha_star, np.tile([0.0, 0.0, 0.0, 1.0], (len(items), 1)))
    labels = res.exemplar_fit.clusters.labels
    for k in range(3):
        assert np.unique(truth[labels == k]).size == 1
    spaced = learn_detailed(items, "l2", K=3, init="spaced").exemplar_fit
    assert np.unique(truth[spaced.init]).size < 3
    assert max(np.unique(truth[spaced.clusters.labels == k]).size for k in range(3)) > 1
    with pytest.raises(ValueError, match="initialisation"):
        learn(items, "l2", K=3, init="random")
