"""G-flow filter: one step is :func:`propose` (per expert) then :func:`update` (all experts).

The filtering distribution (eq. 5) is a weighted set of ``E`` experts. Each expert
holds a pose ``u_{t-1}`` and diagonal Gaussian texture opinions (sec. 3.1). A frame
is processed in two calls, both pure (they return new values and never modify their
inputs):

1. :func:`propose` -- for each expert independently: Gauss-Newton peak of its pose
   opinion (eq. 14), Laplace covariance, ``s`` samples, importance weights (eq. 16)
   and its likelihood estimate (eq. 19). It can be run on any subset of experts
   (``expert_indices``), e.g. in several processes: :func:`concatenate_proposals` of
   the shards is bit-for-bit the same as one call for all experts, provided each
   expert gets the same generator. Use :func:`expert_rngs`, which gives expert ``i``
   ``numpy.random.default_rng([seed, stream_hash, t, i])``.
2. :func:`update` -- credibilities (eq. 17, 19), resampling (sec. 3.4), posterior mean
   pose, and the Kalman update of each child's textures (eq. 7-10). Its randomness is
   the single generator passed in, e.g. ``numpy.random.default_rng([seed, stream_hash, t])``.

Frames are grey ``(H, W)`` float64 in ``[0, 1]`` (see :mod:`.image`); ``sigma_w``,
``Psi_v``, ``Psi_b`` and the texel variances are in those units squared.

Departures from the paper
-------------------------
* The state stores texture *posteriors* at ``t - 1``; the prediction (eq. 9, 10) is
  applied on the fly in :func:`propose` and again before the update in :func:`update`
  (the same arithmetic, so the two agree).
* ``resample_ess_fraction < 1`` resamples only when the ESS of the credibilities is
  below that fraction of ``E`` (otherwise each expert keeps its credibility as a
  weight and picks its own child pose). ``1.0`` resamples at every frame,
  as in sec. 3.4.
* Texels never observed get the finite variance ``unknown_var`` rather than infinity:
  object texels whose vertex is outside the first frame, and background texels under
  the object in the first frame (the object hides them). Object texels whose vertex
  projects outside the image are not updated (prediction only).
* Vertices outside the image sample the replicated border (see :mod:`.image`).
* Self-occlusion is not modelled (every vertex is assumed visible, as in the paper's
  one-to-one ``a_v``).
* Robustness options (off in the paper's settings, :data:`.params.PAPER`; on in the tracker's,
  :class:`.params.GFlowParams`): coarse-to-fine Gauss-Newton with a coarse translation
  search (``pyramid_levels``, ``search_radius``), a per-frame gain and bias in the texture
  observation (``photometric``; the texel Kalman update then observes ``(y - b) / a``), a
  soft wall on the rotation (``max_rotation_deg``) and an outlier process per vertex
  (``outlier_sigmas``; outlier texels are predicted, not updated, so an occluder is not
  learned). See :mod:`.pose_opinion` and :mod:`.photometric`.
* A step may span ``dt`` frame periods (a live source skips frames; the paper's frames are one
  period apart): :meth:`GFlowConfig.at_pace` composes ``dt`` one-period steps of the pose walk,
  the rotation decay, the texels' prediction and the frontal reset; :func:`propose` takes ``dt``
  and the :class:`Proposals` carry it to :func:`update`. ``dt = 1`` is the one-period model, bit
  for bit.
* ``scale_walk`` (:class:`.params.GFlowParams`, 0.01 by default, 0 in the paper's preset; the
  paper leaves the pose transition open, sec. 2): the scale ``c_1``'s walk is a fraction of the first box's ``|c_1|``
  a period instead of ``prior_std_coefficients``' absolute 0.2 (0.2-0.5 % of the nine shared
  sequences' first boxes, against the 1-3 % a period their size-varying boxes and david_indoor's
  landmarks change by); measured over ten seeds in docs/gflow-development.md, "The size's walk".
* ``texel_noise_adapt`` (off by default; measured not to help, docs/gflow-development.md): the texels'
  Kalman update (eq. 7, 8) observes the frame with each expert's moment estimate of the
  observation noise from its residuals, at least ``sigma_w``, instead of ``sigma_w`` itself.
* See also :mod:`.pose_opinion` (Gauss-Newton without the background term by
  default, safeguards, ``alpha = 0``), :mod:`.texture` (``object_mask="hull"`` with a
  margin) and :mod:`.credibility` (systematic resampling).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence, cast

import numpy as np

from .credibility import (
    ess,
    log_credibility,
    log_evidence,
    normalize_rows,
    pick_samples,
    pose_spread,
    posterior_mean_pose,
    resample_experts,
)
from .geometry import COEF, N_RIGID, ROT, TRANS, box_plus, project, rotation_matrices
from .head_model import MorphableModel, bounding_box
from .image import FrameData, bilinear_stencil, frame_pyramid, prepare_frame, validate_frame
from .photometric import Photometric, correct, gain_bias
from .pose_opinion import (
    GaussNewtonResult,
    TextureView,
    background_image_terms,
    coarse_to_fine_peak,
    gauss_newton_peak,
    search_offsets,
    laplace_proposal,
    log_importance_weights,
    log_likelihood,
    log_pose_prior,
    prior_mean,
    RotationReset,
)
from .background import TiledBackground, TiledTexels
from .texture import anchored_predict, kalman_update, object_mask
from .visibility import vertex_normals, visibility_weights

__all__ = [
    "GFlowConfig",
    "ExpertState",
    "Proposals",
    "Estimate",
    "expert_rngs",
    "init_state",
    "propose",
    "concatenate_proposals",
    "update",
    "step",
]


def _ro(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _as_std_tuple(name: str, v, n: int | None) -> tuple[float, ...]:
    t = tuple(float(x) for x in np.atleast_1d(np.asarray(v, dtype=np.float64)))
    if n is not None and len(t) not in (1, n):
        raise ValueError(f"{name} must be one number or {n} numbers, got {len(t)}")
    for x in t:
        if math.isnan(x) or x <= 0.0:
            raise ValueError(f"{name} must be positive (inf = uninformative), got {v!r}")
    return t


@dataclass(frozen=True, kw_only=True)
class GFlowConfig:
    """Parameters of the G-flow filter (no seed: randomness is passed in).

    Made by :meth:`.params.GFlowParams.config`, where the defaults live (the shipped tracker's;
    :func:`.params.paper_config` gives the paper's filter).

    Attributes
    ----------
    n_experts : int
        Number of experts ``E``.
    n_samples : int
        Samples ``s`` per expert's pose opinion (sec. 3.2.2).
    alpha : float
        Proposal sharpness ``alpha >= 0`` (``g(. | u_hat, alpha Sigma_hat)``).
    gn_iterations : int
        Gauss-Newton steps per frame (>= 0).
    sigma_w : float
        Observation noise variance ``sigma_w > 0`` (eq. 4).
    psi_v, psi_b : float
        Object / background texel process noise variances ``Psi_v``, ``Psi_b`` (eq. 4),
        finite, ``>= 0``.
    v_init_var : float
        ``Var(V_1) = kappa I`` (``>= 0``; ``0`` = known template).
    b_init_var : float
        ``Var(B_1)`` of background pixels visible in the first frame (``>= 0``).
    unknown_var : float
        Variance of texels not observed at initialisation (> 0, finite).
    background : bool
        Use the background texture model. False = uninformative background (the
        background terms are dropped), as in the paper's experiments (sec. 5).
    gn_background : bool
        Gauss-Newton includes the first background term of eq. 14, as in the paper
        (sec. 3.2.2). False: foreground and prior only; see :mod:`.pose_opinion`.
    object_mask : {"hull", "vertices"}
        Pixels rendered by the object, excluded from the background update (:mod:`.texture`).
    object_mask_margin : float
        With ``"hull"``: the hull is enlarged by this fraction about its centre, so that
        object pixels outside the mesh's vertices (e.g. the rim of a head whose mesh
        covers only its front) and the object's edge under a slightly wrong pose are
        not learned as background (see :mod:`.texture`).
    prior_std_rotation : float or (3,)
        Std of the pose random walk per frame, rotation (radians, body frame).
    prior_std_translation : float or (2,)
        Translation (pixels).
    prior_std_coefficients : float or (k,)
        Morph coefficients (their units: pixels per model unit). ``inf`` anywhere =
        uninformative component.
    prior_rotation_decay : float in (0, 1]
        ``a`` of the pose prior's mean: the rotation of ``u_{t-1}`` shrunk toward the
        identity, ``exp(a log r_{t-1})`` (:func:`.pose_opinion.prior_mean`); ``1`` = a pure
        random walk (the paper).
    resample_ess_fraction : float in (0, 1]
        Resample experts when ESS < fraction * E; ``1`` = every frame (sec. 3.4).
    pyramid_levels : int >= 1
        Levels of the image pyramid for coarse-to-fine Gauss-Newton
        (:func:`.pose_opinion.coarse_to_fine_peak`); ``1`` = the paper's single scale.
    search_radius, search_step : float
        Pixels. On the coarsest level each expert first tries its previous pose translated
        on a grid ``{-radius .. radius}^2`` with spacing ``step`` and starts Gauss-Newton at the
        best (:func:`.pose_opinion.search_offsets`); ``radius 0`` = no search.
    photometric : bool
        Fit a gain and bias per expert, pose and frame and observe the texels through
        ``(y - b) / a`` (:mod:`.photometric`); False = the paper's ``y = v + w``.
    photometric_gain_max : float > 1
        The gain is clamped to ``[1 / max, max]``.
    max_rotation_deg : float
        Soft wall on the rotation angle from the initial orientation
        (:func:`.pose_opinion.rotation_wall`), part of the pose prior; ``inf`` = none (paper).
    search_stride : int >= 1
        The search evaluates every ``search_stride``-th vertex.
    outlier_sigmas : float > 0
        ``tau``: a vertex whose residual exceeds ``tau`` standard deviations is an outlier
        (:func:`.pose_opinion.robust_cost`): capped cost in Gauss-Newton and the likelihood, and
        its texel is not updated (prediction only), so an occluder is not learned into the
        texture. ``inf`` = the paper's Gaussian.
    max_scale_change : float > 1
        Soft wall on the scale ``|c|`` outside ``[|c_0| / max, |c_0| max]``
        (:func:`.pose_opinion.scale_wall`); ``inf`` = none (the paper).
    scale_reference : tuple of float
        ``c_0``, the initial morph coefficients, needed by ``max_scale_change`` (the G-flow
        stages set it from the initial box; empty = no wall).
    morph_prior_std : tuple of float
        Standard deviations ``m_j`` (one, or ``k - 1``) of a stationary Gaussian factor
        ``N(c_j; 0, m_j^2)`` on the morph coefficients ``c_2 .. c_k`` in the pose prior, so that
        expressions stay within what the model was learned from (:meth:`morph_shrink`); empty
        or ``inf`` = none (the paper's prior is left open, sec. 2). The G-flow stages set it
        from a learned model's ``morph_std``.
    texture_decay : float in (0, 1]
        ``a``: the object texels revert toward the first frame's look, ``V_t - v_1 = a (V_{t-1} - v_1) +
        Z`` (:func:`.texture.anchored_predict`); ``1`` = the paper's random walk.
    reset_rate, reset_std_deg, reset_min_deg : float
        The pose transition's rotation is a mixture: the random walk with probability ``1 - reset_rate``,
        a Gaussian of std ``reset_std_deg`` about the frontal orientation with probability ``reset_rate``;
        experts turned by at least ``reset_min_deg`` also try a peak started frontal
        (:class:`.pose_opinion.RotationReset`). ``reset_rate = 0`` = the random walk alone (the paper).
    data_temper : float >= 1
        ``kappa``: the data term's log-likelihood is divided by it in the pose opinion (eq. 14) and
        the importance weights (eq. 13, 16), a composite likelihood for residuals that are not
        independent (:mod:`.pose_opinion`); ``1`` = the paper's (the default; measured not to help,
        docs/gflow-development.md).
    generic_background : bool
        The object's data term is weighed against a generic background at the vertices (eq. 14's first
        background term with one Gaussian, the frame's mean and variance, for every pixel:
        :func:`.pose_opinion.generic_background`), in the search, Gauss-Newton and the weights (eq. 13,
        16). False: the paper's uninformative background (without ``background``).
    texel_noise_adapt : bool
        The object texels' Kalman update (eq. 7, 8) of each expert observes the frame with the noise
        its fit shows, ``max(sigma_w, mean_i((y_i - mu_i)^2 - sigma_i))`` over its inlier vertices
        (the moment estimate of the observation noise from the innovations), so texels are learned
        less at a pose the frame fits poorly. False: ``sigma_w`` (the paper's).
    local_background : float
        > 0: the object's data term is weighed against a local background at the vertices (eq. 14's
        two background terms with each pixel's Gaussian the frame's mean and variance in a Gaussian
        window of this std, pixels, about it: :func:`.pose_opinion.local_background`), in the chains'
        comparison and the weights (eq. 13, 16); not in Gauss-Newton nor the coarse search. 0: none
        (the paper's uninformative background, without ``background``). Not with ``generic_background``.
    self_occlusion : float in [0, 1]
        > 0: ``c0`` of the vertices' visibility (:mod:`.visibility`): a vertex whose normal, rotated
        with the head, faces the camera with a cosine below ``c0`` counts as partly hidden by the head
        itself (weight ``cos / c0``, none at or past edge-on): its texture term in the search,
        Gauss-Newton and the weights (eq. 13, 14, 16) is weighted by it at the expert's previous pose,
        and its texel's update (eq. 7, 8) at the new pose. 0: every vertex visible (the paper's).
    """

    n_experts: int
    n_samples: int
    alpha: float
    gn_iterations: int
    sigma_w: float
    psi_v: float
    psi_b: float
    v_init_var: float
    b_init_var: float
    unknown_var: float
    background: bool
    gn_background: bool
    object_mask: str
    object_mask_margin: float
    prior_std_rotation: float | tuple[float, ...]
    prior_std_translation: float | tuple[float, ...]
    prior_std_coefficients: float | tuple[float, ...]
    resample_ess_fraction: float
    prior_rotation_decay: float
    pyramid_levels: int
    search_radius: float
    search_step: float
    photometric: bool
    photometric_gain_max: float
    max_rotation_deg: float
    search_stride: int
    outlier_sigmas: float
    max_scale_change: float
    scale_reference: tuple[float, ...]
    morph_prior_std: tuple[float, ...]
    texture_decay: float
    reset_rate: float
    reset_std_deg: float
    reset_min_deg: float
    data_temper: float = 1.0
    generic_background: bool = False
    texel_noise_adapt: bool = False
    local_background: float = 0.0
    self_occlusion: float = 0.0

    def __post_init__(self) -> None:
        for nm in ("n_experts", "n_samples"):
            v = getattr(self, nm)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{nm} must be an integer >= 1, got {v!r}")
        v = self.gn_iterations
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"gn_iterations must be an integer >= 0, got {v!r}")
        if not (math.isfinite(self.alpha) and self.alpha >= 0.0):
            raise ValueError(f"alpha must be finite and >= 0, got {self.alpha!r}")
        if not (math.isfinite(self.sigma_w) and self.sigma_w > 0.0):
            raise ValueError(f"sigma_w must be finite and > 0, got {self.sigma_w!r}")
        for nm in ("psi_v", "psi_b", "v_init_var", "b_init_var"):
            v = getattr(self, nm)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{nm} must be finite and >= 0, got {v!r}")
        if not (math.isfinite(self.unknown_var) and self.unknown_var > 0.0):
            raise ValueError(f"unknown_var must be finite and > 0, got {self.unknown_var!r}")
        if not isinstance(self.background, (bool, np.bool_)):
            raise ValueError(f"background must be True or False, got {self.background!r}")
        if not isinstance(self.gn_background, (bool, np.bool_)):
            raise ValueError(f"gn_background must be True or False, got {self.gn_background!r}")
        if self.object_mask not in ("hull", "vertices"):
            raise ValueError(f"object_mask must be 'hull' or 'vertices', got {self.object_mask!r}")
        if not (math.isfinite(self.object_mask_margin) and self.object_mask_margin >= 0.0):
            raise ValueError(f"object_mask_margin must be finite and >= 0, got {self.object_mask_margin!r}")
        if not (0.0 < self.prior_rotation_decay <= 1.0):
            raise ValueError(f"prior_rotation_decay must be in (0, 1], got {self.prior_rotation_decay!r}")
        v = self.pyramid_levels
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 6:
            raise ValueError(f"pyramid_levels must be an integer in [1, 6], got {v!r}")
        if not (math.isfinite(self.search_radius) and self.search_radius >= 0.0):
            raise ValueError(f"search_radius must be finite and >= 0, got {self.search_radius!r}")
        if not (math.isfinite(self.search_step) and self.search_step > 0.0):
            raise ValueError(f"search_step must be finite and > 0, got {self.search_step!r}")
        if self.search_radius / self.search_step > 20:
            raise ValueError(f"search_radius / search_step must be <= 20 (at most 41 x 41 starts), got "
                             f"{self.search_radius!r} / {self.search_step!r}")
        if not isinstance(self.photometric, (bool, np.bool_)):
            raise ValueError(f"photometric must be True or False, got {self.photometric!r}")
        if not (math.isfinite(self.photometric_gain_max) and self.photometric_gain_max > 1.0):
            raise ValueError(f"photometric_gain_max must be finite and > 1, got {self.photometric_gain_max!r}")
        if math.isnan(self.max_rotation_deg) or self.max_rotation_deg <= 0.0:
            raise ValueError(f"max_rotation_deg must be > 0 (inf = no limit), got {self.max_rotation_deg!r}")
        if math.isnan(self.outlier_sigmas) or self.outlier_sigmas <= 0.0:
            raise ValueError(f"outlier_sigmas must be > 0 (inf = no outlier process), got {self.outlier_sigmas!r}")
        if not (math.isfinite(self.data_temper) and self.data_temper >= 1.0):
            raise ValueError(f"data_temper must be finite and >= 1, got {self.data_temper!r}")
        if math.isnan(self.max_scale_change) or self.max_scale_change <= 1.0:
            raise ValueError(f"max_scale_change must be > 1 (inf = no limit), got {self.max_scale_change!r}")
        ref = tuple(float(x) for x in self.scale_reference)
        if ref and not (all(math.isfinite(x) for x in ref) and math.hypot(*ref) > 0.0):
            raise ValueError(f"scale_reference must be finite and not all zero, got {self.scale_reference!r}")
        object.__setattr__(self, "scale_reference", ref)
        object.__setattr__(self, "morph_prior_std", _as_std_tuple("morph_prior_std", self.morph_prior_std, None)
                           if len(self.morph_prior_std) else ())
        v = self.search_stride
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"search_stride must be an integer >= 1, got {v!r}")
        if not (0.0 <= self.reset_rate < 1.0):
            raise ValueError(f"reset_rate must be in [0, 1), got {self.reset_rate!r}")
        for nm in ("reset_std_deg", "reset_min_deg"):
            v = getattr(self, nm)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{nm} must be finite and > 0, got {v!r}")
        if self.reset_rate > 0 and not all(math.isfinite(v) for v in _as_std_tuple(
                "prior_std_rotation", self.prior_std_rotation, 3)):
            raise ValueError("reset_rate > 0 needs a finite prior_std_rotation (the walk it mixes with)")
        if not isinstance(self.generic_background, (bool, np.bool_)):
            raise ValueError(f"generic_background must be True or False, got {self.generic_background!r}")
        lb = self.local_background
        if isinstance(lb, bool) or not isinstance(lb, (int, float, np.floating, np.integer)) or not (
                math.isfinite(lb) and lb >= 0):
            raise ValueError(f"local_background must be a window std in pixels >= 0 (0: none), got {lb!r}")
        if lb > 0 and self.generic_background:
            raise ValueError("local_background and generic_background are two models of the same background: "
                             "set one")
        so = self.self_occlusion
        if isinstance(so, bool) or not isinstance(so, (int, float, np.floating, np.integer)) or not 0 <= so <= 1:
            raise ValueError(f"self_occlusion must be a cosine in [0, 1] (0: every vertex visible), got {so!r}")
        if not isinstance(self.texel_noise_adapt, (bool, np.bool_)):
            raise ValueError(f"texel_noise_adapt must be True or False, got {self.texel_noise_adapt!r}")
        if not (0.0 < self.texture_decay <= 1.0):
            raise ValueError(f"texture_decay must be in (0, 1], got {self.texture_decay!r}")
        if not (0.0 < self.resample_ess_fraction <= 1.0):
            raise ValueError(f"resample_ess_fraction must be in (0, 1], got {self.resample_ess_fraction!r}")
        object.__setattr__(
            self, "prior_std_rotation", _as_std_tuple("prior_std_rotation", self.prior_std_rotation, 3)
        )
        object.__setattr__(
            self, "prior_std_translation", _as_std_tuple("prior_std_translation", self.prior_std_translation, 2)
        )
        object.__setattr__(
            self, "prior_std_coefficients", _as_std_tuple("prior_std_coefficients", self.prior_std_coefficients, None)
        )

    def at_pace(self, dt: float) -> GFlowConfig:
        """The configuration of one step that spans ``dt`` frame periods (a live source skips frames).

        Every per-frame setting of the models is that of ``dt`` frames composed (``dt = 1``: ``self``,
        the same bits):

        * the pose random walk (eq. 4's ``u_t = u_{t-1} + noise``, sec. 2 leaves it open) over ``dt``
          periods: its standard deviations times ``sqrt(dt)`` (the scale ``c_1``'s too, also when
          :class:`.params.GFlowParams` ``scale_walk`` made it relative to the first box's face: the
          face's log size on david_indoor's reference landmarks changes by 1.9 % RMS over one frame
          and 3.3 % over three, about ``sqrt(3)`` times; ``bench/bench_gflow_pace.py --rates``);
        * the prior mean's rotation decay ``a`` (:func:`.pose_opinion.prior_mean`): ``a^dt``;
        * the object texels (eq. 4's ``V_t = V_{t-1} + Z``; with ``texture_decay = a < 1`` the AR(1)
          process of :func:`.texture.anchored_predict`): ``a^dt`` and
          ``Var(Z) = Psi_v (1 - a^(2 dt)) / (1 - a^2)`` (``Psi_v dt`` when ``a = 1``);
        * the frontal reset's probability ``r`` (:class:`.pose_opinion.RotationReset`): ``1 - (1 - r)^dt``.

        With a morph prior the coefficients' AR(1) mean and spread follow from the walk's widened
        standard deviation (:meth:`morph_shrink`): ``a' = 1 / (1 + dt std^2 / m^2)``, to first order
        ``a^dt``, with the same stationary spread. The background texels (``Psi_b``), kept per frame
        seen by each proposal stage's replica, are not changed, nor is the translation search
        (``search_radius``): its 32 px are 3.7 standard deviations of the walk over 3 periods, and a
        search grown as the walk's spread (times ``sqrt(dt)``) lost the face more often on david_indoor
        played at every 3rd frame (landmark NME 0.178 against 0.136, mean of seeds 1-3). The head's
        motion keeps its velocity for a few periods (david_indoor's reference landmarks move 2.7 times
        as far over three frames as over one, not ``sqrt(3)`` times), but a walk grown as such a motion's
        (an integrated Ornstein-Uhlenbeck velocity of correlation time 1 or 3 periods: ``2.4`` or ``2.7``
        times a period's std over 3 periods) lost the face more often there too (mean NME of seeds 1-3 0.196 and 0.162; docs/gflow-development.md): the
        wider translation walk makes the clutter beside the face cheaper at the head's turn.

        Raises ``ValueError`` unless ``dt`` is finite and ``>= 1``.
        """
        if not (math.isfinite(dt) and dt >= 1.0):
            raise ValueError(f"dt must be finite and >= 1 frame period, got {dt!r}")
        if dt == 1.0:
            return self
        s = math.sqrt(dt)

        def walk(v: float | tuple[float, ...]) -> tuple[float, ...]:
            # std over dt periods of a random walk: sqrt(dt) std  (inf stays inf)
            return tuple(x * s for x in cast("tuple[float, ...]", v))

        a = self.texture_decay
        # Var(V_{t+dt} - a^dt V_t) = Psi_v (1 + a^2 + ... + a^(2 (dt - 1)))
        psi_v = self.psi_v * dt if a == 1.0 else self.psi_v * (1.0 - a ** (2.0 * dt)) / (1.0 - a * a)
        return dataclasses.replace(
            self, prior_std_rotation=walk(self.prior_std_rotation),
            prior_std_translation=walk(self.prior_std_translation),
            prior_std_coefficients=walk(self.prior_std_coefficients),
            prior_rotation_decay=self.prior_rotation_decay ** dt, texture_decay=a ** dt, psi_v=psi_v,
            reset_rate=1.0 - (1.0 - self.reset_rate) ** dt)

    def scale_limits(self) -> tuple[float, float] | None:
        """``(|c_0|, log max_scale_change)`` for :func:`.pose_opinion.scale_wall`, or None."""
        if not (math.isfinite(self.max_scale_change) and self.scale_reference):
            return None
        return math.hypot(*self.scale_reference), math.log(self.max_scale_change)

    def rotation_reset(self) -> RotationReset | None:
        """The mixture transition of the rotation (:class:`.pose_opinion.RotationReset`), or None."""
        if self.reset_rate == 0.0:
            return None
        return RotationReset(rate=self.reset_rate, std=math.radians(self.reset_std_deg),
                             min_angle=math.radians(self.reset_min_deg),
                             walk_std=np.broadcast_to(np.asarray(self.prior_std_rotation, dtype=np.float64), (3,)))

    def photometric_model(self) -> Photometric | None:
        """The gain/bias settings, or None when ``photometric`` is off."""
        return Photometric(gain_max=self.photometric_gain_max) if self.photometric else None

    def prior_std(self, k: int) -> np.ndarray:
        """Standard deviations ``(5 + k,)`` of the pose transition in the pose vector layout: the
        random walk's, and for ``c_2 .. c_k`` with a morph prior ``1 / sqrt(1/std^2 + 1/m^2)``
        (:meth:`morph_shrink`)."""
        c = cast("tuple[float, ...]", self.prior_std_coefficients)  # a tuple after __post_init__
        if len(c) not in (1, k):
            raise ValueError(f"prior_std_coefficients has {len(c)} values but the model has k={k} morph bases")
        out = np.empty(5 + k)
        out[ROT] = self.prior_std_rotation
        out[TRANS] = self.prior_std_translation
        out[COEF] = c
        lam, kap = self._morph_precisions(k)
        if kap is not None:
            # N(c; c', std^2) N(c; 0, m^2) has precision 1/std^2 + 1/m^2
            out[N_RIGID + 1:] = 1.0 / np.sqrt(lam + kap)
        return out

    def _morph_precisions(self, k: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Random-walk and morph-prior precisions of ``c_2 .. c_k`` (None: no morph prior)."""
        m = self.morph_prior_std
        if not m or k < 2:
            return np.zeros(max(k - 1, 0)), None
        if len(m) not in (1, k - 1):
            raise ValueError(f"morph_prior_std has {len(m)} values but the model has k - 1 = {k - 1} morphs")
        c = np.broadcast_to(np.asarray(self.prior_std_coefficients, dtype=np.float64), (k,))[1:]
        lam = np.where(np.isinf(c), 0.0, 1.0 / np.where(np.isinf(c), 1.0, c) ** 2)
        mm = np.broadcast_to(np.asarray(m, dtype=np.float64), (k - 1,))
        kap = np.where(np.isinf(mm), 0.0, 1.0 / np.where(np.isinf(mm), 1.0, mm) ** 2)
        if ((lam + kap) <= 0).any():
            raise ValueError("a morph coefficient has neither a finite random walk nor a finite morph prior")
        return lam, kap

    def morph_shrink(self, k: int) -> np.ndarray | None:
        """Factors ``a (k,)`` of the transition's mean ``a * c_{t-1}`` (None: all 1, no morph prior).

        The random walk ``N(c_t; c_{t-1}, std^2)`` times the stationary factor ``N(c_t; 0, m^2)``,
        normalised over ``c_t``, is ``N(c_t; a c_{t-1}, 1 / (1/std^2 + 1/m^2))`` with
        ``a = (1/std^2) / (1/std^2 + 1/m^2)``: an AR(1) process on each morph coefficient (``a = 1``
        for ``c_1``, the scale). Its stationary spread is about ``m / sqrt(2)`` when ``m >> std``.
        """
        lam, kap = self._morph_precisions(k)
        if kap is None:
            return None
        return np.concatenate([[1.0], lam / (lam + kap)])


@dataclass(frozen=True)
class ExpertState:
    """The experts at time ``t - 1`` (read-only arrays).

    Attributes
    ----------
    poses : (E, P) float64
        ``u_{t-1}`` of each expert (layout in :mod:`.geometry`).
    tex_mean, tex_var : (E, n) float64
        Object texel posterior means and variances (eq. 7, 8).
    bg_mean, bg_var : (E, H, W) float64 or None
        Background texel posteriors; None for an uninformative background. Made by
        :func:`init_state` / :func:`update` as :class:`.background.TiledTexels` (each distinct
        16 x 16 tile stored once, ``np.asarray`` gives the dense array); plain arrays are
        accepted too.
    log_credibility : (E,) float64
        Normalised log credibilities (uniform after resampling).
    image_shape : (H, W)
    tex_anchor : (n,) float64 or None
        The first frame's texels at the initial pose, toward which the texels revert when
        ``GFlowConfig.texture_decay < 1`` (:func:`.texture.anchored_predict`).
    """

    poses: np.ndarray
    tex_mean: np.ndarray
    tex_var: np.ndarray
    bg_mean: np.ndarray | TiledTexels | None
    bg_var: np.ndarray | TiledTexels | None
    log_credibility: np.ndarray
    image_shape: tuple[int, int]
    tex_anchor: np.ndarray | None = None

    @property
    def n_experts(self) -> int:
        return self.poses.shape[0]

    def check(self, model: MorphableModel) -> None:
        """Raise ValueError if the state does not fit ``model``."""
        E, P = self.poses.shape
        if P != model.pose_size:
            raise ValueError(f"state poses have P={P} but the model needs P={model.pose_size}")
        if self.tex_mean.shape != (E, model.n_vertices) or self.tex_var.shape != (E, model.n_vertices):
            raise ValueError(
                f"state textures have shape {self.tex_mean.shape} but the model has n={model.n_vertices} vertices"
            )


@dataclass(frozen=True)
class Proposals:
    """Pose opinions of a set of experts (sec. 3.2) and their likelihoods (eq. 19).

    Attributes
    ----------
    expert_indices : (E',) int64
    u_hat : (E', P) float64
        Peak of the pose opinion (eq. 14).
    sigma_hat : (E', P, P) float64
        Laplace covariance (tangent space at ``u_hat``).
    samples : (E', s, P) float64
        ``u^(d,e)`` drawn from ``N(u_hat, alpha Sigma_hat)``.
    log_weights : (E', s) float64
        ``log w_t(d, e)`` (eq. 16).
    log_evidence : (E',) float64
        ``log p(y_t | u_{1:t-1}^(d), y_{1:t-1})`` estimated by eq. 19.
    gn_objective : (E',) float64
        Gauss-Newton objective at ``u_hat`` (diagnostic).
    reset : (E',) bool
        Experts whose peak is the frontal reset's and whose texture restarts from the first look
        (:class:`.pose_opinion.RotationReset`; all False without ``reset_rate``).
    dt : float
        Frame periods the step spans (:meth:`GFlowConfig.at_pace`); :func:`update` predicts the
        texels over the same periods.
    """

    expert_indices: np.ndarray
    u_hat: np.ndarray
    sigma_hat: np.ndarray
    samples: np.ndarray
    log_weights: np.ndarray
    log_evidence: np.ndarray
    gn_objective: np.ndarray
    reset: np.ndarray
    dt: float = 1.0


@dataclass(frozen=True)
class Estimate:
    """What the filter reports for frame ``t``.

    Attributes
    ----------
    pose : (P,) float64
        Posterior mean pose: the importance-weighted mean over every expert's samples,
        weighted by credibility (eq. 5, 15); chordal mean for the rotation.
    rotation : (3, 3) float64
        Its rotation matrix.
    pose_std : (P,) float64
        Posterior standard deviation in the tangent space at ``pose``.
    spread_px : float
        RMS distance (pixels) of the experts' projected vertices from those of ``pose``.
    ess : float
        Effective sample size of the credibilities, before resampling.
    expert_points : (E, n, 2) float64
        Projected vertices of every expert after the update (figure 2).
    mean_points : (n, 2) float64
        Projected vertices of ``pose``.
    bbox : (4,) float64
        ``(x, y, w, h)`` of ``mean_points``.
    log_credibility : (E,) float64
        Normalised log credibility of each (parent) expert (eq. 17).
    parents : (E,) int64
        Parent of each new expert.
    resampled : bool
    inlier_fraction : float
        Credibility-weighted mean over the new experts and the vertices of the probability that the
        vertex shows the object rather than an outlier, ``1 / (1 + exp((e^2 - tau^2) / 2))`` with ``e``
        its standardised residual (eq. 13) and ``tau`` = ``outlier_sigmas`` (3 if infinite): the
        outlier process of the likelihood, whose density is the object's at ``tau`` standard
        deviations (0 for a vertex outside the image).
    inlier_count : float
        The hard count of the same test: the credibility-weighted fraction of the vertices in the
        image and within ``tau`` standard deviations of their texel (those whose probability is
        above one half).
    """

    pose: np.ndarray
    rotation: np.ndarray
    pose_std: np.ndarray
    spread_px: float
    ess: float
    expert_points: np.ndarray
    mean_points: np.ndarray
    bbox: np.ndarray
    log_credibility: np.ndarray
    parents: np.ndarray
    resampled: bool
    inlier_fraction: float = 1.0
    inlier_count: float = 1.0


def expert_rngs(seed: int, stream_hash: int, t: int, indices: Sequence[int]) -> list[np.random.Generator]:
    """Per-expert generators ``numpy.random.default_rng([seed, stream_hash, t, i])``.

    All four numbers must be non-negative integers.
    """
    return [np.random.default_rng([int(seed), int(stream_hash), int(t), int(i)]) for i in indices]


def init_state(
    model: MorphableModel,
    pose0: np.ndarray,
    frame: np.ndarray,
    cfg: GFlowConfig,
    *,
    rng: np.random.Generator | None = None,
    pose_jitter_std: np.ndarray | float | None = None,
) -> ExpertState:
    """Experts at the first frame: poses near ``pose0``, textures from the frame.

    Object texels start at the frame sampled at each expert's projected vertices with
    variance ``v_init_var`` (``Var(V_1) = kappa I``); the background starts at the frame
    with variance ``b_init_var``, except under the object (``unknown_var``).

    Parameters
    ----------
    model : MorphableModel
    pose0 : (P,) float64
    frame : (H, W) float64 in [0, 1]
    cfg : GFlowConfig
    rng : numpy.random.Generator, optional
        Needed with ``pose_jitter_std``: one ``standard_normal((E, P))`` draw.
    pose_jitter_std : float or (P,), optional
        Experts start at ``pose0 [+] N(0, diag(std^2))`` (the paper initialises them
        "randomly near the correct pose"); None = all at ``pose0``.

    Returns
    -------
    ExpertState
    """
    img = validate_frame(frame)
    u0 = model.check_poses(pose0, "pose0")
    if u0.shape != (model.pose_size,):
        raise ValueError(f"pose0 must have shape ({model.pose_size},), got {u0.shape}")
    E, P = cfg.n_experts, model.pose_size
    cfg.prior_std(model.n_bases)  # validates the coefficient stds against k
    poses = np.tile(u0, (E, 1))
    if pose_jitter_std is not None:
        std = np.broadcast_to(np.asarray(pose_jitter_std, dtype=np.float64), (P,))
        if not np.isfinite(std).all() or (std < 0).any():
            raise ValueError(f"pose_jitter_std must be finite and >= 0, got {pose_jitter_std!r}")
        if rng is None:
            raise ValueError("pose_jitter_std needs an rng")
        poses = box_plus(poses, rng.standard_normal((E, P)) * std)
    pts = project(model.bases, poses)
    st = bilinear_stencil(pts, img.shape)
    y = st.sample(img.reshape(-1))
    tex_mean = np.where(st.inside, y, 0.5)
    tex_var = np.where(st.inside, cfg.v_init_var, cfg.unknown_var)
    bg_mean = bg_var = None
    if cfg.background:
        bg_mean, bg_var = initial_background(model, poses, img, cfg)
    return ExpertState(
        poses=_ro(poses),
        tex_mean=_ro(tex_mean),
        tex_var=_ro(tex_var),
        bg_mean=bg_mean,
        bg_var=bg_var,
        log_credibility=_ro(np.full(E, -np.log(E))),
        image_shape=(int(img.shape[0]), int(img.shape[1])),
        tex_anchor=None if cfg.texture_decay == 1.0 else _ro(texture_anchor(model, u0, img)),
    )


def texture_anchor(model: MorphableModel, pose0: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """The first frame's texels at the initial pose ``v_1`` (n,): the frame at the projected vertices
    (0.5 where a vertex is outside the image); the anchor of :func:`.texture.anchored_predict`."""
    st = bilinear_stencil(project(model.bases, np.asarray(pose0, dtype=np.float64)), frame.shape)
    return np.where(st.inside, st.sample(np.ascontiguousarray(frame, dtype=np.float64).reshape(-1)), 0.5)


def predict_texels(state: ExpertState, rows: np.ndarray, cfg: GFlowConfig) -> tuple[np.ndarray, np.ndarray]:
    """Predicted object texels (eq. 9, 10; with ``texture_decay < 1`` :func:`.texture.anchored_predict`) of the
    experts ``rows``: means and variances ``(len(rows), n)``."""
    return anchored_predict(state.tex_mean[rows], state.tex_var[rows], cfg.psi_v, cfg.texture_decay,
                            state.tex_anchor)


def vertex_visibility(model: MorphableModel, poses: np.ndarray, cfg: GFlowConfig) -> np.ndarray | None:
    """Each vertex's visibility weight ``(..., n)`` at poses ``(..., P)`` (:mod:`.visibility`); None with
    ``self_occlusion`` 0 (every vertex visible)."""
    if cfg.self_occlusion <= 0:
        return None
    return visibility_weights(vertex_normals(model.bases), poses, float(cfg.self_occlusion))


def _texture_view(state: ExpertState, idx: np.ndarray, cfg: GFlowConfig, vis: np.ndarray | None = None
                  ) -> TextureView:
    # predicted texture (eq. 9, 10): mean unchanged, variance + Psi (or reverting toward the first look)
    mean, var = predict_texels(state, idx, cfg)
    return TextureView(
        mean=mean,
        var=var,
        bg_mean=state.bg_mean,
        bg_var=state.bg_var,
        bg_rows=idx if state.bg_mean is not None else None,
        psi_b=cfg.psi_b,
        generic=bool(cfg.generic_background),
        local=float(cfg.local_background),
        vis=vis,
    )


def propose(
    state: ExpertState,
    frame: np.ndarray,
    model: MorphableModel,
    cfg: GFlowConfig,
    rngs: Sequence[np.random.Generator],
    expert_indices: Sequence[int] | np.ndarray | None = None,
    dt: float = 1.0,
    pyramid: Sequence[FrameData] | None = None,
) -> Proposals:
    """Pose opinions (sec. 3.2) and likelihoods (eq. 19) of some or all experts.

    Parameters
    ----------
    state : ExpertState
        Experts at ``t - 1``.
    frame : (H, W) float64 in [0, 1]
        ``y_t``.
    model : MorphableModel
    cfg : GFlowConfig
    rngs : sequence of numpy.random.Generator
        One per proposed expert, in the order of ``expert_indices`` (see
        :func:`expert_rngs`); expert ``i`` draws ``standard_normal((s, P))`` from its
        own generator only (nothing when ``alpha == 0``).
    expert_indices : sequence of int, optional
        Which experts (default: all, ``0 .. E-1``).
    dt : float
        Frame periods since the state's frame (1: the next frame; a live source skips frames): the
        pose transition and the texels' prediction span ``dt`` periods (:meth:`GFlowConfig.at_pace`).
        With dt = 1 the bits are the one-step model's. The proposals carry it to :func:`update`.
    pyramid : sequence of FrameData, optional
        ``frame`` already validated with its gradient images and its coarser levels
        (:func:`.image.prepare_frame`, :func:`.image.frame_pyramid` with ``cfg.pyramid_levels``), made
        ahead of the experts; None: made here. The same arrays either way.

    Returns
    -------
    Proposals
    """
    state.check(model)
    pyramid = _check_pyramid(state, frame, cfg, pyramid)
    fd = pyramid[0]
    idx = _expert_rows(state.n_experts, expert_indices)
    if len(rngs) != idx.size:
        raise ValueError(f"need one rng per proposed expert: got {len(rngs)} rngs for {idx.size} experts")
    # p(u_t | u_{t-dt}) and the texels' prediction over the dt periods since the state's frame
    cfg = cfg.at_pace(dt)
    prior_std = cfg.prior_std(model.n_bases)
    prev = state.poses[idx]
    # mean of p(u_t | u_{t-1}): u_{t-1} itself unless its rotation decays toward the identity
    centre = prior_mean(prev, cfg.prior_rotation_decay, cfg.morph_shrink(model.n_bases))
    # self-occlusion: which vertices the head hides at each expert's previous pose
    tv = _texture_view(state, idx, cfg, vertex_visibility(model, prev, cfg))
    ph = cfg.photometric_model()
    max_rot = math.radians(cfg.max_rotation_deg)
    osq = cfg.outlier_sigmas ** 2
    scale = cfg.scale_limits()
    reset = _anchored_reset(state, cfg)
    gn = _opinion_peak(model, pyramid, prev, centre, tv, prior_std, cfg, ph, reset)
    flags = np.zeros(idx.size, dtype=bool) if gn.reset is None else gn.reset
    if flags.any() and reset is not None and reset.anchor_mean is not None:
        # experts that took the reset are weighed with the first look's texels
        tv = _with_anchor(tv, flags, reset)
    # u^(d,e) ~ g(. | u_hat, alpha Sigma_hat),  Sigma_hat = inverse Hessian of eq. 14
    samples, log_g, sigma_hat = laplace_proposal(gn.u_hat, gn.hessian, cfg.alpha, cfg.n_samples, rngs)
    log_prior = log_pose_prior(centre, samples, prior_std, max_rot, scale, reset)
    bgt = background_image_terms(fd.image, tv, cfg.sigma_w) if tv.has_background else None
    # full likelihood, eq. 13, tempered: log p(y_t | u, y_{1:t-1}) / kappa (departure from the paper)
    log_lik = log_likelihood(model.bases, fd, samples, tv, cfg.sigma_w, bgt, photometric=ph, outlier_sq=osq)
    if cfg.data_temper != 1.0:
        log_lik = log_lik / cfg.data_temper
    # importance weights, eq. 16
    log_w = log_importance_weights(log_prior, log_lik, log_g)
    # likelihood of the expert, eq. 19
    log_ev = log_evidence(log_w)
    return Proposals(
        expert_indices=_ro(idx),
        u_hat=_ro(gn.u_hat),
        sigma_hat=_ro(sigma_hat),
        samples=_ro(samples),
        log_weights=_ro(log_w),
        log_evidence=_ro(log_ev),
        gn_objective=_ro(gn.objective),
        reset=_ro(np.array(flags, dtype=bool)),
        dt=float(dt),
    )


def _check_pyramid(state: ExpertState, frame: np.ndarray, cfg: GFlowConfig,
                   pyramid: Sequence[FrameData] | None) -> Sequence[FrameData]:
    """``pyramid`` checked against the state's image size, or made from ``frame`` when None."""
    if pyramid is None:
        return frame_pyramid(prepare_frame(frame, shape=state.image_shape), cfg.pyramid_levels)
    if not pyramid or pyramid[0].shape != tuple(state.image_shape):
        raise ValueError(f"the frame's pyramid is for {pyramid[0].shape if pyramid else 'no'} frames, the state "
                         f"tracks {tuple(state.image_shape)}")
    return pyramid


def _expert_rows(E: int, expert_indices: Sequence[int] | np.ndarray | None) -> np.ndarray:
    """``expert_indices`` checked (1-D, integer, in ``[0, E)``, distinct) as int64; all ``E`` when None."""
    if expert_indices is None:
        return np.arange(E, dtype=np.int64)
    idx = np.asarray(expert_indices)
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"expert_indices must be a 1-D integer sequence, got {idx!r}")
    if idx.size and (idx.min() < 0 or idx.max() >= E):
        raise ValueError(f"expert_indices must lie in [0, {E}), got {idx.tolist()}")
    if np.unique(idx).size != idx.size:
        raise ValueError("expert_indices contain duplicates")
    return idx.astype(np.int64)


def _anchored_reset(state: ExpertState, cfg: GFlowConfig) -> RotationReset | None:
    """The frontal reset of ``cfg`` (None: off); with a texture anchor, one that also restarts the texels
    from the first look (the anchor of ``texture_decay``)."""
    reset = cfg.rotation_reset()
    if reset is not None and state.tex_anchor is not None:
        reset = dataclasses.replace(reset, anchor_mean=state.tex_anchor,
                                    anchor_var=np.full(state.tex_anchor.shape, cfg.v_init_var + cfg.psi_v))
    return reset


def _opinion_peak(model: MorphableModel, pyramid: Sequence[FrameData], prev: np.ndarray, centre: np.ndarray,
                  tv: TextureView, prior_std: np.ndarray, cfg: GFlowConfig, ph: Photometric | None,
                  reset: RotationReset | None) -> GaussNewtonResult:
    """``u_hat`` = argmin eq. 14 from ``u_{t-1}`` = ``prev`` (E, P) about the prior mean ``centre``: the
    paper's Gauss-Newton (second background term ignored, the first one too unless ``gn_background``)
    or, with any departure configured, :func:`.pose_opinion.coarse_to_fine_peak`."""
    max_rot = math.radians(cfg.max_rotation_deg)
    osq = cfg.outlier_sigmas ** 2
    scale = cfg.scale_limits()
    if (cfg.pyramid_levels == 1 and cfg.search_radius == 0.0 and ph is None and not math.isfinite(max_rot)
            and not math.isfinite(osq) and scale is None and reset is None and cfg.data_temper == 1.0
            and not cfg.generic_background and not cfg.local_background):
        return gauss_newton_peak(
            model.bases, pyramid[0], centre, tv, cfg.sigma_w, prior_std, cfg.gn_iterations, start=prev,
            use_background=cfg.gn_background,
        )
    # departures (see pose_opinion.coarse_to_fine_peak and photometric): pyramid, search, gain/bias
    return coarse_to_fine_peak(
        model.bases, pyramid, centre, tv, cfg.sigma_w, prior_std,
        cfg.gn_iterations, start=prev, use_background=cfg.gn_background, photometric=ph,
        offsets=search_offsets(cfg.search_radius, cfg.search_step), max_rotation=max_rot,
        search_stride=cfg.search_stride, outlier_sq=osq, scale=scale, reset=reset, temper=cfg.data_temper,
    )


def _with_anchor(tv: TextureView, rows: np.ndarray, reset) -> TextureView:
    """``tv`` with the texels of the experts ``rows`` (bool) replaced by the reset's first look."""
    mean, var = np.array(tv.mean), np.array(tv.var)
    mean[rows], var[rows] = reset.anchor_mean, reset.anchor_var
    return dataclasses.replace(tv, mean=mean, var=var)


def concatenate_proposals(parts: Sequence[Proposals]) -> Proposals:
    """Join proposals of disjoint expert shards, ordered by expert index."""
    if not parts:
        raise ValueError("no proposals to concatenate")
    dts = {p.dt for p in parts}
    if len(dts) != 1:
        raise ValueError(f"proposals of one frame made for different time steps {sorted(dts)}")
    idx = np.concatenate([p.expert_indices for p in parts])
    order = np.argsort(idx, kind="stable")

    def cat(name: str) -> np.ndarray:
        return _ro(np.concatenate([getattr(p, name) for p in parts])[order])

    return Proposals(**{f: cat(f) for f in Proposals.__dataclass_fields__ if f != "dt"}, dt=parts[0].dt)


def update(
    state: ExpertState,
    proposals: Proposals,
    frame: np.ndarray,
    model: MorphableModel,
    cfg: GFlowConfig,
    rng: np.random.Generator,
) -> tuple[ExpertState, Estimate]:
    """Credibility, resampling and texture update (sec. 3.3, 3.4, eq. 7-10).

    Parameters
    ----------
    state : ExpertState
        Experts at ``t - 1`` (the state ``proposals`` were computed from).
    proposals : Proposals
        For all experts, ``0 .. E-1`` in order (see :func:`concatenate_proposals`); the texels are
        predicted over its ``dt`` periods.
    frame : (H, W) float64 in [0, 1]
        ``y_t``.
    model : MorphableModel
    cfg : GFlowConfig
    rng : numpy.random.Generator
        Resampling: one uniform draw (if resampling) then ``random(E)``.

    Returns
    -------
    state : ExpertState
        Experts at ``t``.
    estimate : Estimate
    """
    state.check(model)
    img = validate_frame(frame, shape=state.image_shape)
    E = state.n_experts
    _check_proposals(proposals, E)
    samples, log_w = proposals.samples, proposals.log_weights
    # the texels are predicted over the periods the proposals' step spans (eq. 9, 10)
    cfg = cfg.at_pace(proposals.dt)
    s = samples.shape[1]
    # credibility, eq. 17 with eq. 19
    log_cred = log_credibility(state.log_credibility, proposals.log_evidence)
    ess_val = ess(log_cred)
    # posterior (eq. 5): expert credibility x normalised importance weight of each sample (eq. 15)
    log_post = (log_cred[:, None] + normalize_rows(log_w)).reshape(-1)
    flat = samples.reshape(E * s, -1)
    mean_pose = posterior_mean_pose(flat, log_post)
    pose_std = pose_spread(flat, log_post, mean_pose)
    resampled = bool(cfg.resample_ess_fraction >= 1.0 or ess_val < cfg.resample_ess_fraction * E)
    parents, picks, new_log_cred = _children(log_cred, log_w, resampled, rng)
    poses = samples[parents, picks]
    pts = project(model.bases, poses)
    tex_mean, tex_var, p_in = _learn_texels(state, proposals, parents, pts, img, cfg,
                                            vertex_visibility(model, poses, cfg))
    bg_mean = bg_var = None
    if state.bg_mean is not None:
        assert state.bg_var is not None
        bg_mean, bg_var = advance_background(state.bg_mean, state.bg_var, poses, parents, img, model, cfg)
    mean_pts = project(model.bases, mean_pose)
    W = np.exp(new_log_cred)
    d2 = np.sum((pts - mean_pts[None]) ** 2, axis=-1).mean(axis=-1)
    new_state = ExpertState(
        poses=_ro(np.ascontiguousarray(poses)),
        tex_mean=_ro(tex_mean),
        tex_var=_ro(tex_var),
        bg_mean=bg_mean,
        bg_var=bg_var,
        log_credibility=_ro(new_log_cred),
        image_shape=state.image_shape,
        tex_anchor=state.tex_anchor,
    )
    est = Estimate(
        pose=_ro(mean_pose),
        rotation=_ro(rotation_matrices(mean_pose)),
        pose_std=_ro(pose_std),
        spread_px=float(np.sqrt(W @ d2 / W.sum())),
        ess=float(ess_val),
        expert_points=_ro(pts),
        mean_points=_ro(mean_pts),
        bbox=_ro(bounding_box(mean_pts)),
        log_credibility=_ro(log_cred),
        parents=_ro(parents),
        resampled=resampled,
        inlier_fraction=float(W @ p_in.mean(axis=1) / W.sum()),
        inlier_count=float(W @ (p_in > 0.5).mean(axis=1) / W.sum()),
    )
    return new_state, est


def _check_proposals(proposals: Proposals, E: int) -> None:
    """Raise ValueError unless ``proposals`` cover the ``E`` experts in order with finite samples and weights."""
    if not np.array_equal(proposals.expert_indices, np.arange(E)):
        raise ValueError(
            f"update needs proposals for all {E} experts in order; got indices {proposals.expert_indices.tolist()}"
        )
    if not (np.isfinite(proposals.log_weights).all() and np.isfinite(proposals.samples).all()):
        raise ValueError("proposals contain NaN or infinite values")


def _children(log_cred: np.ndarray, log_w: np.ndarray, resampled: bool, rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each expert's parent (E,), the sample it takes (E,) and its log credibility (E,) at ``t`` (sec. 3.4).

    Resampling draws children from parents in proportion to credibility (uniform credibility after);
    otherwise every expert is its own parent and keeps its credibility. ``u_t`` is one of the parent's
    samples drawn by importance weight either way.
    """
    if resampled:
        parents, picks = resample_experts(log_cred, log_w, rng)
        return parents, picks, np.full(log_cred.shape[0], -np.log(log_cred.shape[0]))
    return np.arange(log_cred.shape[0], dtype=np.int64), pick_samples(normalize_rows(log_w), rng), log_cred


def _learn_texels(state: ExpertState, proposals: Proposals, parents: np.ndarray, pts: np.ndarray, img: np.ndarray,
                  cfg: GFlowConfig, vis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object texels at ``t`` of the children of ``parents`` (E,) at their vertices ``pts`` (E, n, 2).

    Predict (eq. 9, 10; children of an expert that took the frontal reset start from the first look) then
    the Kalman update (eq. 7, 8) where the vertex is in the image and, with ``outlier_sigmas``, explained
    by the texels; with visibility weights ``vis`` (E, n) (self-occlusion at the children's poses) the
    observation noise is ``sigma_w / vis`` and a hidden vertex (``vis = 0``) keeps its prediction.
    Returns the means and variances (E, n) and each vertex's inlier probability (E, n).
    """
    st = bilinear_stencil(pts, img.shape)
    y = st.sample(img.reshape(-1))
    pred_mean, pred_var = predict_texels(state, parents, cfg)
    restart = proposals.reset[parents]
    if restart.any() and state.tex_anchor is not None:
        # children of an expert that took the frontal reset start from the first look's texels
        pred_mean, pred_var = np.array(pred_mean), np.array(pred_var)
        pred_mean[restart], pred_var[restart] = state.tex_anchor, cfg.v_init_var + cfg.psi_v
    y, p_in, r2, vv = explained(y, st.inside, pred_mean, pred_var, cfg)
    observed = st.inside
    if math.isfinite(cfg.outlier_sigmas):
        # outlier vertices (occluder, highlight) are not learned: prediction only
        observed = observed & (r2 <= cfg.outlier_sigmas ** 2 * vv)
    sigma_w: float | np.ndarray = cfg.sigma_w
    if cfg.texel_noise_adapt:
        # E((y_i - mu_i)^2) = sigma_i + sigma_w: the observation noise the expert's fit shows (E, 1)
        n_in = np.maximum(observed.sum(axis=1, keepdims=True), 1)
        excess = np.where(observed, r2 - pred_var, 0.0).sum(axis=1, keepdims=True) / n_in
        sigma_w = np.maximum(cfg.sigma_w, excess)
    if vis is not None:
        # self-occlusion: a partly hidden vertex observes its texel through noise sigma_w / v_i, a hidden one not
        observed = observed & (vis > 0.0)
        sigma_w = sigma_w / np.maximum(vis, 1e-12)
    # object texels: predict (eq. 9, 10) then update (eq. 7, 8) where the vertex is in the image
    tex_mean, tex_var = kalman_update(pred_mean, pred_var, y, sigma_w, observed=observed)
    return tex_mean, tex_var, p_in


def explained(y: np.ndarray, inside: np.ndarray, mean: np.ndarray, var: np.ndarray, cfg: GFlowConfig
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How well texels explain the frame at the vertices.

    Parameters
    ----------
    y : (E, n) the frame sampled at each expert's projected vertices; inside : (E, n) bool, the
        vertex is in the image; mean, var : (E, n) the predicted texels (eq. 9, 10).

    Returns
    -------
    y : (E, n) the frame as the texels observe it (light-corrected ``(y - b) / a`` with the
        photometric model); p_in : (E, n) P(object | y) of each vertex, 0 outside the image;
        r2 : (E, n) squared residuals; vv : (E, n) their variances ``var + sigma_w``.
    """
    ph = cfg.photometric_model()
    if ph is not None:
        # the texels observe the light-corrected frame (y - b) / a (see photometric)
        a, b = gain_bias(y, mean, 1.0 / (var + cfg.sigma_w), ph)
        y = correct(y, a, b)
    vv = var + cfg.sigma_w
    r2 = (y - mean) ** 2
    tau = cfg.outlier_sigmas if math.isfinite(cfg.outlier_sigmas) else 3.0
    # P(object | y) = N(e) / (N(e) + N(tau)): the texel's Gaussian (eq. 13) against the outlier process
    p_in = np.where(inside, 1.0 / (1.0 + np.exp(np.minimum(0.5 * (r2 / vv - tau * tau), 700.0))), 0.0)
    return y, p_in, r2, vv


def _masks(model: MorphableModel, poses: np.ndarray, shape: tuple[int, int], cfg: GFlowConfig) -> np.ndarray:
    """Object pixels ``X(u)`` of each pose, (E, H, W) bool (:func:`.texture.object_mask`)."""
    pts = project(model.bases, poses)
    out = np.empty((poses.shape[0],) + tuple(shape), dtype=bool)
    for e in range(poses.shape[0]):
        out[e] = object_mask(pts[e], shape, cfg.object_mask, cfg.object_mask_margin)
    return out


def initial_background(model: MorphableModel, poses: np.ndarray, frame: np.ndarray,
                       cfg: GFlowConfig) -> tuple[TiledTexels, TiledTexels]:
    """Background texels at the first frame: the frame itself with variance ``b_init_var``,
    except under each expert's object, ``unknown_var``.

    Parameters
    ----------
    poses : (E, P) float64, the experts' first poses.
    frame : (H, W) float64 in [0, 1]

    Returns
    -------
    bg_mean, bg_var : (E, H, W) float64 texels stored once per distinct tile
        (:class:`.background.TiledTexels`; ``np.asarray`` gives the dense arrays).
    """
    img = validate_frame(frame)
    bank = TiledBackground.initial(img, _masks(model, poses, img.shape, cfg), cfg.b_init_var, cfg.unknown_var)
    return bank.mean, bank.var


def _bank(bg_mean, bg_var) -> TiledBackground:
    if isinstance(bg_mean, TiledTexels) and isinstance(bg_var, TiledTexels) and bg_mean.bank is bg_var.bank:
        return bg_mean.bank
    return TiledBackground.from_dense(bg_mean, bg_var)


def advance_background(bg_mean, bg_var, poses: np.ndarray, parents: np.ndarray, frame: np.ndarray,
                       model: MorphableModel, cfg: GFlowConfig) -> tuple[TiledTexels, TiledTexels]:
    """Background texels at ``t`` from those at ``t - 1`` (sec. 3.1, eq. 7-10).

    Each new expert ``e`` starts from its parent's background ``parents[e]``, which is
    predicted (eq. 9, 10) and updated with ``frame`` outside the object it renders at
    ``poses[e]`` (eq. 7, 8). This needs only the parents, the new poses and the frame, so a
    proposal process can keep its own bit-identical copy of the backgrounds instead of
    receiving (E, H, W) arrays every frame. Computed on distinct tiles
    (:meth:`.background.TiledBackground.advance`), texel for texel the arithmetic of
    :func:`.texture.background_predict_update`.

    Parameters
    ----------
    bg_mean, bg_var : (E, H, W) posterior at ``t - 1`` (:class:`.background.TiledTexels` of one
        bank, or float64 arrays).
    poses : (E, P) float64, ``u_t`` of the new experts.
    parents : (E,) int64
    frame : (H, W) float64 in [0, 1], ``y_t``.

    Returns
    -------
    bg_mean, bg_var : (E, H, W) at ``t``, :class:`.background.TiledTexels`, new objects.
    """
    bank = _bank(bg_mean, bg_var)
    img = validate_frame(frame, shape=bank.layout.shape)
    new = bank.advance(np.asarray(parents), _masks(model, poses, img.shape, cfg), img, cfg.psi_b, cfg.sigma_w)
    return new.mean, new.var


def predict_background(bg_mean, bg_var, parents: np.ndarray, cfg: GFlowConfig) -> tuple[TiledTexels, TiledTexels]:
    """Prediction only (eq. 9, 10), for a frame that was not seen: each new expert takes its
    parent's means, and its variances plus ``Psi_b``."""
    new = _bank(bg_mean, bg_var).predict(np.asarray(parents), cfg.psi_b)
    return new.mean, new.var


def step(
    state: ExpertState,
    frame: np.ndarray,
    model: MorphableModel,
    cfg: GFlowConfig,
    seed: int,
    t: int,
    stream_hash: int = 0,
) -> tuple[ExpertState, Estimate]:
    """One filter step with the documented generators (:func:`propose` then :func:`update`).

    Expert ``i`` uses ``default_rng([seed, stream_hash, t, i])``; the update uses
    ``default_rng([seed, stream_hash, t])``.
    """
    props = propose(state, frame, model, cfg, expert_rngs(seed, stream_hash, t, range(state.n_experts)))
    return update(state, props, frame, model, cfg, np.random.default_rng([int(seed), int(stream_hash), int(t)]))
