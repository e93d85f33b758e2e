"""Departures that make G-flow robust: coarse-to-fine Gauss-Newton with a coarse search
(pose_opinion.coarse_to_fine_peak), per-frame gain/bias (photometric) and the rotation wall."""

from __future__ import annotations

import dataclasses
import numpy as np
import pytest

from gflow_core.gflow import paper_config
from gflow_core.gflow.filter import init_state, step
from gflow_core.gflow.geometry import ROT, TRANS, box_plus, make_pose
from gflow_core.gflow.head_model import fit_head_to_box
from gflow_core.gflow.image import frame_pyramid, prepare_frame
from gflow_core.gflow.photometric import Photometric, gain_bias
from gflow_core.gflow.pose_opinion import (
    TextureView,
    coarse_to_fine_peak,
    gauss_newton_objective,
    gauss_newton_peak,
    log_pose_prior,
    rotation_wall,
    search_offsets,
)
from gflow_core.gflow.synthetic_head import SphereTexture, render_head, smooth_background

PRIOR = np.array([0.05, 0.05, 0.05, 50.0, 50.0, 1.0])


def _scene(offset_px: float, gain: float = 1.0, bias: float = 0.0):
    """A rendered head moved by ``offset_px`` (x and y, pixels) from the start pose."""
    rng = np.random.default_rng(7)
    shape = (160, 200)
    head, pose0 = fit_head_to_box(np.array([70.0, 40.0, 50.0, 60.0]), shape)
    model = head.model()
    tex = SphereTexture.random(rng, min_freq=1.0, max_freq=3.0)
    true = make_pose(None, pose0[TRANS] + offset_px / np.sqrt(2.0), pose0[5:])
    frame = render_head(head, true, tex, smooth_background(shape, rng, sigma_px=12.0), rng=rng, noise_std=0.005)
    frame = np.clip(gain * frame + bias, 0.0, 1.0)
    tv = TextureView(tex(head.directions())[None], np.full((1, model.n_vertices), 1e-4))
    return model, pose0[None], true, frame, tv


def _trans_error(u: np.ndarray, true: np.ndarray) -> float:
    return float(np.hypot(*(u[0, TRANS] - true[TRANS])))


def test_pyramid_gauss_newton_converges_from_30px_where_single_scale_does_not() -> None:
    model, start, true, frame, tv = _scene(30.0)
    fd = prepare_frame(frame)
    single = gauss_newton_peak(model.bases, fd, start, tv, 1e-3, PRIOR, 15)
    pyr = coarse_to_fine_peak(model.bases, frame_pyramid(fd, 4), start, tv, 1e-3, PRIOR, 5)
    assert _trans_error(single.u_hat, true) > 10.0
    assert _trans_error(pyr.u_hat, true) < 1.0
    assert np.all(np.linalg.eigvalsh(pyr.hessian) > 0)


def test_coarse_search_reaches_a_36px_jump() -> None:
    model, start, true, frame, tv = _scene(36.0 * np.sqrt(2.0))  # 51 px diagonal
    fd = prepare_frame(frame)
    pyr = coarse_to_fine_peak(model.bases, frame_pyramid(fd, 3), start, tv, 1e-3, PRIOR, 5)
    found = coarse_to_fine_peak(model.bases, frame_pyramid(fd, 3), start, tv, 1e-3, PRIOR, 5,
                                offsets=search_offsets(40.0, 8.0))
    assert _trans_error(pyr.u_hat, true) > 10.0
    assert _trans_error(found.u_hat, true) < 1.0


def test_one_level_without_search_is_plain_gauss_newton() -> None:
    model, start, _, frame, tv = _scene(3.0)
    fd = prepare_frame(frame)
    a = gauss_newton_peak(model.bases, fd, start, tv, 1e-3, PRIOR, 5)
    b = coarse_to_fine_peak(model.bases, [fd], start, tv, 1e-3, PRIOR, 5)
    assert np.array_equal(a.u_hat, b.u_hat) and np.array_equal(a.hessian, b.hessian)


def test_search_offsets_start_at_zero_and_cover_the_square() -> None:
    off = search_offsets(16.0, 8.0)
    assert off.shape == (25, 2) and np.array_equal(off[0], [0.0, 0.0])
    assert np.abs(off).max() == 16.0
    assert search_offsets(0.0, 8.0).shape == (1, 2)


