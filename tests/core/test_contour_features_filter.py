"""The contour filter's side of the protocol over precomputed features
(gflow_core.contour.features_filter.FEATURE_FILTER, what the chamfer and m2 filter stages drive)
gives the contour protocol's (CHAMFER, which computes the features itself) posterior and estimates
bit for bit when handed the same features."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from gflow_core.contour.features_filter import FEATURE_FILTER
from gflow_core.contour.observation import exemplar_error, is_blank, same_profile, usable_chamfer, usable_grey
from gflow_core.contour.params import ChamferParams
from gflow_core.contour.protocol import CHAMFER
from gflow_core.synthetic import SyntheticScene
from gflow_core.tracker import FrameRng


def test_the_feature_filter_steps_as_the_contour_protocol_does() -> None:
    scene = SyntheticScene(width=160, height=120, n_frames=8, seed=5, noise=4.0)
    params, box = ChamferParams(particles=120), scene.truth_box(0)
    rng = lambda t: FrameRng(3, 77, t)  # noqa: E731
    frame0 = CHAMFER.observe(params, scene.render(0))
    track, est = CHAMFER.init(params, frame0, box, rng(0), {})
    fobs = lambda fr: CHAMFER.features(params, fr, track.edges, track.thresholds, True)  # noqa: E731
    st, est2 = FEATURE_FILTER.init(params, fobs(frame0), box, rng(0), {})
    assert est2.box == est.box and est2.phase == "init"
    for t in range(1, 8):
        img = np.zeros_like(scene.render(t)) if t == 5 else scene.render(t)  # a blank frame coasts
        frame = CHAMFER.observe(params, img)
        proposal = CHAMFER.propose(params, track, frame, rng(t))
        track, est = CHAMFER.update(params, track, proposal, frame, rng(t))
        st, est2 = FEATURE_FILTER.update(params, st, proposal, fobs(frame), rng(t))
        assert (est2.box, est2.phase, est2.confidence) == (est.box, est.phase, est.confidence)
        assert np.array_equal(st.cloud.alpha, track.filter.cloud.alpha)
    assert est.phase in ("track", "lost", "redetect")
    # frames with no features at all: the last posterior weighed by no evidence
    st, est2 = FEATURE_FILTER.coast(params, st, rng(8))
    assert est2.phase == "coast"
    obs = FEATURE_FILTER.observe(params, scene.render(0))
    assert obs.edges is not None and obs.edges.shape == (120, 160) and obs.chamfer is not None and obs.grey is not None


def test_what_the_filter_reads_of_features_and_refuses_of_proposals() -> None:
    from gflow_core.m2.tracking import ParticleCloud

    edges = np.zeros((20, 30), np.uint8)
    edges[5, :9] = 255
    assert is_blank(ChamferParams(min_edges=10), edges) and not is_blank(ChamferParams(min_edges=9), edges)
    assert not is_blank(ChamferParams(min_edges=0), np.zeros((20, 30), np.uint8))  # the rule off
    cham = np.ones((20, 30), np.float32)
    assert usable_chamfer(cham) and not usable_chamfer(cham[0]) and not usable_chamfer(cham[:0])
    cham[3, 4] = np.nan
    assert not usable_chamfer(cham)
    assert usable_grey(np.zeros((3, 3), np.uint8)) and not usable_grey(np.zeros((2, 30), np.uint8))
    assert not usable_grey(np.zeros((20, 30, 3), np.uint8))
    truncated = SimpleNamespace(profile="truncated", g0=100.0)
    assert same_profile(truncated, "truncated", 100.0 + 1e-9)
    assert not same_profile(truncated, "truncated", 64.0) and not same_profile(truncated, "quadratic", 100.0)
    assert same_profile(SimpleNamespace(profile="quadratic", g0=100.0), "quadratic", 64.0)  # g0 unused
    cloud = ParticleCloud(alpha=np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)), k=np.array([0, 2, 1]), log_w=np.zeros(3))
    assert exemplar_error(cloud, 3) == ""
    assert exemplar_error(cloud, 2) == "exemplar index 2 beyond the model's K=2"
