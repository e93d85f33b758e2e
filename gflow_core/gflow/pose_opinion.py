"""Pose opinion of an expert (sec. 3.2): Gauss-Newton peak, Laplace covariance, samples.

For expert ``d`` with previous pose ``u_{t-1}`` and predicted textures (eq. 9, 10)
the pose opinion peak is (eq. 14)::

    u_hat = argmin_u  -log p(u | u_{t-1})
            + 1/2 sum_i [ (y_t(x_i(u)) - mu_v(i))^2 / (sigma_v(i) + sigma_w)        (foreground)
                        - (y_t(x_i(u)) - mu_b(x_i(u)))^2 / (sigma_b(x_i(u)) + sigma_w)  (background 1)
                        - log(sigma_b(x_i(u)) + sigma_w) ]                            (background 2)

Gauss-Newton ignores the second background term, as the paper does (sec. 3.2.2);
the importance weights (eq. 16) use the full likelihood of eq. 13. The Laplace
covariance is ``Sigma_hat = H^-1`` with ``H`` the Gauss-Newton Hessian at ``u_hat``,
and ``s`` samples are drawn from ``N(u_hat, alpha Sigma_hat)``.

Everything is vectorised over a batch of ``E`` experts, and the result for one
expert does not depend on which other experts are in the batch (the per-expert
computations are the same array operations on that expert's slice, and the only
randomness comes from that expert's own ``numpy.random.Generator``).

Tangent space
-------------
Poses are stepped, sampled and compared in the tangent space of
:mod:`.geometry` (``u [+] d``). ``Sigma_hat`` is the covariance of the increment
``d`` at ``u_hat``; a sample is ``u_hat [+] d``, ``d ~ N(0, alpha Sigma_hat)``, and
``g(u | u_hat, alpha Sigma_hat)`` (eq. 16) is the Gaussian density of that ``d``.

Pose transition prior
---------------------
``p(u_t | u_{t-1})`` is a Gaussian in the tangent space at its mean ``m(u_{t-1})``:
``box_minus(m, u_t) ~ N(0, diag(std^2))``, with ``std`` per component
(``inf`` = uninformative, that component contributes nothing). By default ``m = u_{t-1}``
(a random walk). The paper leaves the pose dynamics unspecified (sec. 2); optionally
(:func:`prior_mean`, ``rotation_decay = a < 1``) the rotation of the mean is pulled
toward the identity (the initial, frontal orientation): ``r_m = exp(a log r_{t-1})``, an
AR(1) process on the rotation vector whose stationary spread is ``std / sqrt(1 - a^2)``;
Gauss-Newton still starts from ``u_{t-1}``. Inside Gauss-Newton the tangent difference is linearised as ``d(u [+] delta) ~ d(u) + delta`` (the
right Jacobian of the rotation log is taken as the identity, exact at ``d = 0`` and
accurate to ``O(|d_w|^2)`` for the small inter-frame rotations the prior allows).

Departures from the paper
-------------------------
* Gauss-Newton and the background (``GFlowConfig.gn_background``, default False).
  The paper's Gauss-Newton keeps the first background term of eq. 14 and drops the
  second. That is available (``gn_background=True``), but by default Gauss-Newton
  uses the foreground term and the prior only, and the background enters through
  the importance weights and credibilities (full eq. 13 in eq. 16 and 19). Reason:
  the first background term rewards a vertex by up to ``r^2 / (sigma_b + sigma_w)``
  (about 30 per vertex for ``r = 0.2``, against about 0.4 for a one-pixel texture
  misalignment), and ``sigma_b`` jumps by three orders of magnitude across the
  object boundary, so the objective is rough and dominated by the boundary vertices.
  Measured on the synthetic sequences of :mod:`.render` with the background model
  on and default parameters (8 sequences of 30 frames at 160x120, 10 experts): mean
  rotation / translation error 18.6 deg / 4.7 px with the term, 7.1 deg / 1.8 px
  without it; one 320x240 sequence with 20 experts: 14.3 deg / 9.8 px against
  3.5 deg / 3.6 px.

* Robustness (all off by default here; on in ``pipeline/graphs/gflow.yaml``; chosen on the
  four shared sequences caviar1, crossing, david_indoor and jumping together):

  - Coarse-to-fine Gauss-Newton (:func:`coarse_to_fine_peak`, ``GFlowConfig.pyramid_levels``)
    on an image pyramid, so that the peak of eq. 14 is found from further than the few
    pixels single-scale Gauss-Newton reaches; with ``search_radius`` the coarsest level
    first tries a grid of translations (fast motion: 36 px between two frames on
    jumping) and the peak found from there competes with the one found from ``u_{t-1}``.
    ``u_hat`` stays a deterministic function of the expert, so eq. 16 and 19 are unchanged.
  - A gain and bias per expert and frame in the texture observation (:mod:`.photometric`).
  - A soft wall on the rotation angle from the initial pose (:func:`rotation_wall`), part of
    the pose prior: the generic head seen edge-on had collapsed its box on david_indoor.
  - A soft wall on the scale's drift from the initial scale (:func:`scale_wall`).
  - An outlier process per vertex (:func:`robust_cost`): occluders and highlights cost a
    capped amount instead of a quadratic one (in Gauss-Newton on every level and in the
    likelihood; not in the coarse search, where a capped cost lost jumping: CLE 42 px
    against 27.5 px).

* A tempered data term (``temper = kappa``, ``GFlowConfig.data_temper``; off, ``kappa = 1``,
  by default and in the shipped graphs). Eq. 13 treats every vertex's residual as independent,
  but neighbouring vertices sample overlapping, blurred pixels, so the data term is over-confident
  by about the number of vertices per independent residual. A composite (power) likelihood divides
  its log by ``kappa``: in eq. 14 (foreground, background term and, where texels differ, their
  normalising terms; search, every level, gradient and Hessian, so ``Sigma_hat`` grows by
  ``kappa``) and in eq. 13 for the weights (the caller, :mod:`.filter`). For the peak this is the
  prior made ``kappa`` times as precise. The outlier cap stays on the untempered standardised
  residual. Measured on david_indoor (docs/gflow-development.md): it does not keep the experts on the face
  at every 3rd frame, and it loses it at every frame, so it is not used.

* A generic background (``TextureView.generic``, ``GFlowConfig.generic_background``; off by default
  and in the shipped graphs). Without the background model the paper drops eq. 14's background
  terms, so the data term is the object's alone: a squared residual ``(y - mu_v)^2 / (sigma_v +
  sigma_w)`` per vertex, which is smaller on a low-contrast patch than on a face whose texels
  correlate with it only weakly (david_indoor at every 3rd frame, step 348 -> 351: the face's
  pixels have a standard deviation of 0.18, the shirt collar's 0.14; the texels correlate 0.40 with
  the face, 0.25 with the collar, yet eq. 14 prefers the collar). With the generic background the
  vertices' pixels, were they background, are ``N(m, s^2)``, the frame's mean and variance
  (:func:`generic_background`, on the level the objective is evaluated on), and eq. 14's first
  background term ``- sum_i (y(x_i) - m)^2 / s^2`` enters as in the paper: a likelihood ratio of
  object against background at the vertices, so a featureless patch gains nothing by being claimed
  (the step above: 50 at the face against 75 on the collar). Its second term is the same at every
  pose and is dropped. It enters the coarse search, the objective by which the chains are compared
  (the search's, the previous pose's and the frontal reset's) and the importance weights (eq. 13,
  16); Gauss-Newton climbs the object's term and the prior alone, as the paper's does without its
  second background term, because with the generic term in its steps the fitted face grew and
  turned (david_indoor at every frame, seeds 1-2: 0.092 / 0.098 against 0.077 / 0.075). Measured
  (docs/gflow-development.md): at every 3rd frame 0.113 / 0.100 / 0.115 (seeds 1-3; 0.108
  / 0.134 / 0.165 without), at every frame 0.077 / 0.075 (0.070 / 0.067 without): the goal of 0.10
  at every 3rd frame is not met, so it stays off.

* A local background (``TextureView.local``, ``GFlowConfig.local_background`` = ``S`` px; the
  tracker's default ``S`` = 5 since 2026-12-02, with the pose walks at a face's rates, which
  together bring david_indoor at every 3rd frame within 0.10: docs/gflow-development.md, "Both
  walks at the face's rates"; 0 in the paper's preset). The paper's background model learns a texel per pixel over
  past frames (``background``), which a moving camera leaves describing the view before it moved
  (david_indoor at every 3rd frame: 0.199 / 0.204 / 0.176, seeds 1-3). Here each pixel's
  background is read from the frame itself, about the pixel: ``N(M(x), V(x))``, the frame's mean
  and variance in a Gaussian window of std ``S`` (:func:`local_background`; ``V`` at least
  ``sigma_w``, the observation noise). Both background terms of eq. 14 then count, and the second,
  ``- log V(x_i)``, changes with the pose: a flat patch (small ``V``), which the background explains
  well, costs the object its claim. ``B(x) = (y - M)^2 / V + log V`` is a per-pixel image, read
  bilinearly at the vertices (rather than ``B`` of the bilinear sample: one image per frame for
  every expert and sample). It enters the objective by which the chains are compared and the importance
  weights (eq. 13, 16, so the credibilities, eq. 19); Gauss-Newton and the coarse translation
  search keep the object's term and the prior (in the search too it lost tiger1 more often, AUC
  0.543 against 0.630, and was no better on david_indoor). Measured (docs/gflow-development.md,
  "The face against its surroundings"): every 3rd frame 0.102 / 0.107 / 0.098 (seeds 1-3), mean 0.107 over seeds 1-10 against
  0.135; every frame 0.077 / 0.084 / 0.069 (0.070 / 0.067 / 0.104 without; over seeds 1-10 0.075
  against 0.076, 6 seeds worse); the nine shared
  sequences' AUC 0.641 against 0.653: alone it stayed off. With both walks at a face's rates:
  0.089 / 0.094 / 0.092 at every 3rd frame, 0.075 / 0.061 / 0.061 at every frame, AUC 0.639
  against 0.642 measured beside it (OpenCV 5.1.0): the default.

* Self-occlusion (``TextureView.vis``, ``GFlowConfig.self_occlusion``; off by default and in the
  shipped graphs). The paper sees every vertex at every pose (the one-to-one ``a_v`` of eq. 2-4), so
  the far side of a turned face is scored on whatever lies beyond the head. With visibility weights
  ``v_i in [0, 1]`` (:mod:`.visibility`: back-facing vertices by their normals; no depth order),
  computed by the caller at each expert's previous pose and held for the frame, each vertex's texture
  term of eq. 13 and 14 counts ``v_i`` times and the rest, ``1 - v_i``, is its expectation under the
  texel's Gaussian, ``E (y - mu_v)^2 / (sigma_v + sigma_w) = 1`` (the normalising term ``log(sigma_v +
  sigma_w)`` stays whole), so that experts hiding different vertices compare: in the search, every
  level of Gauss-Newton (gradient and Hessian weighted alike), the chains' comparison, the gain and
  bias and the likelihood of the weights; a generic or local background's terms at a vertex count
  ``v_i`` times too (a hidden vertex claims no pixel). The texel update is the caller's
  (:func:`.filter.update`). Measured (docs/gflow-development.md, "Self-occlusion"): every 3rd frame
  0.116 / 0.103 / 0.153 at ``0.2`` (seeds 1-3; mean over seeds 1-10 0.141 against 0.135), every frame
  0.093 / 0.066 / 0.077 (0.070 / 0.067 / 0.104 without), the nine shared sequences' AUC 0.605 against
  0.653: it stays off.

Implementation (speed; the same mathematics, results equal to the straightforward
version to about 1e-14 relative, measured over 20-30 frames of each shared sequence):

* One evaluation of the objective per Gauss-Newton step (:class:`_Evaluation`) serves both
  the step's acceptance test and, for the experts whose step is accepted only, the
  linearisation at the new point (gradient images sampled with the same stencil); a
  rejected expert keeps the linearisation it had. Rotations go through quaternions in
  plain numpy (:mod:`.geometry`), the Jacobian is built with the vertices last.
* :func:`coarse_to_fine_peak` computes the peak once for experts that are exact copies of
  one another (resampled children of one parent that drew the same sample: on jumping
  about 9 distinct of 20), and runs the second chain only for the experts the search moved
  (where the search keeps the start, the second chain would repeat the first bit for bit).
  The search itself (:mod:`.coarse_search`) shares each vertex's bilinear weights across
  the whole-pixel translations.
* Every step is per expert, so any split of the experts (shards, blocks, distinct rows)
  gives the same numbers bit for bit (tested).

Numerical safeguards:

* Gauss-Newton with step control: a step is taken only if it decreases the
  Gauss-Newton objective, otherwise the step length for that expert is halved
  (and doubled again, up to 1, after a success). A fixed number of iterations is
  run for every expert so that results do not depend on the batch.
* The background curvature ``-J_b^T W_b J_b`` is negative; to keep the Hessian
  positive definite it is limited so that it removes at most
  ``1 - MIN_CURVATURE_FRACTION`` (90 %) of the foreground-plus-prior curvature in any
  direction (eigenvalue clamp in the metric of the foreground-plus-prior Hessian).
* A ridge ``1e-10 * diag(H) + 1e-12 * max(max(diag(H)), 1e-12)`` is added to the
  foreground-plus-prior Hessian so that it is invertible (and ``Sigma_hat`` finite)
  on a blank frame with an uninformative prior. It changes step lengths, not the
  stationary point.
* ``alpha = 0`` (the paper's limit, samples = ``u_hat``): the ``s`` samples are all
  ``u_hat`` and ``log g`` is replaced by the ``alpha = 1`` density at its mode,
  ``-P/2 log 2 pi + 1/2 log |H|``, so that ``w = f(u_hat) (2 pi)^{P/2} |Sigma_hat|^{1/2}``,
  the Laplace estimate of the integral in eq. 18.
* The image gradient at a vertex is the bilinear sample of the central-difference
  gradient images of ``y_t`` (as in Lucas-Kanade), not the derivative of the bilinear
  interpolant used for the values. So the plain Gauss-Newton fixed point is not
  exactly the minimum of the sampled objective (it differed by up to about 1 degree
  along the flat rotation/translation valley of the synthetic head); the step
  control makes the iteration stop where the objective stops decreasing. The exact
  interpolant derivative was measured to track worse (mean rotation error 6.9
  against 3.4 degrees over 8 synthetic sequences), being piecewise constant.
* With ``gn_background``, the gradient of the background mean is the derivative of
  its bilinear interpolant, and the background texel weights
  ``1/(sigma_b + sigma_w)`` are held fixed within a Gauss-Newton step.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .geometry import (COEF, ROT, TRANS, box_minus, box_plus, pose_quaternions, project,
                       quaternion_matrices, relative_rotvecs)
from .background import TiledTexels
from .coarse_search import translation_costs
from .image import BilinearStencil, FrameData, stencil_xy
from .photometric import Photometric

__all__ = [
    "MIN_CURVATURE_FRACTION",
    "TextureView",
    "GaussNewtonResult",
    "RotationReset",
    "log_pose_prior",
    "gauss_newton_objective",
    "gauss_newton_peak",
    "coarse_to_fine_peak",
    "search_offsets",
    "rotation_wall",
    "robust_cost",
    "scale_wall",
    "linearise_objective",
    "prior_precision",
    "prior_mean",
    "laplace_proposal",
    "background_image_terms",
    "log_likelihood",
    "log_importance_weights",
    "generic_background",
    "local_background",
]

#: Fraction of foreground-plus-prior curvature the background term may not remove.
MIN_CURVATURE_FRACTION = 0.1

_LOG_2PI = float(np.log(2.0 * np.pi))

#: The translation search of :func:`coarse_to_fine_peak` evaluates at most this many
#: (expert, offset, vertex) triples at once (about 80 bytes of temporaries each; see
#: :func:`.coarse_search.translation_costs`).
SEARCH_BLOCK_VERTICES = 1 << 16


@dataclass(frozen=True)
class TextureView:
    """Predicted texture opinions (eq. 9, 10) of a batch of ``E`` experts.

    Attributes
    ----------
    mean, var : (E, n) float64
        Predicted object texel means ``mu_v`` and variances ``sigma_v`` (posterior at
        ``t - 1`` plus ``Psi_v``).
    bg_mean, bg_var : (R, H, W) float64, :class:`.background.TiledTexels` or None
        Background texel posterior at ``t - 1`` for all ``R`` experts of the state
        (``None``: uninformative background). Not copied.
    bg_rows : (E,) intp or None
        Row of ``bg_mean`` / ``bg_var`` of each expert in the batch.
    psi_b : float
        ``Psi_b``; the predicted background variance is ``bg_var + psi_b`` (eq. 10).
    generic : bool
        The vertices' pixels, were they background, are read by a generic background: one
        Gaussian for every pixel, the mean and variance of the frame (of the pyramid level the
        objective is evaluated on), whose first term of eq. 14 enters at every vertex
        (:func:`generic_background`; departure from the paper, see the module docstring).
    local : float
        > 0: the vertices' pixels, were they background, are read by a local background: each
        pixel ``N(M(x), V(x))``, the frame's mean and variance in a Gaussian window of this std
        (pixels of level 0) about it, whose two terms of eq. 14 enter at every vertex
        (:func:`local_background`; departure from the paper, see the module docstring). 0: none.
    vis : (E, n) float64 in [0, 1] or None
        Each vertex's visibility weight ``v_i`` (:mod:`.visibility`, at the expert's previous pose):
        its texture term counts ``v_i`` times and the rest of it is replaced by its expectation under
        the texel's Gaussian (departure from the paper, see the module docstring). None: every vertex
        visible (the paper's).
    """

    mean: np.ndarray
    var: np.ndarray
    bg_mean: np.ndarray | TiledTexels | None = None
    bg_var: np.ndarray | TiledTexels | None = None
    bg_rows: np.ndarray | None = None
    psi_b: float = 0.0
    generic: bool = False
    local: float = 0.0
    vis: np.ndarray | None = None

    @property
    def frame_background(self) -> bool:
        """Whether a background read from the frame itself (generic or local) weighs the data term."""
        return self.generic or self.local > 0

    @property
    def has_background(self) -> bool:
        return self.bg_mean is not None

    def bg_at(self, st: BilinearStencil, rows: np.ndarray, with_grad: bool = False):
        """Background mean (and its x/y derivative) and predicted variance at points."""
        fm, fv = _flat(self.bg_mean), _flat(self.bg_var)
        var = st.sample(fv, rows) + self.psi_b
        if with_grad:
            m, mx, my = st.sample_with_gradient(fm, rows)
            return m, mx, my, var
        return st.sample(fm, rows), var


def generic_background(image: np.ndarray) -> tuple[float, float]:
    """The generic background of a (contrast-normalised) frame ``(H, W)``: every pixel
    ``N(m, s^2)`` with ``m`` and ``s^2`` the frame's mean and variance (``s^2`` floored at
    ``1e-6``). Returns ``(m, 1 / s^2)``, the mean and the weight of its first term of eq. 14."""
    m = float(image.mean())
    v = float(image.var())
    return m, 1.0 / max(v, 1e-6)


def local_background(image: np.ndarray, sigma: float, floor: float) -> np.ndarray:
    """The local background of a (contrast-normalised) frame ``(H, W)``: every pixel ``x`` is
    ``N(M(x), V(x))`` with ``M = G * y`` and ``V = max(G * (y - M)^2, floor)``, ``G`` a Gaussian of
    std ``sigma`` pixels (the background texels of eq. 13 read from the frame around each pixel
    rather than learnt over past frames; ``floor``: the observation noise ``sigma_w``, below which a
    pixel's variance cannot fall). Returns its two terms of eq. 14 per pixel, ``(H, W)``::

        B(x) = (y(x) - M(x))^2 / V(x) + log V(x)

    twice the negative log-density of the pixel as background, without its constant; the objective
    subtracts ``1/2 sum_i B(x_i)`` at the vertices (``B`` bilinearly interpolated).
    """
    import cv2

    m = cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    d = image - m
    v = np.maximum(cv2.GaussianBlur(d * d, (0, 0), sigma, borderType=cv2.BORDER_REFLECT), floor)
    return d * d / v + np.log(v)


def local_background_of(fd: FrameData, sigma: float, floor: float) -> np.ndarray:
    """:func:`local_background` of ``fd.image``, flat ``(H*W,)``: computed once per frame and
    ``(sigma, floor)`` and kept in ``fd.derived`` (the chains' objective and the importance weights
    read the same image; a stage computes it ahead, :meth:`.tracker.GFlowTracker.with_pyramid`)."""
    key = ("local_background", float(sigma), float(floor))
    got = fd.derived.get(key)
    if got is None:
        got = fd.derived[key] = local_background(fd.image, sigma, floor).reshape(-1)
    return got


def _flat(stack):
    """An ``(R, H, W)`` stack as a flat array for :class:`BilinearStencil` (an ndarray, or
    :class:`.background.TiledTexels` read tile by tile)."""
    return stack.reshape(-1) if isinstance(stack, np.ndarray) else stack.flat_view()


@dataclass(frozen=True)
class GaussNewtonResult:
    """Peak of the pose opinions of a batch of experts.

    Attributes
    ----------
    u_hat : (E, P) float64
        Peak of eq. 14 (without its second background term).
    hessian : (E, P, P) float64
        Gauss-Newton Hessian at ``u_hat`` (positive definite); ``Sigma_hat = hessian^-1``.
    objective : (E,) float64
        Gauss-Newton objective at ``u_hat``.
    reset : (E,) bool or None
        Experts whose peak is that of the frontal reset (:class:`RotationReset`); None: no reset tried.
    """

    u_hat: np.ndarray
    hessian: np.ndarray
    objective: np.ndarray
    reset: np.ndarray | None = None


def prior_precision(prior_std: np.ndarray) -> np.ndarray:
    """Precisions ``1 / std^2`` of the pose random walk, 0 where ``std`` is infinite."""
    std = np.asarray(prior_std, dtype=np.float64)
    return np.where(np.isinf(std), 0.0, 1.0 / np.where(np.isinf(std), 1.0, std) ** 2)


def prior_mean(prev: np.ndarray, rotation_decay: float = 1.0, coefficient_shrink: np.ndarray | None = None
               ) -> np.ndarray:
    """Mean ``m(u_{t-1})`` of the pose transition ``p(u_t | u_{t-1})``.

    Parameters
    ----------
    prev : (..., P) float64
        ``u_{t-1}``.
    rotation_decay : float in (0, 1]
        ``a``: the mean's rotation is ``exp(a log r_{t-1})`` (rotation vector times ``a``);
        translation is that of ``u_{t-1}``. ``1`` and no shrink return ``prev`` itself.
    coefficient_shrink : (k,) float64, optional
        The mean's coefficients are ``coefficient_shrink * c_{t-1}`` (the morph prior's AR(1)
        mean, :meth:`.filter.GFlowConfig.morph_shrink`); None: ``c_{t-1}``.

    Returns
    -------
    (..., P) float64
    """
    if rotation_decay == 1.0 and coefficient_shrink is None:
        return prev
    m = np.array(prev, dtype=np.float64)
    # w_m = a w_{t-1}  (geodesic from the identity to r_{t-1}, at fraction a)
    m[..., ROT] *= rotation_decay
    if coefficient_shrink is not None:
        # c_m = a_c c_{t-1}   (random walk times the stationary morph prior, normalised)
        m[..., COEF] *= coefficient_shrink
    return m


#: Standard deviation (radians, 1 degree) of the soft wall of :func:`rotation_wall`.
WALL_STD = float(np.radians(1.0))


def rotation_wall(poses: np.ndarray, max_rotation: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Soft wall on the absolute rotation angle (departure from the paper; a guard).

    ``-log`` of an extra factor of the pose prior that is 1 while the rotation angle
    ``theta = |w|`` (from the initial, frontal orientation) is at most ``max_rotation`` and
    falls as a half-Gaussian of std :data:`WALL_STD` beyond it::

        pen = (theta - max_rotation)_+^2 / (2 WALL_STD^2)

    A rigid head turned by 60-90 degrees is seen edge-on (the generic head has vertices on
    its front only), its box collapses and nothing brings it back; on david_indoor the
    pose reached 90 degrees within 300 frames. The factor's normalising constant (which
    depends on ``u_{t-1}``) is ignored.

    Parameters
    ----------
    poses : (..., P) float64
    max_rotation : float
        Radians; ``inf`` = no wall (zero penalty, gradient and curvature).

    Returns
    -------
    pen : (...) float64
    grad : (..., 3) float64
        Gradient wrt a body-frame rotation increment. Exact: the rotation vector ``w`` is an
        eigenvector (eigenvalue 1) of the right Jacobian of the rotation log, so
        ``d theta / d delta = w / theta``.
    hess : (..., 3, 3) float64
        Gauss-Newton curvature ``n n^T / WALL_STD^2`` beyond the wall (``n = w / theta``).
    """
    w = poses[..., ROT]
    shp = w.shape[:-1]
    if not np.isfinite(max_rotation):
        return np.zeros(shp), np.zeros(shp + (3,)), np.zeros(shp + (3, 3))
    th = np.sqrt((w * w).sum(axis=-1))
    ex = np.maximum(th - max_rotation, 0.0)
    k = 1.0 / WALL_STD ** 2
    pen = 0.5 * k * ex * ex
    if not (ex > 0.0).any():  # every pose inside the wall (the usual case)
        return pen, np.zeros(shp + (3,)), np.zeros(shp + (3, 3))
    n = w / np.maximum(th, 1e-12)[..., None]
    grad = (k * ex)[..., None] * n
    hess = np.where((ex > 0.0)[..., None, None], k * n[..., :, None] * n[..., None, :], 0.0)
    return pen, grad, hess