def test_gain_bias_recovers_a_known_gain_and_bias() -> None:
    rng = np.random.default_rng(3)
    mu = rng.uniform(0.1, 0.9, (4, 200))
    a_true, b_true = np.array([0.6, 1.0, 1.3, 1.8]), np.array([0.1, 0.0, -0.2, 0.05])
    y = a_true[:, None] * mu + b_true[:, None] + rng.normal(0.0, 0.005, mu.shape)
    a, b = gain_bias(y, mu, np.full(mu.shape, 1e3), Photometric(gain_max=2.0))
    np.testing.assert_allclose(a, a_true, atol=0.01)
    np.testing.assert_allclose(b, b_true, atol=0.01)
    # the clamp
    a2, _ = gain_bias(3.0 * mu, mu, np.ones(mu.shape), Photometric(gain_max=2.0))
    assert np.all(a2 == 2.0)


def test_photometric_gauss_newton_is_not_moved_by_a_change_of_light() -> None:
    model, start, true, frame, tv = _scene(4.0, gain=0.6, bias=0.15)
    fd = prepare_frame(frame)
    plain = gauss_newton_peak(model.bases, fd, start, tv, 1e-3, PRIOR, 10)
    robust = gauss_newton_peak(model.bases, fd, start, tv, 1e-3, PRIOR, 10, photometric=Photometric())
    assert _trans_error(robust.u_hat, true) < 0.5
    assert _trans_error(robust.u_hat, true) < _trans_error(plain.u_hat, true)


def test_rotation_wall_is_zero_inside_and_its_gradient_is_right() -> None:
    u = make_pose(np.radians([10.0, 0.0, 0.0]), [0.0, 0.0], [1.0])[None]
    pen, g, h = rotation_wall(u, np.radians(30.0))
    assert pen[0] == 0.0 and not g.any() and not h.any()
    u = make_pose(np.radians([30.0, 25.0, -5.0]), [0.0, 0.0], [1.0])[None]
    pen, g, _ = rotation_wall(u, np.radians(30.0))
    assert pen[0] > 0
    for p in range(3):
        e = np.zeros(6)
        e[p] = 1e-6
        fp = rotation_wall(box_plus(u, e), np.radians(30.0))[0]
        fm = rotation_wall(box_plus(u, -e), np.radians(30.0))[0]
        np.testing.assert_allclose(g[0, p], (fp - fm)[0] / 2e-6, rtol=1e-4)
    prev = u.copy()
    assert log_pose_prior(prev, u[:, None], PRIOR, np.radians(30.0))[0, 0] < log_pose_prior(prev, u[:, None], PRIOR)[0, 0]
    f_wall = gauss_newton_objective(np.zeros((3, 3, 1)) + 1.0, prepare_frame(np.full((8, 8), 0.5)), prev, u,
                                    TextureView(np.full((1, 3), 0.5), np.full((1, 3), 1e-3)), 1e-3, PRIOR,
                                    max_rotation=np.radians(30.0))
    assert f_wall[0] == pytest.approx(pen[0])


def test_robust_filter_shards_equal_one_batch() -> None:
    """Experts stay independent (so proposal shards concatenate bit for bit) with every option on."""
    from gflow_core.gflow.filter import concatenate_proposals, expert_rngs, propose

    model, start, _, frame, _ = _scene(20.0)
    cfg = paper_config(n_experts=4, n_samples=3, pyramid_levels=3, search_radius=16.0, search_step=8.0,
                      photometric=True, max_rotation_deg=30.0, outlier_sigmas=3.0, max_scale_change=1.5,
                      scale_reference=tuple(start[0, 5:]))
    st = init_state(model, start[0], frame, cfg, rng=np.random.default_rng(0), pose_jitter_std=1.0)
    whole = propose(st, frame, model, cfg, expert_rngs(1, 0, 1, range(4)))
    parts = [propose(st, frame, model, cfg, expert_rngs(1, 0, 1, ix), ix) for ix in ([2, 3], [0, 1])]
    joined = concatenate_proposals(parts)
    for f in ("u_hat", "samples", "log_weights", "log_evidence"):
        assert np.array_equal(getattr(whole, f), getattr(joined, f)), f
    st2, est = step(st, frame, model, cfg, 1, 1)
    assert np.isfinite(est.pose).all()


