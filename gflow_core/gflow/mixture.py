"""A mixture proposal for G-flow's experts: the dynamics-driven pose opinion and a detector's
(``online_mix``, off by default).

A departure from Marks et al. (NIPS 2004), whose proposal for expert ``d`` is its pose opinion
alone, ``g(u | u_hat^(d), alpha Sigma_hat^(d))`` (sec. 3.2.2, eq. 16). Where a detector places the
target in frame t, ICONDENSATION (Isard & Blake, ECCV 1998, sec. 3) and the boosted particle filter
(Okuma et al., ECCV 2004, sec. 4) draw part of the samples from a density about the detection and
correct every sample's importance weight for the mixture it was drawn from:

    q^(d)(u) = (1 - a) g(u | u_hat^(d), alpha Sigma_hat^(d)) + a g(u | u_det^(d), alpha Sigma_det^(d))

    w(d, e) = p(u^(d,e) | u_{t-1}^(d)) p(y_t | u^(d,e), ...) / q^(d)(u^(d,e))        (eq. 16 with q)

Here the detector is the online model of the face (:mod:`.online_guard`, which lives in the filter
beside the weights): where it places the face on frame t, expert ``d``'s detector component is the
peak of the expert's own objective (eq. 14: its texels, its transition from ``u_{t-1}^(d)``) found by
coarse-to-fine Gauss-Newton from ``u_hat^(d)`` moved so that its box is centred at the model's place
(no translation search: the detector says where), and its Laplace covariance, as the lost guard's
:func:`.guard.settle` places a re-detected box. The last ``round(a s)`` of each expert's ``s`` samples
are drawn from that component instead (a fixed share of each: the deterministic mixture of Owen &
Zhou 2000, whose weights are those above with ``a`` the share drawn). The weights of the samples the
expert drew itself change only through ``q``; the likelihood (eq. 13, as :func:`.filter.propose`
computes it, tempered by ``data_temper``) and the transition density are evaluated at the new ones.
The expert's likelihood (eq. 19) is the mean of the corrected weights.

What it cannot do is make the likelihood prefer the face: it puts samples there, and the weights
(with ``online_cue``, the model's own likelihood besides) judge them. docs/gflow-development.md,
"A mixture proposal that draws from the online model", has the figures. Nothing here draws but from the generator it is given. No I/O.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .credibility import log_evidence
from .filter import (ExpertState, GFlowConfig, Proposals, _anchored_reset, _ro, _texture_view, _with_anchor,
                     vertex_visibility)
from .geometry import TRANS, box_minus, box_plus
from .head_model import MorphableModel
from .image import FrameData
from .pose_opinion import (GaussNewtonResult, RotationReset, TextureView, coarse_to_fine_peak,
                           log_importance_weights, log_likelihood, log_pose_prior, prior_mean)

__all__ = ["detector_starts", "detector_peaks", "mixture_proposals"]

_LOG_2PI = math.log(2.0 * math.pi)


def detector_starts(u_hat: np.ndarray, centres: np.ndarray, place: tuple[float, float]) -> np.ndarray:
    """Each expert's pose opinion ``u_hat`` (E, P) moved so that its box, centred at ``centres`` (E, 2)
    (x, y) px, is centred at the detector's ``place`` (x, y): the translation shifted by the difference
    (a box follows the translation one to one). Returns (E, P) float64."""
    out = np.array(u_hat, dtype=np.float64)
    out[:, TRANS] += np.asarray(place, dtype=np.float64)[None, :] - np.asarray(centres, dtype=np.float64)
    return out


def _log_gauss(centre: np.ndarray, hessian: np.ndarray, alpha: float, poses: np.ndarray) -> np.ndarray:
    """``log g(u | centre, alpha H^-1)`` of poses (E, s, P) about ``centre`` (E, P), ``H`` (E, P, P)
    (the tangent-space Gaussian of :func:`.pose_opinion.laplace_proposal`), (E, s)."""
    P = centre.shape[-1]
    d = box_minus(centre[:, None, :], poses)
    L = np.linalg.cholesky(hessian)
    # |L^T d|^2 = d^T H d
    z2 = np.sum(np.einsum("eij,esi->esj", L, d) ** 2, axis=-1) / alpha
    half_logdet = np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=-1)
    # log g = -P/2 log(2 pi alpha) + 1/2 log|H| - 1/2 d^T H d / alpha
    return -0.5 * P * (_LOG_2PI + math.log(alpha)) + half_logdet[:, None] - 0.5 * z2


def _weighing(state: ExpertState, proposals: Proposals, model: MorphableModel, cfg: GFlowConfig
              ) -> tuple[np.ndarray, np.ndarray, TextureView, RotationReset | None, float, tuple[float, float] | None]:
    """What expert d's weights need, as :func:`.filter.propose` has them: the transition's mean (E, P),
    the prior's std (P,), the predicted texels (the first look's for experts that took the frontal reset),
    the frontal reset, the rotation wall (radians) and the scale wall."""
    prior_std = cfg.prior_std(model.n_bases)
    prev = state.poses
    centre = prior_mean(prev, cfg.prior_rotation_decay, cfg.morph_shrink(model.n_bases))
    tv = _texture_view(state, np.arange(state.n_experts, dtype=np.int64), cfg, vertex_visibility(model, prev, cfg))
    reset = _anchored_reset(state, cfg)
    if proposals.reset.any() and reset is not None and reset.anchor_mean is not None:
        # experts that took the frontal reset are weighed with the first look's texels, as in propose
        tv = _with_anchor(tv, proposals.reset, reset)
    return centre, prior_std, tv, reset, math.radians(cfg.max_rotation_deg), cfg.scale_limits()


def detector_peaks(state: ExpertState, proposals: Proposals, pyramid: tuple[FrameData, ...], model: MorphableModel,
                   cfg: GFlowConfig, starts: np.ndarray) -> GaussNewtonResult:
    """Each expert's detector component: the peak ``u_det`` (E, P) of its own objective (eq. 14, its
    texels and transition from ``state`` at t - 1, over the ``proposals.dt`` periods) found by coarse-to-fine
    Gauss-Newton on ``pyramid`` (frame t's) from ``starts`` (E, P) without a translation search, and the
    Hessian there (``Sigma_det^-1``)."""
    cfg = cfg.at_pace(proposals.dt)
    centre, prior_std, tv, _, max_rot, scale = _weighing(state, proposals, model, cfg)
    return coarse_to_fine_peak(model.bases, pyramid, centre, tv, cfg.sigma_w, prior_std, cfg.gn_iterations,
                               start=np.asarray(starts, dtype=np.float64), use_background=False,
                               photometric=cfg.photometric_model(), offsets=None, max_rotation=max_rot,
                               outlier_sq=cfg.outlier_sigmas ** 2, scale=scale, temper=cfg.data_temper)


def mixture_proposals(state: ExpertState, proposals: Proposals, pyramid: tuple[FrameData, ...],
                      model: MorphableModel, cfg: GFlowConfig, starts: np.ndarray, share: float,
                      rng: np.random.Generator) -> Proposals:
    """``proposals`` (every expert's, from ``state`` at t - 1) with the last ``round(share s)`` samples of
    each expert drawn from its detector component about ``starts`` (E, P) (:func:`detector_starts`,
    :func:`detector_peaks`) and every weight corrected for the mixture (module docstring). ``pyramid``:
    frame t's (:func:`.image.frame_pyramid`). ``rng`` draws ``standard_normal((E, m, P))`` and nothing else.
    Returns ``proposals`` itself when no sample is to be drawn (``round(share s) == 0`` or ``alpha == 0``).
    Raises ValueError with the background model (the experts' backgrounds are not where the weights are).
    """
    E, s, P = proposals.samples.shape
    m = int(round(share * s))
    if m == 0 or cfg.alpha <= 0.0:
        return proposals
    if cfg.background:
        raise ValueError("online_mix needs background off: the experts' background textures are not kept where "
                         "the weights are corrected")
    det = detector_peaks(state, proposals, pyramid, model, cfg, starts)
    cfg = cfg.at_pace(proposals.dt)
    centre, prior_std, tv, reset, max_rot, scale = _weighing(state, proposals, model, cfg)
    L = np.linalg.cholesky(det.hessian)
    z = rng.standard_normal((E, m, P))
    # d = sqrt(alpha) L^-T z ~ N(0, alpha Sigma_det)
    d = np.linalg.solve(L.transpose(0, 2, 1)[:, None], z[..., None])[..., 0]
    new = box_plus(det.u_hat[:, None, :], np.sqrt(cfg.alpha) * d)
    # p(u | u_{t-1}) p(y_t | u, ...) of the new samples, as propose weighs its own (eq. 13, tempered)
    log_lik = log_likelihood(model.bases, pyramid[0], new, tv, cfg.sigma_w, None, photometric=cfg.photometric_model(),
                             outlier_sq=cfg.outlier_sigmas ** 2)
    if cfg.data_temper != 1.0:
        log_lik = log_lik / cfg.data_temper
    log_pl_new = log_pose_prior(centre, new, prior_std, max_rot, scale, reset) + log_lik
    samples = np.concatenate([proposals.samples[:, : s - m], new], axis=1)
    sigma_inv = np.linalg.inv(proposals.sigma_hat)
    log_own = _log_gauss(proposals.u_hat, 0.5 * (sigma_inv + sigma_inv.transpose(0, 2, 1)), cfg.alpha, samples)
    log_det = _log_gauss(det.u_hat, det.hessian, cfg.alpha, samples)
    # the kept samples' p(u | u_{t-1}) p(y_t | u): their weight times the expert's own g (eq. 16)
    log_pl = np.concatenate([proposals.log_weights[:, : s - m] + log_own[:, : s - m], log_pl_new], axis=1)
    a = m / s
    # q(u) = (1 - a) g(u | u_hat, alpha Sigma_hat) + a g(u | u_det, alpha Sigma_det)
    log_q = np.logaddexp(math.log1p(-a) + log_own, math.log(a) + log_det) if a < 1.0 else log_det
    # w = p(u | u_{t-1}) p(y_t | u) / q(u)                                 (eq. 16 with the mixture)
    log_w = log_importance_weights(log_pl, np.zeros_like(log_pl), log_q)
    return dataclasses.replace(proposals, samples=_ro(samples), log_weights=_ro(log_w),
                               log_evidence=_ro(log_evidence(log_w)))