#: Standard deviation of the soft wall of :func:`scale_wall` (log scale, 1 %).
SCALE_WALL_STD = 0.01


def scale_wall(poses: np.ndarray, scale: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Soft wall on the scale's drift from the initial scale (departure from the paper; a guard).

    With ``scale = (|c_0|, log_max)``: ``s = log(|c| / |c_0|)`` (``c`` the morph coefficients;
    for a rigid model, the scale) and ``pen = (|s| - log_max)_+^2 / (2 SCALE_WALL_STD^2)``.
    Without it the head shrank to a point on jumping (``c`` from 32 to 0 within 200 frames),
    where every vertex samples one pixel and matches any flat patch. ``None`` = no wall.

    Returns
    -------
    pen : (...) float64
    grad : (..., k) float64, wrt the coefficients
    hess : (..., k, k) float64, Gauss-Newton curvature
    """
    c = poses[..., COEF]
    k = c.shape[-1]
    shp = c.shape[:-1]
    if scale is None:
        return np.zeros(shp), np.zeros(shp + (k,)), np.zeros(shp + (k, k))
    ref, log_max = scale
    nrm2 = np.maximum((c * c).sum(axis=-1), 1e-12)
    sl = 0.5 * np.log(nrm2) - np.log(ref)
    ex = np.maximum(np.abs(sl) - log_max, 0.0) * np.sign(sl)
    kk = 1.0 / SCALE_WALL_STD ** 2
    pen = 0.5 * kk * ex * ex
    if not (ex != 0.0).any():  # every scale inside the wall (the usual case)
        return pen, np.zeros(shp + (k,)), np.zeros(shp + (k, k))
    ds = c / nrm2[..., None]  # d s / d c
    grad = (kk * ex)[..., None] * ds
    hess = np.where((ex != 0.0)[..., None, None], kk * ds[..., :, None] * ds[..., None, :], 0.0)
    return pen, grad, hess


def robust_cost(e2: np.ndarray, outlier_sq: float) -> np.ndarray:
    """Per-vertex cost with an outlier process (departure from the paper): ``min(e^2, tau^2)``.

    ``e^2 = (y - mu_v)^2 / (sigma_v + sigma_w)`` is the vertex's term of eq. 13/14. Capping it
    at ``tau^2`` is the negative log of ``max(N(y; mu_v, .), uniform)``: each vertex is either
    the object's texel or an outlier of flat density (a hand, a passing person, a highlight).
    Without it one occluded patch of large residuals drags the Gauss-Newton peak and dominates
    the importance weights. ``tau^2 = inf`` (the default) is the paper's Gaussian. Gauss-Newton
    gives the capped vertices zero weight (iteratively reweighted least squares).
    """
    if not np.isfinite(outlier_sq):
        return e2
    return np.minimum(e2, outlier_sq)


@dataclass(frozen=True)
class RotationReset:
    """A pose transition that now and then turns the head back toward the frontal view (departure
    from the paper, which leaves ``p(u_t | u_{t-1})`` open, sec. 2).

    The rotation of ``u_t`` is drawn from a mixture: with probability ``1 - rate`` the random walk
    about the prior's mean ``m`` (:func:`prior_mean`), with probability ``rate`` a Gaussian about
    the identity (the frontal orientation the model was placed in)::

        p(w_t | u_{t-1}) = (1 - rate) N(log(r_m^T r_t); 0, diag(walk_std^2)) + rate N(w_t; 0, std^2 I)

    (translation and coefficients as in the walk). A tracker that locked on a turned pose after a
    large head turn (the texels anchored toward the first look match the face better at the
    frontal pose, but every step of the walk from the turned pose makes it worse) can so come
    back: :func:`coarse_to_fine_peak` also refines, for experts turned by at least ``min_angle``,
    a chain that starts frontal under the reset component, and keeps the peak whose objective
    under the mixture is lower.

    With an ``anchor`` (the first frame's texels, when they are the anchor of
    :func:`.texture.anchored_predict`), a reset also restarts the expert's texture from that first
    look: the frontal chain is fitted to the anchor texels, the two peaks are compared by their
    objectives including the texels' normalising terms ``1/2 sum_i log(sigma_v(i) + sigma_w)``, and
    an expert that takes the reset is weighed (eq. 13, 16, 19) and updated (eq. 7-10) from the
    anchor texels. This is what lets an expert that followed the wrong patch through a large turn
    (its texels learned that patch, so the wrong pose explains the frame well) find the face again.

    Attributes
    ----------
    rate : float in (0, 1)
    std : float
        Radians, the spread of the reset component about frontal.
    min_angle : float
        Radians.
    walk_std : (3,) float64
        The random walk's rotation std (finite).
    anchor_mean, anchor_var : (n,) float64 or None
        The first look's texels and their predicted variance.
    """

    rate: float
    std: float
    min_angle: float
    walk_std: np.ndarray
    anchor_mean: np.ndarray | None = None
    anchor_var: np.ndarray | None = None

    def anchor_view(self, rows: int) -> TextureView | None:
        """The anchor texels as the texture opinions of ``rows`` experts (None without an anchor)."""
        if self.anchor_mean is None or self.anchor_var is None:
            return None
        return TextureView(mean=np.broadcast_to(self.anchor_mean, (rows, self.anchor_mean.size)),
                           var=np.broadcast_to(self.anchor_var, (rows, self.anchor_var.size)))

    def neg_log_rotation(self, centre: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """``-log p(w | u_{t-1})`` of the mixture (module docstring), for poses ``(..., P)`` against
        prior means ``centre`` broadcast alike."""
        ws = np.asarray(self.walk_std, dtype=np.float64)
        d = relative_rotvecs(pose_quaternions(centre), pose_quaternions(poses))
        w = np.asarray(poses, dtype=np.float64)[..., ROT]
        # log N(d; 0, diag(ws^2)) and log N(w; 0, std^2 I)
        walk = -0.5 * np.sum((d / ws) ** 2, axis=-1) - np.sum(np.log(ws)) - 1.5 * _LOG_2PI
        jump = -0.5 * np.sum(w * w, axis=-1) / self.std ** 2 - 3.0 * np.log(self.std) - 1.5 * _LOG_2PI
        return -np.logaddexp(np.log1p(-self.rate) + walk, np.log(self.rate) + jump)


def log_pose_prior(prev: np.ndarray, poses: np.ndarray, prior_std: np.ndarray,
                   max_rotation: float = np.inf, scale: tuple[float, float] | None = None,
                   reset: RotationReset | None = None) -> np.ndarray:
    """Log of the pose transition density ``p(u_t | u_{t-1})`` (Gaussian random walk; with ``reset``
    its rotation part is the mixture of :class:`RotationReset`).

    Parameters
    ----------
    prev : (E, P) float64
        Mean of the transition for each expert (``u_{t-1}`` for a random walk; see
        :func:`prior_mean`).
    poses : (E, s, P) float64
        Candidate ``u_t``.
    prior_std : (P,) float64
        Standard deviation per tangent component (``inf`` = flat; omitted).
    max_rotation : float
        Radians: the soft wall of :func:`rotation_wall` (``inf`` = none).

    Returns
    -------
    (E, s) float64
    """
    std = np.asarray(prior_std, dtype=np.float64)
    fin = np.isfinite(std)
    if reset is not None:
        fin[ROT] = False  # the rotation's density is the mixture's, added below
    d = box_minus(prev[:, None, :], poses)[..., fin]
    sd = std[fin]
    # log N(d; 0, diag(std^2)) = -1/2 sum (d/std)^2 - sum log std - P'/2 log 2 pi
    const = -np.sum(np.log(sd)) - 0.5 * sd.size * _LOG_2PI
    out = -0.5 * np.sum((d / sd) ** 2, axis=-1) + const
    if reset is not None:
        out = out - reset.neg_log_rotation(prev[:, None, :], poses)
    if np.isfinite(max_rotation):
        out = out - rotation_wall(poses, max_rotation)[0]
    if scale is not None:
        out = out - scale_wall(poses, scale)[0]
    return out


def _fg_weights(tv: TextureView, sigma_w: float) -> np.ndarray:
    # 1 / (sigma_v(i) + sigma_w)
    return 1.0 / (tv.var + sigma_w)


class _Fit:
    """What stays fixed while the poses of one batch of experts are fitted on one image.

    The texel weights ``w = 1 / (sigma_v + sigma_w)`` and, with a gain and bias, the sums of
    the normal equations of :func:`.photometric.gain_bias` that do not involve ``y`` are
    computed once per Gauss-Newton run instead of at every evaluation (the same
    expressions, so the same values); so are the quaternions of the prior's mean.
    """

    def __init__(self, bases: np.ndarray, fd: FrameData, prev: np.ndarray, tv: TextureView, sigma_w: float,
                 lam: np.ndarray, use_background: bool, level_scale: float, photometric: Photometric | None,
                 max_rotation: float, outlier_sq: float, scale: tuple[float, float] | None,
                 temper: float = 1.0) -> None:
        self.bases, self.fd, self.prev, self.tv, self.sigma_w, self.lam = bases, fd, prev, tv, sigma_w, lam
        self.temper = float(temper)
        # h_i as (3, n, k), and as (k, 3 n) and (3, k, n): the shape vertices and the Jacobian come out
        # with the vertices last
        self.h = np.ascontiguousarray(bases.transpose(1, 0, 2))
        self.hk = np.ascontiguousarray(bases.transpose(2, 1, 0).reshape(bases.shape[2], -1))
        self.hT = np.ascontiguousarray(bases.transpose(1, 2, 0))
        self.q_prev = pose_quaternions(prev)
        self.background = bool(tv.has_background and use_background)
        self.level_scale, self.photometric = level_scale, photometric
        self.max_rotation, self.outlier_sq, self.scale = max_rotation, outlier_sq, scale
        self.walls = np.isfinite(max_rotation) or scale is not None
        self.generic = generic_background(fd.image) if tv.generic else None
        self.local = local_background_of(fd, tv.local * level_scale, sigma_w) if tv.local > 0 else None
        self.mu = tv.mean
        self.w = _fg_weights(tv, sigma_w)  # (E, n)
        self.vis = tv.vis
        if tv.vis is not None:
            # the hidden part of each vertex's term: its expectation, E (y - mu_v)^2 / (sigma_v + sigma_w) = 1
            self.hidden = np.sum(1.0 - tv.vis, axis=-1)
        if photometric is not None:
            # normal equations of gain_bias (over the visible vertices): the parts that do not depend on y
            self.la = 1.0 / photometric.gain_std ** 2
            self.wv = self.w if tv.vis is None else self.w * tv.vis
            self.wmu = self.wv * self.mu
            sw = np.sum(self.wv, axis=-1)
            self.sm = np.sum(self.wmu, axis=-1)
            smm = np.sum(self.wmu * self.mu, axis=-1)
            self.a11, self.a22 = smm + self.la, sw + 1.0 / photometric.bias_std ** 2
            self.det = self.a11 * self.a22 - self.sm * self.sm


class _Evaluation:
    """The Gauss-Newton objective (eq. 14 without its second background term) at poses ``u``,
    keeping what its linearisation at any subset of the rows needs.

    Attributes
    ----------
    f : (E,) float64
        ``1/2 sum_i min(w_v (y - mu_v)^2, tau^2) [- 1/2 sum_i w_b (y - mu_b)^2] + 1/2 d^T Lambda d``
        plus the soft walls (:func:`gauss_newton_objective`).
    """

    def __init__(self, fit: _Fit, u: np.ndarray) -> None:
        self.fit, self.u = fit, u
        ls = fit.level_scale
        qu = pose_quaternions(u)
        self.g_r = quaternion_matrices(qu, rows=2)  # (E, 2, 3) = g r
        # h_i c, (E, 3, n): one (1, k) x (k, 3 n) product per expert (a batch of BLAS calls, each
        # expert's alone, so any split of the experts gives the same numbers)
        self.s = (u[:, None, COEF] @ fit.hk).reshape(u.shape[0], 3, -1)
        # x_i = g r (h_i c) + l   (eq. 1), then to the level's pixels
        xy = self.g_r @ self.s  # (E, 2, n)
        x, y = xy[:, 0] + u[:, 3, None], xy[:, 1] + u[:, 4, None]
        if ls != 1.0:
            x, y = x * ls, y * ls
        self.st = st = stencil_xy(x, y, fit.fd.shape)
        yv = st.sample(fit.fd.flat)
        mu, w = fit.mu, fit.w
        if fit.photometric is not None:
            # gain and bias (photometric.gain_bias), r = y - (a mu_v + b)
            sy = (fit.wv * yv).sum(axis=-1)
            smy = (fit.wmu * yv).sum(axis=-1)
            a = ((smy + fit.la) * fit.a22 - fit.sm * sy) / fit.det
            a = np.clip(a, 1.0 / fit.photometric.gain_max, fit.photometric.gain_max)
            b = (sy - a * fit.sm) / fit.a22
            r = yv - (a[:, None] * mu + b[:, None])
        else:
            r = yv - mu
        e2 = w * r * r
        if np.isfinite(fit.outlier_sq):
            # outlier process: vertices beyond the cap cost a constant, so they drop out of the step
            c = np.minimum(e2, fit.outlier_sq)
            self.w_eff = np.where(e2 <= fit.outlier_sq, w, 0.0)
        else:
            c, self.w_eff = e2, w
        vis = fit.vis
        if vis is None:
            f = c.sum(axis=-1)
        else:
            # self-occlusion: v_i of each vertex's term, its expectation (1) for the rest
            f = (vis * c).sum(axis=-1) + fit.hidden
            self.w_eff = self.w_eff * vis
        self.r = r
        if fit.background:
            tv = fit.tv
            assert tv.bg_rows is not None
            self.mb, self.mbx, self.mby, vb = tv.bg_at(st, tv.bg_rows[:, None], with_grad=True)
            self.wb = 1.0 / (vb + fit.sigma_w)
            self.rb = yv - self.mb
            f = f - (self.rb * self.rb * self.wb).sum(axis=-1)
        if fit.generic is not None:
            # the generic background's first term of eq. 14: - sum_i (y(x_i) - m)^2 / s^2
            self.rg = yv - fit.generic[0]
            if vis is not None:
                # a hidden vertex claims no pixel: no likelihood ratio there
                self.rg = self.rg * np.sqrt(vis)
            f = f - fit.generic[1] * (self.rg * self.rg).sum(axis=-1)
        if fit.local is not None:
            # the local background's two terms of eq. 14: - sum_i [(y - M)^2 / V + log V](x_i)
            b = st.sample(fit.local)
            f = f - (b if vis is None else vis * b).sum(axis=-1)
        if fit.temper != 1.0:
            # tempered data term (departure from the paper): its log-likelihood times 1 / kappa
            f = f / fit.temper
        # prior: -log p(u|u_{t-1}) = 1/2 d^T Lambda d (+ the soft walls); d = box_minus(prev, u)
        d = u - fit.prev
        d[:, ROT] = relative_rotvecs(fit.q_prev, qu)
        self.d = d
        out = 0.5 * f + 0.5 * (fit.lam * d * d).sum(axis=-1)
        # the soft walls; their gradient and curvature are needed only where they are touched
        self.wall_r = self.wall_s = False
        if np.isfinite(fit.max_rotation):
            pen = rotation_wall(u, fit.max_rotation)[0]
            out = out + pen
            self.wall_r = bool(pen.any())
        if fit.scale is not None:
            pen = scale_wall(u, fit.scale)[0]
            out = out + pen
            self.wall_s = bool(pen.any())
        self.f = out

    def _jacobian(self, gx: np.ndarray, gy: np.ndarray, sel) -> np.ndarray:
        """``d v(x_i(u [+] delta)) / d delta`` for an image ``v`` of gradient ``(gx, gy)`` (level-0
        pixels) at the points: ``(E', P, n)``.

        With ``q_i = r^T g^T grad_i``: rotation ``s_i x q_i`` (``dx_i/dd_w = -g r [s_i]x``),
        translation ``grad_i``, coefficients ``q_i . h_i`` (:func:`.geometry.projection_jacobian`).
        """
        s, g_r = self.s[sel], self.g_r[sel]
        E, n = gx.shape
        k = self.fit.hT.shape[1]
        q = g_r.transpose(0, 2, 1) @ np.stack([gx, gy], axis=1)  # (E, 3, n)
        J = np.empty((E, 5 + k, n))
        s0, s1, s2 = s[:, 0], s[:, 1], s[:, 2]
        q0, q1, q2 = q[:, 0], q[:, 1], q[:, 2]
        np.subtract(s1 * q2, s2 * q1, out=J[:, 0])
        np.subtract(s2 * q0, s0 * q2, out=J[:, 1])
        np.subtract(s0 * q1, s1 * q0, out=J[:, 2])
        J[:, 3] = gx
        J[:, 4] = gy
        # q_i . h_i for each coefficient: sum over the 3 axes, in order
        hT = self.fit.hT
        Jc = J[:, 5:]
        np.multiply(q[:, 0, None, :], hT[0], out=Jc)
        Jc += q[:, 1, None, :] * hT[1]
        Jc += q[:, 2, None, :] * hT[2]
        return J

    def linearise(self, sel: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Gradient ``(E', P)`` and Gauss-Newton Hessian ``(E', P, P)`` (with the safeguards of the
        module docstring) at the rows ``sel`` (default all)."""
        fit = self.fit
        sl = slice(None) if sel is None else sel
        st = self.st
        if sel is not None:
            st = BilinearStencil(st.idx[sel], st.fx[sel], st.fy[sel], st._x[sel], st._y[sel], fit.fd.shape)
        ls = fit.level_scale
        # d y_t(x_i(u [+] delta)) / d delta = grad y_t(x_i)^T dx_i/d delta  (the gradient images, see module doc)
        gx, gy = st.sample_gradient_images(fit.fd)
        if ls != 1.0:
            gx, gy = gx * ls, gy * ls
        J = self._jacobian(gx, gy, sl)  # (E', P, n)
        w = self.w_eff[sl]
        wr = w * self.r[sl]
        # foreground: g = J^T W r,  H = J^T W J
        g = (J @ wr[:, :, None])[:, :, 0]
        H = (J * w[:, None, :]) @ J.transpose(0, 2, 1)  # a new C-contiguous array
        Hg = None
        if fit.generic is not None:
            # the generic background's term enters with a minus sign, its mean flat:
            # g -= J^T (r_g / s^2),  H -= J^T J / s^2 (limited as the background's, below)
            g -= (J @ (fit.generic[1] * self.rg[sl] * (1.0 if fit.vis is None else np.sqrt(fit.vis[sl])))[:, :, None]
                  )[:, :, 0]
            Jv = J if fit.vis is None else J * np.sqrt(fit.vis[sl])[:, None, :]
            Hg = fit.generic[1] * (Jv @ Jv.transpose(0, 2, 1))
        kappa = fit.temper
        if kappa != 1.0:
            # tempered data term: g and H of 1/kappa times the data's part of eq. 14
            g, H = g / kappa, H / kappa
        P = H.shape[-1]
        diag = H.reshape(H.shape[0], P * P)[:, :: P + 1]  # a view of its diagonals
        # prior: d(u [+] delta) ~ d(u) + delta
        lam, u = fit.lam, self.u[sl]
        g += lam * self.d[sl]
        diag += lam
        if self.wall_r:
            _, gw, hw = rotation_wall(u, fit.max_rotation)
            g[:, ROT] += gw
            H[:, ROT, ROT] += hw
        if self.wall_s:
            _, gc, hc = scale_wall(u, fit.scale)
            g[:, COEF] += gc
            H[:, COEF, COEF] += hc
        # ridge (numerical guard, see module docstring)
        ridge = 1e-10 * diag + 1e-12 * np.maximum(diag.max(axis=1, keepdims=True), 1e-12)
        diag += ridge
        if fit.background:
            # d (y_t(x) - mu_b(x)) / d delta
            bx, by = gx - self.mbx[sl] * ls, gy - self.mby[sl] * ls
            Jb = self._jacobian(bx, by, sl)
            wb = self.wb[sl]
            wrb = wb * self.rb[sl]
            # background term 1 enters with a minus sign: g -= J_b^T W_b r_b, H -= J_b^T W_b J_b
            g = g - (Jb @ wrb[:, :, None])[:, :, 0] / kappa
            Hb = (Jb * wb[:, None, :]) @ Jb.transpose(0, 2, 1) / kappa
            Hg = Hb if Hg is None else Hg / kappa + Hb
        elif Hg is not None:
            Hg = Hg / kappa
        if Hg is not None:
            H = _safe_hessian(H, Hg)
        return g, H


def gauss_newton_objective(
    bases: np.ndarray,
    fd: FrameData,
    prev: np.ndarray,
    poses: np.ndarray,
    tv: TextureView,
    sigma_w: float,
    prior_std: np.ndarray,
    use_background: bool = True,
    level_scale: float = 1.0,
    photometric: Photometric | None = None,
    max_rotation: float = np.inf,
    outlier_sq: float = np.inf,
    scale: tuple[float, float] | None = None,
    temper: float = 1.0,
) -> np.ndarray:
    """The Gauss-Newton objective: eq. 14 without its second background term.

    Parameters
    ----------
    bases : (n, 3, k) float64
    fd : FrameData
    prev : (E, P) float64
        ``u_{t-1}``.
    poses : (E, P) float64
        Candidate ``u_t``.
    tv : TextureView
    sigma_w : float
    prior_std : (P,) float64
    use_background : bool
        Include the first background term (when ``tv`` has a background).
    level_scale : float
        ``fd`` is pyramid level ``l`` and ``level_scale = 2^-l``: vertices are sampled at
        ``level_scale * x_i(u)`` (see :func:`coarse_to_fine_peak`).
    photometric : Photometric, optional
        Fit a gain and bias per expert; the residual is ``y - (a mu_v + b)`` (see
        :mod:`.photometric`).

    Returns
    -------
    (E,) float64
        ``1/2 d^T Lambda d + 1/2 sum_i [w_v (y - mu_v)^2 - w_b (y - mu_b)^2]``
        (``-log p(u|u_{t-1})`` without its constant).
    """
    fit = _Fit(bases, fd, prev, tv, sigma_w, prior_precision(prior_std), use_background, level_scale, photometric,
               max_rotation, outlier_sq, scale, temper)
    return _Evaluation(fit, np.asarray(poses, dtype=np.float64)).f


def _safe_hessian(h_pos: np.ndarray, h_bg: np.ndarray) -> np.ndarray:
    """``h_pos - h_bg`` with its eigenvalues (in the metric of ``h_pos``) floored."""
    L = np.linalg.cholesky(h_pos)
    Li = np.linalg.inv(L)
    A = Li @ h_bg @ Li.transpose(0, 2, 1)
    A = 0.5 * (A + A.transpose(0, 2, 1))
    lam, V = np.linalg.eigh(A)
    m = np.maximum(1.0 - lam, MIN_CURVATURE_FRACTION)
    M = (V * m[:, None, :]) @ V.transpose(0, 2, 1)
    H = L @ M @ L.transpose(0, 2, 1)
    return 0.5 * (H + H.transpose(0, 2, 1))


def linearise_objective(
    bases: np.ndarray,
    fd: FrameData,
    prev: np.ndarray,
    u: np.ndarray,
    tv: TextureView,
    sigma_w: float,
    lam: np.ndarray,
    use_background: bool,
    level_scale: float = 1.0,
    photometric: Photometric | None = None,
    max_rotation: float = np.inf,
    outlier_sq: float = np.inf,
    scale: tuple[float, float] | None = None,
    temper: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton linearisation of :func:`gauss_newton_objective` at ``u``.

    Parameters
    ----------
    bases, fd, prev, tv, sigma_w, use_background
        As in :func:`gauss_newton_objective`.
    u : (E, P) float64
        Linearisation point.
    lam : (P,) float64
        Prior precisions ``1 / std^2`` (0 for an infinite std).
    level_scale, photometric
        As in :func:`gauss_newton_objective` (the gain and bias are held fixed within the
        step: their derivative wrt the pose is not taken).

    Returns
    -------
    g : (E, P) float64
        Gradient wrt the tangent increment at ``u``.
    H : (E, P, P) float64
        Gauss-Newton Hessian (with the safeguards of the module docstring).
    f : (E,) float64
        Objective at ``u``.
    """
    fit = _Fit(bases, fd, prev, tv, sigma_w, lam, use_background, level_scale, photometric, max_rotation,
               outlier_sq, scale, temper)
    ev = _Evaluation(fit, np.asarray(u, dtype=np.float64))
    g, H = ev.linearise()
    return g, H, ev.f


def gauss_newton_peak(
    bases: np.ndarray,
    fd: FrameData,
    prev: np.ndarray,
    tv: TextureView,
    sigma_w: float,
    prior_std: np.ndarray,
    n_iter: int,
    start: np.ndarray | None = None,
    use_background: bool = True,
    level_scale: float = 1.0,
    photometric: Photometric | None = None,
    max_rotation: float = np.inf,
    outlier_sq: float = np.inf,
    scale: tuple[float, float] | None = None,
    final_hessian: bool = True,
    temper: float = 1.0,
) -> GaussNewtonResult:
    """Gauss-Newton to the peak ``u_hat`` of each expert's pose opinion (eq. 12, 14).

    Each step evaluates the objective at the candidate poses of every expert, and builds
    the gradient and Hessian (from the same projected vertices and samples) only for the
    experts whose step is accepted; a rejected expert keeps its linearisation.

    Parameters
    ----------
    bases : (n, 3, k) float64
        Morph bases.
    fd : FrameData
        ``y_t`` and its gradient images.
    prev : (E, P) float64
        ``u_{t-1}`` of each expert (also the starting point unless ``start`` is given).
    tv : TextureView
        Predicted textures.
    sigma_w : float
        Observation noise variance.
    prior_std : (P,) float64
        Pose random-walk standard deviations (``inf`` allowed).
    n_iter : int
        Number of Gauss-Newton steps (the same for every expert).
    start : (E, P) float64, optional
    use_background : bool
        Include the first background term of eq. 14 (the paper's choice); False uses
        the foreground term and the prior only.
    level_scale, photometric
        As in :func:`gauss_newton_objective`.
    final_hessian : bool
        False: the returned ``hessian`` of an expert whose last step was accepted is that of
        the point before it (saves one linearisation when only ``u_hat`` is wanted).

    Returns
    -------
    GaussNewtonResult
    """
    lam = prior_precision(prior_std)
    u = np.array(prev if start is None else start, dtype=np.float64)
    E = u.shape[0]
    step_len = np.ones(E)
    fit = _Fit(bases, fd, prev, tv, sigma_w, lam, use_background, level_scale, photometric, max_rotation,
               outlier_sq, scale, temper)
    ev = _Evaluation(fit, u)
    f = ev.f.copy()
    g, H = ev.linearise()
    n_iter = int(n_iter)
    for it in range(n_iter):
        # Gauss-Newton step: delta = -H^-1 g
        step = -np.linalg.solve(H, g[..., None])[..., 0] * step_len[:, None]
        cand = box_plus(u, step)
        ev = _Evaluation(fit, cand)
        ok = np.isfinite(ev.f) & (ev.f <= f)
        step_len = np.where(ok, np.minimum(1.0, 2.0 * step_len), 0.5 * step_len)
        n_ok = int(np.count_nonzero(ok))
        if n_ok == 0:
            continue
        u[ok] = cand[ok]
        f[ok] = ev.f[ok]
        if final_hessian or it < n_iter - 1:
            # relinearise where the step was taken (elsewhere the point, so g and H, are unchanged);
            # every row when most steps were taken (each row's numbers are its own either way)
            if 2 * n_ok >= E:
                g_all, H_all = ev.linearise()
                g[ok], H[ok] = g_all[ok], H_all[ok]
            else:
                sel = np.flatnonzero(ok)
                g[sel], H[sel] = ev.linearise(sel)
    return GaussNewtonResult(u, H, f)


def search_offsets(radius: float, step: float) -> np.ndarray:
    """Translations ``(G, 2)`` (pixels) of a square grid ``{-radius .. radius}^2`` with spacing ``step``.

    Ordered by distance from ``(0, 0)`` (the first is ``(0, 0)``), then row-major, so that a tie
    in :func:`coarse_to_fine_peak`'s search keeps the start nearest the previous pose.
    """
    if radius <= 0.0:
        return np.zeros((1, 2))
    k = int(np.floor(radius / step + 1e-9))
    v = np.arange(-k, k + 1, dtype=np.float64) * step
    gx, gy = np.meshgrid(v, v)
    off = np.stack([gx.reshape(-1), gy.reshape(-1)], axis=1)
    order = np.argsort(np.hypot(off[:, 0], off[:, 1]), kind="stable")
    return off[order]


def coarse_to_fine_peak(
    bases: np.ndarray,
    pyramid: Sequence[FrameData],
    prev: np.ndarray,
    tv: TextureView,
    sigma_w: float,
    prior_std: np.ndarray,
    n_iter: int,
    start: np.ndarray | None = None,
    use_background: bool = True,
    photometric: Photometric | None = None,
    offsets: np.ndarray | None = None,
    max_rotation: float = np.inf,
    search_stride: int = 1,
    outlier_sq: float = np.inf,
    scale: tuple[float, float] | None = None,
    reset: RotationReset | None = None,
    temper: float = 1.0,
) -> GaussNewtonResult:
    """Coarse-to-fine Gauss-Newton peak of eq. 14 on an image pyramid (departure from the paper).

    The paper runs Gauss-Newton on the frame itself (sec. 3.2.2), which converges only
    from within about the width of the image's features (a few pixels). Here:

    1. on the coarsest level ``L - 1`` of ``pyramid`` (:func:`.image.frame_pyramid`), the
       objective is evaluated at the start translated by each of ``offsets`` (pixels of
       level 0, :func:`search_offsets`; raw intensities, no gain/bias) and each expert keeps
       its lowest (the first on a tie);
    2. ``n_iter`` Gauss-Newton steps on each level from the coarsest to level 0, each level
       starting where the previous one stopped, vertices at ``x_i(u) / 2^l``; with a search
       this is done twice, from the start and from the search's best, and the peak with the
       lower level-0 objective is kept. (Taking the search's best alone made the tracker
       jump to dark background on david_indoor, where the light changes: measured CLE 104 px
       against 4.9 px without a search; the level-0 objective with the gain/bias fit
       compares the two chains fairly.)

    The objective on every level is that of eq. 14 (foreground and prior; the background
    term, if asked for, only on level 0) with the level's blurred image; the pose, the prior
    and the texels are those of level 0. The Laplace covariance is the Hessian at level 0.
    ``u_hat`` stays a deterministic function of the expert's ``u_{t-1}``, textures and
    ``y_t``, so ``g(u | u_hat, alpha Sigma_hat)`` is still the density the samples are drawn
    from and the importance weights of eq. 16 (and the likelihood estimate of eq. 19) need
    no other correction. With one level and no offsets this is :func:`gauss_newton_peak`.

    Parameters
    ----------
    pyramid : sequence of FrameData
        Level 0 (the frame) first.
    offsets : (G, 2) float64, optional
        Translations tried on the coarsest level (None or one row of zeros: no search).
    max_rotation : float
        Soft wall on the rotation angle (:func:`rotation_wall`), on every level.
    outlier_sq : float
        Cap of the per-vertex cost (:func:`robust_cost`), on every level (not in the search).
    scale : (|c_0|, log_max), optional
        Soft wall on the scale (:func:`scale_wall`), on every level and in the search.
    temper : float >= 1
        ``kappa``: the data term is divided by it everywhere (search, every level, the reset's
        comparison); see the module docstring. 1 = eq. 14.
    search_stride : int
        The search evaluates every ``search_stride``-th vertex only (its cost is that of
        ``G`` objective evaluations; the coarsest level has fewer pixels than the head has
        vertices anyway).
    Other parameters as in :func:`gauss_newton_peak`.

    Returns
    -------
    GaussNewtonResult
        At level 0.
    """
    u = np.array(prev if start is None else start, dtype=np.float64)
    if not (use_background and tv.has_background):
        # experts that are copies of one another (resampled children of one parent that drew the
        # same sample: same pose, prior and texels) get the same peak: compute it once
        first, inverse = _distinct_rows(prev, u, tv.mean, tv.var, *(() if tv.vis is None else (tv.vis,)))
        if first.size < u.shape[0]:
            sub = TextureView(mean=tv.mean[first], var=tv.var[first], generic=tv.generic, local=tv.local,
                              vis=None if tv.vis is None else tv.vis[first])
            res = coarse_to_fine_peak(bases, pyramid, prev[first], sub, sigma_w, prior_std, n_iter, u[first],
                                      use_background, photometric, offsets, max_rotation, search_stride, outlier_sq,
                                      scale, reset, temper)
            return GaussNewtonResult(res.u_hat[inverse], res.hessian[inverse], res.objective[inverse],
                                     None if res.reset is None else res.reset[inverse])
    L = len(pyramid)
    fg = TextureView(mean=tv.mean, var=tv.var, generic=tv.generic, local=tv.local, vis=tv.vis)
    chains = (bases, pyramid, prev, tv, fg, sigma_w, prior_std, n_iter, use_background, photometric, max_rotation,
              outlier_sq, scale, offsets, search_stride, temper)
    if offsets is None or len(offsets) <= 1:
        res = _refine(bases, pyramid, prev, tv, fg, sigma_w, prior_std, n_iter, u, use_background, photometric,
                      max_rotation, outlier_sq, scale, temper)
        return res if reset is None else _frontal_chain(res, reset, *chains)
    g_best = _search_best(bases, pyramid[L - 1].image, 0.5 ** (L - 1), prev, u, tv, sigma_w, prior_std, offsets,
                          max_rotation, search_stride, scale, temper)
    res = _two_chains(bases, pyramid, prev, tv, fg, sigma_w, prior_std, n_iter, u, use_background, photometric,
                      max_rotation, outlier_sq, scale, offsets, g_best, temper)
    return res if reset is None else _frontal_chain(res, reset, *chains)


def _search_best(bases: np.ndarray, coarse: np.ndarray, ls: float, prev: np.ndarray, u: np.ndarray,
                 tv: TextureView, sigma_w: float, prior_std: np.ndarray, offsets: np.ndarray, max_rotation: float,
                 search_stride: int, scale: tuple[float, float] | None, temper: float = 1.0) -> np.ndarray:
    """Step 1 of :func:`coarse_to_fine_peak`: for each expert, the index (E,) into ``offsets`` (G, 2) of the
    translation of ``u`` (E, P) with the lowest objective on the coarsest level ``coarse`` (its scale ``ls``
    = ``2^-(L-1)``); the first on a tie."""
    every = slice(None, None, int(search_stride))
    # the search compares raw intensities with an uncapped cost: with a gain and bias fitted
    # at every grid point low-contrast patches matched too, and with the outlier cap most
    # vertices of a motion-blurred face were outliers everywhere (see the module docstring).
    # The candidates differ from u only in l, so the rotated shape g r (h_i c) + l is projected
    # once per expert and only the texture term is evaluated per translation (coarse_search).
    xy = project(bases[every], u)
    # self-occlusion: each vertex's term times its visibility (the rest is the same at every offset)
    vis = 1.0 if tv.vis is None else tv.vis[:, every]
    cost = translation_costs(coarse, xy[..., 0] * ls, xy[..., 1] * ls, offsets * ls,
                             tv.mean[:, every], _fg_weights(tv, sigma_w)[:, every] * vis, SEARCH_BLOCK_VERTICES)
    if tv.generic:
        # the generic background's first term of eq. 14 on this level: - sum_i (y(x_i) - m)^2 / s^2
        gm, gw = generic_background(coarse)
        xs = xy[..., 0] * ls
        cost = cost - translation_costs(coarse, xs, xy[..., 1] * ls, offsets * ls, np.full(xs.shape, gm),
                                        np.full(xs.shape, gw) * vis, SEARCH_BLOCK_VERTICES)
    # the rest of the objective (gauss_newton_objective): prior (only its translation part
    # changes with the offset) and the soft walls
    lam = prior_precision(prior_std)
    d = box_minus(prev, u)
    dt = d[:, None, TRANS] + offsets[None]  # (E, G, 2)
    fixed = 0.5 * (lam * d * d).sum(axis=-1) - 0.5 * (lam[TRANS] * d[:, TRANS] ** 2).sum(axis=-1)
    if temper != 1.0:
        # tempered data term (see _Evaluation)
        cost = cost / temper
    f = 0.5 * cost + 0.5 * (lam[TRANS] * dt * dt).sum(axis=-1) + fixed[:, None]
    if np.isfinite(max_rotation):
        f = f + rotation_wall(u, max_rotation)[0][:, None]
    if scale is not None:
        f = f + scale_wall(u, scale)[0][:, None]
    f = np.where(np.isfinite(f), f, np.inf)
    return np.argmin(f, axis=1)


def _two_chains(bases, pyramid, prev, tv, fg, sigma_w, prior_std, n_iter, u, use_background, photometric,
                max_rotation, outlier_sq, scale, offsets, g_best, temper=1.0) -> GaussNewtonResult:
    """Step 2 of :func:`coarse_to_fine_peak` with a search: each expert refined from ``u`` (E, P) and from
    ``u`` translated by ``offsets[g_best]``, the lower level-0 objective (eq. 14) kept (the first on a tie)."""
    E = u.shape[0]
    # two chains per expert, refined alike: from u_{t-1} and from the search's best start. Where the
    # best is offsets[0] = (0, 0) the second chain would repeat the first bit for bit (the rows are
    # independent), so it is run only for the experts the search moved, in one batch with the
    # first chains (the per-call cost dominates for a shard of a few experts)
    moved = np.flatnonzero(g_best != 0)
    far_start = u[moved].copy()
    far_start[:, TRANS] += offsets[g_best[moved]]
    rows = np.concatenate([np.arange(E), moved])
    both = _refine(bases, pyramid, prev[rows], _rows_view(tv, rows), _rows_view(fg, rows), sigma_w, prior_std,
                   n_iter, np.concatenate([u, far_start]), use_background, photometric, max_rotation, outlier_sq,
                   scale, temper)
    u_hat, hess, obj = both.u_hat[:E].copy(), both.hessian[:E].copy(), both.objective[:E].copy()
    # keep the lower level-0 objective (eq. 14); the local chain on a tie
    pick = both.objective[E:] < obj[moved]
    take = moved[pick]
    u_hat[take] = both.u_hat[E:][pick]
    hess[take] = both.hessian[E:][pick]
    obj[take] = both.objective[E:][pick]
    return GaussNewtonResult(u_hat, hess, obj)


def _frontal_chain(res: GaussNewtonResult, reset: RotationReset, bases, pyramid, prev, tv, fg, sigma_w, prior_std,
                   n_iter, use_background, photometric, max_rotation, outlier_sq, scale, offsets,
                   search_stride, temper=1.0) -> GaussNewtonResult:
    """The peak of :func:`coarse_to_fine_peak` compared with a peak started frontal under the reset
    component of :class:`RotationReset` (found the same way, translation search included), for the
    experts whose prior mean is turned by at least ``reset.min_angle``; the objectives compared (and
    returned) are eq. 14's with the mixture prior."""
    lam_rot = prior_precision(prior_std)[ROT]

    def mixture_objective(obj, centre, u, lam, walk_centre):
        # the chain's objective with its own rotation prior replaced by the mixture's -log density
        d = relative_rotvecs(pose_quaternions(centre), pose_quaternions(u))
        return obj - 0.5 * (lam * d * d).sum(axis=-1) + reset.neg_log_rotation(walk_centre, u)

    obj = mixture_objective(res.objective, prev, res.u_hat, lam_rot, prev)
    flags = np.zeros(prev.shape[0], dtype=bool)
    w = prev[:, ROT]
    sel = np.flatnonzero(np.sqrt((w * w).sum(axis=-1)) >= reset.min_angle)
    if sel.size == 0:
        return GaussNewtonResult(res.u_hat, res.hessian, obj, flags)
    # the reset component: rotation about the identity with std reset.std, the rest as the walk;
    # with an anchor, fitted to the first look's texels
    centre = prev[sel].copy()
    centre[:, ROT] = 0.0
    start = res.u_hat[sel].copy()
    start[:, ROT] = 0.0
    std = np.array(prior_std, dtype=np.float64)
    std[ROT] = reset.std
    anchor = reset.anchor_view(sel.size)
    tv_r = _rows_view(tv, sel) if anchor is None else dataclasses.replace(
        anchor, generic=tv.generic, local=tv.local, vis=None if tv.vis is None else tv.vis[sel])
    fr = coarse_to_fine_peak(bases, pyramid, centre, tv_r, sigma_w, std, n_iter, start,
                             use_background and anchor is None, photometric, offsets, max_rotation, search_stride,
                             outlier_sq, scale, temper=temper)
    obj_f = mixture_objective(fr.objective, centre, fr.u_hat, np.full(3, 1.0 / reset.std ** 2), prev[sel])
    obj_l = obj[sel]
    if anchor is not None:
        # different texels: their Gaussians' normalising terms 1/2 sum log(sigma_v + sigma_w) (eq. 13) count too
        # (tempered with the data term)
        obj_f = obj_f + 0.5 * np.log(anchor.var + sigma_w).sum(axis=-1) / temper
        obj_l = obj_l + 0.5 * np.log(tv.var[sel] + sigma_w).sum(axis=-1) / temper
    pick = obj_f < obj_l
    take = sel[pick]
    u_hat, hess = res.u_hat.copy(), res.hessian.copy()
    u_hat[take], hess[take], obj[take] = fr.u_hat[pick], fr.hessian[pick], obj_f[pick]
    flags[take] = True
    return GaussNewtonResult(u_hat, hess, obj, flags)


def _distinct_rows(*arrays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows that are equal in every array (bytewise): ``first`` (indices of the first of each
    group, ascending) and ``inverse`` (the group of each row), so ``a[first][inverse]`` equals
    ``a`` for every array."""
    seen: dict[bytes, int] = {}
    first: list[int] = []
    inverse = np.empty(arrays[0].shape[0], dtype=np.intp)
    keys = np.concatenate([np.ascontiguousarray(a, dtype=np.float64).reshape(a.shape[0], -1) for a in arrays], axis=1)
    for i, row in enumerate(keys):
        k = row.tobytes()
        j = seen.get(k)
        if j is None:
            j = seen[k] = len(first)
            first.append(i)
        inverse[i] = j
    return np.asarray(first, dtype=np.intp), inverse


def _rows_view(tv: TextureView, rows: np.ndarray) -> TextureView:
    """The texture opinions of the experts ``rows`` (repeats allowed)."""
    return TextureView(mean=tv.mean[rows], var=tv.var[rows], bg_mean=tv.bg_mean, bg_var=tv.bg_var,
                       bg_rows=None if tv.bg_rows is None else tv.bg_rows[rows], psi_b=tv.psi_b,
                       generic=tv.generic, local=tv.local, vis=None if tv.vis is None else tv.vis[rows])


def _refine(bases, pyramid, prev, tv, fg, sigma_w, prior_std, n_iter, u, use_background, photometric,
            max_rotation, outlier_sq, scale, temper=1.0) -> GaussNewtonResult:
    """``n_iter`` Gauss-Newton steps on every level, coarsest first, from ``u`` (only level 0's
    Hessian is kept: the coarser levels pass on their peak)."""
    res = None
    frame_bg = {"generic": tv.generic, "local": tv.local}
    if tv.frame_background:
        # Gauss-Newton climbs the object's term and the prior alone (as without the generic or local
        # background); the peak's objective, which the chains are compared by, has their terms
        tv, fg = (dataclasses.replace(v, generic=False, local=0.0) for v in (tv, fg))
    for lev in range(len(pyramid) - 1, -1, -1):
        res = gauss_newton_peak(
            bases, pyramid[lev], prev, tv if lev == 0 else fg, sigma_w, prior_std, n_iter, start=u,
            use_background=use_background and lev == 0, level_scale=0.5 ** lev,
            photometric=photometric, max_rotation=max_rotation,
            outlier_sq=outlier_sq, scale=scale, final_hessian=lev == 0, temper=temper,
        )
        u = res.u_hat
    assert res is not None
    if frame_bg["generic"] or frame_bg["local"]:
        f = gauss_newton_objective(bases, pyramid[0], prev, res.u_hat, dataclasses.replace(tv, **frame_bg), sigma_w,
                                   prior_std, use_background, 1.0, photometric, max_rotation, outlier_sq, scale, temper)
        res = dataclasses.replace(res, objective=f)
    return res


def laplace_proposal(
    u_hat: np.ndarray,
    hessian: np.ndarray,
    alpha: float,
    n_samples: int,
    rngs: Sequence[np.random.Generator],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw ``s`` samples per expert from ``g(. | u_hat, alpha Sigma_hat)`` (sec. 3.2.2).

    Parameters
    ----------
    u_hat : (E, P) float64
    hessian : (E, P, P) float64
        ``Sigma_hat^-1``, positive definite.
    alpha : float
        Sharpness, ``>= 0`` (``0``: every sample is ``u_hat``; see the module docstring).
    n_samples : int
        ``s``.
    rngs : sequence of E numpy.random.Generator
        Expert ``e`` draws ``rngs[e].standard_normal((s, P))`` and nothing else.

    Returns
    -------
    samples : (E, s, P) float64
        ``u_hat [+] d``, ``d ~ N(0, alpha Sigma_hat)``.
    log_g : (E, s) float64
        Log proposal density of each sample.
    sigma_hat : (E, P, P) float64
        Laplace covariance ``hessian^-1``.
    """
    E, P = u_hat.shape
    if len(rngs) != E:
        raise ValueError(f"need one rng per expert: got {len(rngs)} rngs for {E} experts")
    L = np.linalg.cholesky(hessian)  # H = L L^T
    Li = np.linalg.inv(L)
    # Sigma_hat = H^-1 = L^-T L^-1
    sigma_hat = Li.transpose(0, 2, 1) @ Li
    half_logdet_h = np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=-1)  # 1/2 log|H|
    s = int(n_samples)
    if alpha > 0.0:
        z = np.stack([np.asarray(r.standard_normal((s, P)), dtype=np.float64) for r in rngs])
        # d = sqrt(alpha) L^-T z  ~ N(0, alpha H^-1)   (row vectors: d^T = sqrt(alpha) z^T L^-1)
        d = np.sqrt(alpha) * (z @ Li)
        samples = box_plus(u_hat[:, None, :], d)
        # log g = -P/2 log(2 pi alpha) + 1/2 log|H| - 1/2 |z|^2
        log_g = -0.5 * P * (_LOG_2PI + np.log(alpha)) + half_logdet_h[:, None] - 0.5 * np.sum(z * z, axis=-1)
    else:
        samples = np.repeat(u_hat[:, None, :], s, axis=1)
        log_g = np.repeat((-0.5 * P * _LOG_2PI + half_logdet_h)[:, None], s, axis=1)
    return samples, log_g, 0.5 * (sigma_hat + sigma_hat.transpose(0, 2, 1))


def background_image_terms(frame: np.ndarray, tv: TextureView, sigma_w: float) -> np.ndarray:
    """Whole-image background terms of eq. 13 for each expert of the batch.

    ``B_d = sum_j [(y_t(j) - mu_b(j))^2 / (sigma_b(j) + sigma_w) + log(sigma_b(j) + sigma_w)]``
    over all ``m`` pixels, with the predicted ``sigma_b`` (eq. 10). Computed one expert
    at a time (no ``(E, H, W)`` temporary).

    Returns
    -------
    (E,) float64
    """
    rows, bg_mean, bg_var = tv.bg_rows, tv.bg_mean, tv.bg_var
    assert rows is not None and bg_mean is not None and bg_var is not None
    out = np.empty(len(rows))
    v = np.empty(frame.shape)
    d = np.empty(frame.shape)
    for j, r in enumerate(rows):
        # sigma_b(j) + sigma_w with the predicted sigma_b (eq. 10)
        np.add(bg_var[r], tv.psi_b + sigma_w, out=v)
        np.subtract(frame, bg_mean[r], out=d)
        d *= d
        d /= v
        np.log(v, out=v)
        out[j] = d.sum() + v.sum()
    return out


def log_likelihood(
    bases: np.ndarray,
    fd: FrameData,
    poses: np.ndarray,
    tv: TextureView,
    sigma_w: float,
    bg_image_terms: np.ndarray | None = None,
    photometric: Photometric | None = None,
    outlier_sq: float = np.inf,
) -> np.ndarray:
    """Predictive log-likelihood ``log p(y_t | u_{1:t}, y_{1:t-1})`` (eq. 13) at poses.

    With the background model::

        -m/2 log 2pi - 1/2 sum_i [log(sigma_v(i)+sigma_w) + (y(x_i) - mu_v(i))^2/(sigma_v(i)+sigma_w)]
        - 1/2 B_d + 1/2 sum_i [(y(x_i) - mu_b(x_i))^2/(sigma_b(x_i)+sigma_w) + log(sigma_b(x_i)+sigma_w)]

    (the sum over ``j not in X(u)`` of eq. 13 written as the whole-image sum ``B_d``
    minus the vertex pixels). Without it (uninformative background) the background
    terms are an additive constant common to all experts and poses and are dropped,
    and ``m`` is replaced by ``n``.

    Parameters
    ----------
    bases : (n, 3, k) float64
    fd : FrameData
    poses : (E, s, P) float64
    tv : TextureView
    sigma_w : float
    bg_image_terms : (E,) float64, optional
        :func:`background_image_terms`; required with a background model.
    photometric : Photometric, optional
        The object term uses ``y - (a mu_v + b)`` with the gain and bias fitted per sample
        (:mod:`.photometric`).
    outlier_sq : float
        Cap of each vertex's squared standardised residual (:func:`robust_cost`).

    Returns
    -------
    (E, s) float64
    """
    E, s, P = poses.shape
    n = bases.shape[0]
    flat = poses.reshape(E * s, P)
    # x_i = g r (h_i c) + l (eq. 1), as in _Evaluation
    g_r = quaternion_matrices(pose_quaternions(flat), rows=2)
    xy = g_r @ np.einsum("xnk,ek->exn", np.ascontiguousarray(bases.transpose(1, 0, 2)), flat[:, COEF])
    x = (xy[:, 0] + flat[:, 3, None]).reshape(E, s, n)
    yy = (xy[:, 1] + flat[:, 4, None]).reshape(E, s, n)
    st = stencil_xy(x, yy, fd.shape)
    y = st.sample(fd.flat)
    vv = tv.var + sigma_w  # (E, n)
    mu = tv.mean[:, None, :]
    vis = None if tv.vis is None else tv.vis[:, None, :]
    if photometric is not None:
        # gain_bias with the sums that do not involve y taken once per expert (the same values), over the
        # visible vertices
        w = 1.0 / vv if tv.vis is None else tv.vis / vv
        wmu = w * tv.mean
        la = 1.0 / photometric.gain_std ** 2
        sm = wmu.sum(axis=-1)[:, None]
        a11 = (wmu * tv.mean).sum(axis=-1)[:, None] + la
        a22 = w.sum(axis=-1)[:, None] + 1.0 / photometric.bias_std ** 2
        det = a11 * a22 - sm * sm
        sy = (y * w[:, None, :]).sum(axis=-1)
        smy = (y * wmu[:, None, :]).sum(axis=-1)
        a = np.clip(((smy + la) * a22 - sm * sy) / det, 1.0 / photometric.gain_max, photometric.gain_max)
        b = (sy - a * sm) / a22
        r = y - (a[..., None] * mu + b[..., None])
    else:
        r = y - mu
    rc = robust_cost(r * r / vv[:, None, :], outlier_sq)
    if vis is None:
        fg = rc.sum(axis=-1)
    else:
        # self-occlusion: v_i of each vertex's term, its expectation under the texel's Gaussian (1) for the rest
        fg = (vis * rc).sum(axis=-1) + (1.0 - vis).sum(axis=-1)
    one = 1.0 if vis is None else vis
    if tv.generic:
        # the generic background at the vertices (its normalising terms are the same at every pose)
        gm, gw = generic_background(fd.image)
        fg = fg - gw * (one * (y - gm) ** 2).sum(axis=-1)
    if tv.local > 0:
        # the local background at the vertices, both its terms (its variance changes with the pose)
        fg = fg - (one * st.sample(local_background_of(fd, tv.local, sigma_w))).sum(axis=-1)
    logdet_v = np.sum(np.log(vv), axis=-1)
    if not tv.has_background:
        return -0.5 * n * _LOG_2PI - 0.5 * (fg + logdet_v[:, None])
    if bg_image_terms is None:
        raise ValueError("bg_image_terms is required with a background model")
    m = fd.image.size
    assert tv.bg_rows is not None
    mb, vb = tv.bg_at(st, tv.bg_rows[:, None, None])
    vb = vb + sigma_w
    rb = y - mb
    bgv = np.sum(rb * rb / vb + np.log(vb), axis=-1)
    return -0.5 * m * _LOG_2PI - 0.5 * (fg + logdet_v[:, None]) - 0.5 * bg_image_terms[:, None] + 0.5 * bgv


def log_importance_weights(log_prior: np.ndarray, log_lik: np.ndarray, log_g: np.ndarray) -> np.ndarray:
    """Log importance weights (eq. 16).

    ``log w(d, e) = log p(u^(d,e) | u_{t-1}^(d)) + log p(y_t | u_{1:t-1}^(d), u^(d,e), y_{1:t-1})
    - log g(u^(d,e) | u_hat^(d), alpha Sigma_hat^(d))``

    Parameters
    ----------
    log_prior, log_lik, log_g : (E, s) float64

    Returns
    -------
    (E, s) float64
    """
    # w_t(d,e) = p(u | u_{t-1}) p(y_t | u_{1:t-1}, u, y_{1:t-1}) / g(u | u_hat, alpha Sigma_hat)   (eq. 16)
    return log_prior + log_lik - log_g