def test_config_rejects_bad_robust_options() -> None:
    for kw in ({"pyramid_levels": 0}, {"search_radius": -1.0}, {"search_step": 0.0}, {"photometric_gain_max": 1.0},
               {"max_rotation_deg": 0.0}, {"search_stride": 0}, {"max_scale_change": 1.0}, {"outlier_sigmas": 0.0},
               {"search_radius": 100.0, "search_step": 1.0}):
        with pytest.raises(ValueError, match=next(iter(kw)).split("_")[0]):
            paper_config(**kw)


def test_outlier_process_caps_the_cost_and_ignores_an_occluded_patch() -> None:
    from gflow_core.gflow.pose_opinion import log_likelihood, robust_cost

    e2 = np.array([0.5, 4.0, 100.0])
    assert np.array_equal(robust_cost(e2, 9.0), [0.5, 4.0, 9.0])
    assert robust_cost(e2, np.inf) is e2
    model, start, true, frame, tv = _scene(1.0)
    # a dark occluder over the upper left of the head (box 70..120 x 40..100)
    occluded = frame.copy()
    occluded[40:60, 70:90] = 0.05
    fd = prepare_frame(occluded)
    plain = gauss_newton_peak(model.bases, fd, start, tv, 1e-3, PRIOR, 10)
    robust = gauss_newton_peak(model.bases, fd, start, tv, 1e-3, PRIOR, 10, outlier_sq=9.0)
    assert _trans_error(plain.u_hat, true) > 2.0
    assert _trans_error(robust.u_hat, true) < 0.6
    ll = log_likelihood(model.bases, fd, true[None, None], tv, 1e-3, outlier_sq=9.0)
    assert np.isfinite(ll).all() and ll[0, 0] > log_likelihood(model.bases, fd, true[None, None], tv, 1e-3)[0, 0]


def test_outlier_texels_are_not_updated() -> None:
    model, start, _, frame, _ = _scene(0.0)
    cfg = paper_config(n_experts=2, n_samples=2, alpha=0.0, outlier_sigmas=3.0)
    st = init_state(model, start[0], frame, cfg)
    occluded = frame.copy()
    occluded[30:60, 60:90] = 0.0
    st2, _ = step(st, occluded, model, cfg, 1, 1)
    changed = np.abs(st2.tex_mean - st.tex_mean) > 0.05
    assert not changed.any()
    assert (st2.tex_var > st.tex_var).any()  # those texels were only predicted


def test_scale_wall_is_zero_inside_and_its_gradient_is_right() -> None:
    from gflow_core.gflow.pose_opinion import scale_wall

    lim = (40.0, np.log(1.5))
    inside = make_pose(None, [0.0, 0.0], [50.0])[None]
    pen, g, h = scale_wall(inside, lim)
    assert pen[0] == 0.0 and not g.any() and not h.any()
    for c in (20.0, 75.0):
        u = make_pose(None, [0.0, 0.0], [c])[None]
        pen, g, _ = scale_wall(u, lim)
        assert pen[0] > 0
        e = 1e-5
        fp = scale_wall(make_pose(None, [0.0, 0.0], [c + e])[None], lim)[0]
        fm = scale_wall(make_pose(None, [0.0, 0.0], [c - e])[None], lim)[0]
        np.testing.assert_allclose(g[0, 0], (fp - fm)[0] / (2 * e), rtol=1e-5)
    assert scale_wall(inside, None)[0][0] == 0.0


def test_the_scale_wall_is_relative_to_the_initial_box() -> None:
    from gflow_core.gflow import PAPER, GFlowParams, model_setup
    from gflow_core.params import make

    box = (40.0, 30.0, 30.0, 40.0)
    setup = model_setup(make(GFlowParams, PAPER, max_scale_change=1.5), box, (120, 160))
    assert setup.cfg.scale_reference == (pytest.approx(40.0),)
    assert setup.cfg.scale_limits() == (pytest.approx(40.0), pytest.approx(np.log(1.5)))
    assert model_setup(make(GFlowParams, PAPER), box, (120, 160)).cfg.scale_limits() is None


