"""The mixture proposal of G-flow's experts (``online_mix``, :mod:`gflow_core.gflow.mixture`): a share of each
expert's samples drawn about a detector's place, every importance weight corrected for the mixture."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from gflow_core.gflow import expert_rngs, fit_head_model_to_box, init_state, paper_config, propose
from gflow_core.gflow.geometry import project
from gflow_core.gflow.head_model import bounding_box
from gflow_core.gflow.image import frame_pyramid, prepare_frame
from gflow_core.gflow.geometry import box_minus
from gflow_core.gflow.mixture import detector_peaks, detector_starts, mixture_proposals
from gflow_core.gflow.pose_opinion import TextureView, log_likelihood, log_pose_prior
from gflow_core.gflow.params import GFlowParams
from gflow_core.gflow.synthetic_head import synthetic_sequence


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(np.random.default_rng(5), 3, (60, 80), rot_amp_deg=(4, 6, 3), trans_amp_px=(4, 2))


def _proposed(seq, n_samples: int, n_experts: int = 2, gn_iterations: int = 5):
    model, pose0 = fit_head_model_to_box(seq.box, seq.frames.shape[1:])
    cfg = paper_config(n_experts=n_experts, n_samples=n_samples, sigma_w=2e-3, pyramid_levels=2,
                       gn_iterations=gn_iterations)
    state = init_state(model, pose0, seq.frames[0], cfg)
    props = propose(state, seq.frames[1], model, cfg, expert_rngs(7, 0, 1, range(n_experts)))
    pyramid = tuple(frame_pyramid(prepare_frame(seq.frames[1]), cfg.pyramid_levels))
    centres = bounding_box(project(model.bases, props.u_hat))
    centres = centres[:, :2] + 0.5 * (centres[:, 2:] - 1.0)
    return model, cfg, state, props, pyramid, centres


def test_no_share_is_the_proposal_itself(seq) -> None:
    model, cfg, state, props, pyramid, centres = _proposed(seq, 10)
    starts = detector_starts(props.u_hat, centres, (30.0, 20.0))
    assert mixture_proposals(state, props, pyramid, model, cfg, starts, 0.0, np.random.default_rng(1)) is props
    assert mixture_proposals(state, props, pyramid, model, cfg, starts, 0.04, np.random.default_rng(1)) is props


def test_the_share_is_drawn_about_the_detection_and_the_rest_kept(seq) -> None:
    model, cfg, state, props, pyramid, centres = _proposed(seq, 10)
    place = tuple(float(v) for v in centres[0] + (3.0, -2.0))
    starts = detector_starts(props.u_hat, centres, place)
    # the opinions' boxes moved to the detector's place
    moved = bounding_box(project(model.bases, starts))
    assert np.allclose(moved[:, :2] + 0.5 * (moved[:, 2:] - 1.0), np.array(place)[None], atol=1e-9)
    out = mixture_proposals(state, props, pyramid, model, cfg, starts, 0.3, np.random.default_rng(1))
    again = mixture_proposals(state, props, pyramid, model, cfg, starts, 0.3, np.random.default_rng(1))
    assert np.array_equal(out.samples, again.samples) and np.array_equal(out.log_weights, again.log_weights)
    assert np.array_equal(out.samples[:, :7], props.samples[:, :7])  # round(0.3 * 10) = 3 drawn anew
    assert not np.allclose(out.samples[:, 7:], props.samples[:, 7:])
    assert np.isfinite(out.log_weights).all() and out.log_evidence.shape == (2,)
    # a detection this near settles on the expert's own peak: the mixture is the expert's own density and
    # the kept samples' weights stay (to round-off of the peak), though every one was divided anew
    assert np.allclose(out.log_weights[:, :7], props.log_weights[:, :7], atol=0.01)


def test_the_weights_are_corrected_for_the_mixture(seq) -> None:
    """Every sample's weight is p(u | u_{t-1}) p(y_t | u) over the mixture's density at u, whichever component
    drew it (ICONDENSATION), recomputed here from the densities themselves; and the expert's likelihood
    (eq. 19, the mean of its weights) estimates the same integral as the expert's own samples alone."""
    # one Gauss-Newton step: the detector's component stays near its place, apart from the expert's own
    model, cfg, state, props, pyramid, centres = _proposed(seq, 400, n_experts=1, gn_iterations=1)
    place = tuple(float(v) for v in centres[0] + (1.5, 1.0))
    starts = detector_starts(props.u_hat, centres, place)
    share = 0.25
    out = mixture_proposals(state, props, pyramid, model, cfg, starts, share, np.random.default_rng(3))
    det = detector_peaks(state, props, pyramid, model, cfg, starts)
    u = out.samples[0]
    prior = log_pose_prior(state.poses, out.samples, cfg.prior_std(model.n_bases),
                           math.radians(cfg.max_rotation_deg), cfg.scale_limits())[0]
    tv = TextureView(mean=state.tex_mean, var=state.tex_var + cfg.psi_v)
    lik = log_likelihood(model.bases, pyramid[0], out.samples, tv, cfg.sigma_w, None,
                         photometric=cfg.photometric_model(), outlier_sq=cfg.outlier_sigmas ** 2)[0]
    own = multivariate_normal(np.zeros(u.shape[1]), cfg.alpha * props.sigma_hat[0]).logpdf(box_minus(props.u_hat[0], u))
    at_det = multivariate_normal(np.zeros(u.shape[1]), cfg.alpha * np.linalg.inv(det.hessian[0])
                                 ).logpdf(box_minus(det.u_hat[0], u))
    q = np.logaddexp(math.log(1 - share) + own, math.log(share) + at_det)
    assert np.allclose(out.log_weights[0], prior + lik - q, atol=1e-6, rtol=0)
    # the detection drew where the expert's own samples are sparse: the components differ
    assert np.abs(own - at_det).max() > 5.0
    assert abs(out.log_evidence[0] - props.log_evidence[0]) < 0.1


def test_off_by_default_and_bad_settings_refused() -> None:
    assert GFlowParams().online_mix == 0.0
    for bad in ({"online_mix": -0.1}, {"online_mix": 1.5}, {"online_mix": math.nan},
                {"online_mix": 0.3, "background": True}):
        with pytest.raises(ValueError, match="online_mix") as e:
            GFlowParams(**bad)
        assert "\n" not in str(e.value)