def test_copied_experts_and_one_expert_shards_equal_one_batch() -> None:
    """The peak is computed once for experts that are copies of one another, the search's second
    chain only for the experts it moved, and Gauss-Newton relinearises only the experts whose
    step was taken: none of this may change any expert's numbers, alone or in a batch."""
    from gflow_core.gflow.filter import ExpertState, concatenate_proposals, expert_rngs, propose

    model, start, _, frame, _ = _scene(20.0)
    cfg = paper_config(n_experts=4, n_samples=3, pyramid_levels=3, search_radius=32.0, search_step=8.0,
                      photometric=True, max_rotation_deg=30.0, outlier_sigmas=3.0, max_scale_change=1.5,
                      scale_reference=tuple(start[0, 5:]))
    st = init_state(model, start[0], frame, cfg, rng=np.random.default_rng(0), pose_jitter_std=1.0)
    # experts 0-2 copies of one, 3-4 of another, 5 alone (a resampled population)
    rows = np.array([0, 0, 0, 1, 1, 3])
    st = ExpertState(poses=st.poses[rows], tex_mean=st.tex_mean[rows], tex_var=st.tex_var[rows], bg_mean=None,
                     bg_var=None, log_credibility=np.full(6, -np.log(6)), image_shape=st.image_shape)
    cfg = dataclasses.replace(cfg, n_experts=6)
    whole = propose(st, frame, model, cfg, expert_rngs(1, 0, 1, range(6)))
    assert np.array_equal(whole.u_hat[0], whole.u_hat[2]) and not np.array_equal(whole.u_hat[0], whole.u_hat[5])
    alone = concatenate_proposals([propose(st, frame, model, cfg, expert_rngs(1, 0, 1, [i]), [i]) for i in range(6)])
    for f in ("u_hat", "sigma_hat", "samples", "log_weights", "log_evidence", "gn_objective"):
        assert np.array_equal(getattr(whole, f), getattr(alone, f)), f


def test_whole_pixel_search_samples_as_the_stencil_does() -> None:
    """coarse_search's shared bilinear weights and padded border give the values of sampling
    every translated vertex through image.stencil_xy (clamped border), far outside the image too."""
    from gflow_core.gflow.coarse_search import _Lattice, translation_costs
    from gflow_core.gflow.image import stencil_xy

    rng = np.random.default_rng(4)
    img = rng.random((30, 40))
    x = rng.uniform(-60.0, 100.0, (3, 50))
    y = rng.uniform(-50.0, 80.0, (3, 50))
    x[0, :5] = [0.0, 39.0, 39.5, -0.25, 38.999]
    shifts = search_offsets(4.0, 2.0)
    got = _Lattice(img, shifts.astype(np.intp)).sample(x, y)
    want = stencil_xy(x[:, None, :] + shifts[None, :, 0, None], y[:, None, :] + shifts[None, :, 1, None],
                      img.shape).sample(img.reshape(-1))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    mu, w = rng.random((3, 50)), rng.random((3, 50))
    c = translation_costs(img, x, y, shifts, mu, w)
    np.testing.assert_allclose(c, ((want - mu[:, None]) ** 2 * w[:, None]).sum(-1), rtol=1e-12)
    # translations that are not whole pixels take the general path, with the same result form
    c2 = translation_costs(img, x, y, shifts + 0.5, mu, w)
    want2 = stencil_xy(x[:, None, :] + shifts[None, :, 0, None] + 0.5, y[:, None, :] + shifts[None, :, 1, None] + 0.5,
                       img.shape).sample(img.reshape(-1))
    np.testing.assert_allclose(c2, ((want2 - mu[:, None]) ** 2 * w[:, None]).sum(-1), rtol=1e-12)


def test_tempered_data_term_is_the_prior_made_kappa_times_as_precise() -> None:
    """``data_temper = kappa`` divides eq. 14's data term by kappa: the same peak (search included) as the
    untempered objective with the prior's std divided by sqrt(kappa), with kappa times smaller objective and
    Hessian; with a tight prior the tempered peak stays nearer the prior's mean."""
    model, start, true, frame, tv = _scene(20.0)
    pyr = frame_pyramid(prepare_frame(frame), 3)
    off = search_offsets(32.0, 8.0)
    prior = np.array([0.05, 0.05, 0.05, 4.0, 4.0, 1.0])
    kappa = 4.0
    plain = coarse_to_fine_peak(model.bases, pyr, start, tv, 1e-3, prior, 5, offsets=off, outlier_sq=9.0)
    tempered = coarse_to_fine_peak(model.bases, pyr, start, tv, 1e-3, prior, 5, offsets=off, outlier_sq=9.0,
                                   temper=kappa)
    same = coarse_to_fine_peak(model.bases, pyr, start, tv, 1e-3, prior / np.sqrt(kappa), 5, offsets=off,
                               outlier_sq=9.0)
    np.testing.assert_allclose(tempered.u_hat, same.u_hat, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(kappa * tempered.hessian, same.hessian, rtol=1e-9)
    np.testing.assert_allclose(kappa * tempered.objective, same.objective, rtol=1e-9)
    assert _trans_error(tempered.u_hat, start[0]) < _trans_error(plain.u_hat, start[0]) - 0.2
    # kappa = 1 is the untempered objective, bit for bit
    one = gauss_newton_objective(model.bases, pyr[0], start, plain.u_hat, tv, 1e-3, prior, temper=1.0)
    assert one.tobytes() == gauss_newton_objective(model.bases, pyr[0], start, plain.u_hat, tv, 1e-3, prior).tobytes()


@pytest.mark.parametrize("bad", [0.5, 0.0, float("nan"), float("inf")])
def test_data_temper_below_one_or_not_finite_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="data_temper"):
        paper_config(data_temper=bad)


def test_generic_background_subtracts_its_first_term_of_eq14_everywhere() -> None:
    """``TextureView.generic``: eq. 14's data term minus ``sum_i (y(x_i) - m)^2 / s^2`` (the frame's mean and
    variance) in the objective, the log-likelihood (eq. 13) and the coarse search, at any pose."""
    from gflow_core.gflow.coarse_search import translation_costs
    from gflow_core.gflow.geometry import project
    from gflow_core.gflow.image import bilinear_stencil
    from gflow_core.gflow.pose_opinion import generic_background, log_likelihood

    model, start, true, frame, tv = _scene(6.0)
    fd = prepare_frame(frame)
    gen = dataclasses.replace(tv, generic=True)
    m, w = generic_background(fd.image)
    assert m == pytest.approx(frame.mean()) and w == pytest.approx(1.0 / frame.var())
    poses = np.stack([start[0], true, box_plus(true, np.array([0.02, 0.0, 0.0, 3.0, -2.0, 0.0]))])
    prev = np.repeat(start, 3, axis=0)
    tv3 = TextureView(np.repeat(tv.mean, 3, axis=0), np.repeat(tv.var, 3, axis=0))
    gen3 = dataclasses.replace(tv3, generic=True)
    y = bilinear_stencil(project(model.bases, poses), fd.shape).sample(fd.flat)  # (3, n)
    term = w * ((y - m) ** 2).sum(axis=-1)
    plain = gauss_newton_objective(model.bases, fd, prev, poses, tv3, 1e-3, PRIOR, outlier_sq=9.0)
    with_bg = gauss_newton_objective(model.bases, fd, prev, poses, gen3, 1e-3, PRIOR, outlier_sq=9.0)
    np.testing.assert_allclose(plain - with_bg, 0.5 * term, rtol=1e-9)
    ll = log_likelihood(model.bases, fd, poses[:, None], tv3, 1e-3, outlier_sq=9.0)
    ll_bg = log_likelihood(model.bases, fd, poses[:, None], gen3, 1e-3, outlier_sq=9.0)
    np.testing.assert_allclose(ll_bg - ll, 0.5 * term[:, None], rtol=1e-9)
    # the search's costs on a level: the same term at every translation
    xy = project(model.bases, start)
    shifts = search_offsets(8.0, 4.0)
    c = translation_costs(fd.image, xy[..., 0], xy[..., 1], shifts, np.full(xy.shape[:-1], m),
                          np.full(xy.shape[:-1], w))
    ys = bilinear_stencil(xy[:, None] + shifts[None, :, None], fd.shape).sample(fd.flat)
    np.testing.assert_allclose(c, w * ((ys - m) ** 2).sum(axis=-1), rtol=1e-9)
    # the peak with the generic background still finds the head, with a positive definite Hessian
    pk = coarse_to_fine_peak(model.bases, frame_pyramid(fd, 3), start, gen, 1e-3, PRIOR, 5,
                             offsets=search_offsets(16.0, 8.0), outlier_sq=9.0)
    assert _trans_error(pk.u_hat, true) < 1.0
    assert np.all(np.linalg.eigvalsh(pk.hessian) > 0)


def test_generic_background_must_be_a_bool() -> None:
    with pytest.raises(ValueError, match="generic_background"):
        paper_config(generic_background="yes")
