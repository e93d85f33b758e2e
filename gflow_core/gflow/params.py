"""The G-flow tracker's parameters: :class:`GFlowParams`, the only place their defaults live.

The defaults are the shipped tracker's: the built-in face model (``docs/faces.md``) with the
departures from the paper listed in ``docs/trackers.md`` switched on (coarse-to-fine Gauss-Newton
with a translation search, soft walls on rotation and scale, an outlier process per vertex,
contrast-normalised frames, texels reverting toward the first look, a morph prior and a frontal
reset). Two presets name other settings in one place:

* :data:`PAPER` -- the filter of Marks, Hershey, Roddey & Movellan (NIPS 2004) as written: every
  departure off, the generic head. Its special cases (constrained optic flow, template
  matching, :mod:`.special_cases`) start from it.
* :data:`ELLIPSOID` -- the generic rigid head fitted into the box (``gflow track --model
  ellipsoid``): a flatter head, the paper's grey levels with a gain and bias per frame.

:meth:`GFlowParams.config` turns the parameters into the :class:`.filter.GFlowConfig` that
:func:`.filter.propose` and :func:`.filter.update` read, with the settings that depend on the
model and the initial pose (the scale wall's reference, the morph prior's spreads) filled in.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Literal, Mapping

from ..params import Memory, check_memory, make, param

if TYPE_CHECKING:  # the filter is imported when a configuration is made, not with the parameters
    import numpy as np

    from .filter import GFlowConfig
    from .head_model import MorphableModel

__all__ = ["GFlowParams", "PAPER", "ELLIPSOID", "paper_config"]


@dataclass(frozen=True)
class GFlowParams:
    """Every setting of the G-flow tracker, with the shipped tracker's defaults.

    Grey levels are in ``[0, 1]``, so variances are in those units squared; equation numbers are
    the paper's. Each field's help text is in its declaration; ``gflow info gflow`` prints them
    all. Raises ``ValueError`` naming the first parameter it refuses.
    """

    # memory: the peak resident memory of `gflow track caviar1 --tracker gflow --inline --stop 3` grows by 22.2 KB a
    # pose sample of an expert (--samples 100 to 400 with 20 experts; 22.6 KB --samples 20 to 80 with 200), 2026-12-05
    n_experts: int = param(20, "number of experts E", option="--experts",
                           memory=Memory(22_000, "pose sample", times=("n_samples",)))
    n_samples: int = param(10, "pose samples s per expert (sec. 3.2.2)", option="--samples",
                           memory=Memory(22_000, "pose sample", times=("n_experts",)))
    alpha: float = param(1.0, "sharpness of the Laplace proposal N(u_hat, alpha Sigma_hat); 0 = the peak",
                         option="--alpha")
    gn_iterations: int = param(5, "Gauss-Newton steps per frame (eq. 14)")
    sigma_w: float = param(1e-2, "observation noise variance sigma_w (eq. 4)")
    psi_v: float = param(1e-3, "process noise variance of the object texels Psi_v (eq. 4)")
    psi_b: float = param(1e-4, "process noise variance of the background texels Psi_b (eq. 4)")
    v_init_var: float = param(1e-3, "Var(V_1) of the object texels at the first frame (0: a known template)")
    b_init_var: float = param(1e-3, "Var(B_1) of the background pixels visible in the first frame")
    unknown_var: float = param(1.0, "variance of texels not observed at the first frame")
    background: bool = param(False, "model the background texture, one Kalman filter per pixel and expert "
                                    "(off: uninformative background, as in the paper's experiments)",
                             option="--background")
    gn_background: bool = param(False, "Gauss-Newton includes the first background term of eq. 14")
    object_mask: Literal["hull", "vertices"] = param("hull", "pixels the object covers, kept out of the "
                                                             "background update: its hull or its vertices")
    object_mask_margin: float = param(0.2, "the hull enlarged by this fraction about its centre")
    prior_std_rotation: float | tuple[float, ...] = param((0.024, 0.035, 0.020), "std of the pose random walk per "
                                                          "frame, rotation about x, y, z (radians; one or 3 numbers; "
                                                          "inf: none)", inf="none")
    prior_std_translation: float | tuple[float, ...] = param(5.0, "std of the pose random walk per frame, "
                                                                  "translation (px; one or 2 numbers; inf: none)",
                                                             inf="none")
    prior_std_coefficients: float | tuple[float, ...] = param(0.2, "std of the pose random walk per frame, morph "
                                                                   "coefficients (one or k numbers; inf: none)",
                                                              inf="none")
    scale_walk: float = param(0.01, "std of the pose random walk per frame of the scale c_1, a fraction of the "
                                   "initial box's |c_1| (a relative walk of the face's size; replaces "
                                   "prior_std_coefficients' c_1 value; 0: that value)", before=0.0)
    resample_ess_fraction: float = param(1.0, "resample the experts when their ESS < this fraction of E "
                                              "(1: every frame, sec. 3.4)")
    prior_rotation_decay: float = param(0.98, "the prior's mean rotation decays toward the initial one at this "
                                              "rate per frame (1: the paper's random walk)")
    pyramid_levels: int = param(3, "coarse-to-fine levels of Gauss-Newton (1: the paper's single scale)")
    search_radius: float = param(32.0, "translation search on the coarsest level, px (0: none)")
    search_step: float = param(8.0, "spacing of the translation search, px")
    photometric: bool = param(False, "a gain and bias per expert and frame (the ellipsoid's setting: on)")
    photometric_gain_max: float = param(2.0, "the gain is clamped to [1 / max, max]")
    max_rotation_deg: float = param(70.0, "soft wall on the head's rotation from its initial orientation, "
                                          "degrees (inf: none)", inf="none")
    search_stride: int = param(1, "the translation search evaluates every this-many-th vertex")
    outlier_sigmas: float = param(3.0, "a vertex beyond this many standard deviations is an outlier: a constant "
                                       "cost, its texel not updated (inf: none)", inf="none")
    max_scale_change: float = param(1.5, "soft wall on the scale outside [1 / max, max] times the initial box's "
                                         "(inf: none)", inf="none")
    scale_reference: tuple[float, ...] = param((), "the initial morph coefficients the scale wall is relative "
                                                   "to (empty: from the initial box)")
    morph_prior_std: tuple[float, ...] = param((), "stds of the morph prior on c_2..c_k (empty: from "
                                                   "morph_prior and the model)")
    texture_decay: float = param(0.9, "texels revert toward the first look at this rate per frame (1: the "
                                      "paper's random walk)")
    data_temper: float = param(1.0, "the data term's log-likelihood (eq. 13, 14) is divided by this: about the "
                               "number of vertices per independent residual (1: the paper's)")
    generic_background: bool = param(False, "the data term is weighed against a generic background at the vertices: "
                                            "every pixel N(mean, variance of the frame) (eq. 14's first background "
                                            "term; False: the paper's uninformative background)")
    texel_noise_adapt: bool = param(False, "each expert's texel update (eq. 7, 8) observes the frame with the noise its "
                                           "fit shows, max(sigma_w, mean inlier residual^2 - texel variance) (False: "
                                           "sigma_w, the paper's)")
    local_background: float = param(5.0, "the data term is weighed against a local background at the vertices: every "
                                          "pixel N(mean, variance of the frame in a Gaussian window of this std, px, "
                                          "about it) (eq. 14's two background terms; 0: the paper's uninformative "
                                          "background)", before=0.0)
    self_occlusion: float = param(0.0, "vertices the head itself hides: a vertex whose normal faces the camera with a "
                                       "cosine below this counts cos / this of its texture term and texel update "
                                       "(none edge-on or beyond; 0: every vertex visible, the paper's)")
    reset_rate: float = param(0.01, "probability a frame's pose transition turns the head back to frontal")
    reset_std_deg: float = param(20.0, "std of the frontal reset's rotation, degrees")
    reset_min_deg: float = param(10.0, "experts turned at least this far also try a peak started frontal, "
                                       "degrees")
    morph_prior: float = param(0.5, "expressions held near the model's training spread: std morph_prior * "
                                    "spread * c_1 (inf: the paper's random walk)",
                               inf="the paper's random walk")
    contrast_sigma: float = param(5.0, "frames are local-contrast normalised over this many pixels (0: raw "
                                       "grey levels)")
    model: str = param("face", "the morphable model: face (built in), a file from `gflow learn gflow`, or "
                               "empty for the generic ellipsoid head fitted into the box")
    depth_ratio: float = param(1.0, "generic head only: depth semi-axis over width semi-axis")
    head_grid: tuple[int, int] = param((15, 15), "generic head only: (longitudes, latitudes) of its vertices")
    init_jitter: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0), "std of the experts' initial poses about the box's: rotation (rad), translation (px), "
                         "morph coefficients (fraction)")
    occluded_below: float = param(0.6, "without the lost guard: the target is occluded when the fraction of "
                                       "vertices the frame explains falls below this")
    lost_below: float = param(0.3, "without the lost guard: the target is lost when that fraction falls below "
                                   "this")
    lost_guard: bool = param(True, "verify the estimate against the initial box (edges and colour), hold it while "
                                   "the target is hidden, search for it and re-seat the experts where it is "
                                   "found (gflow_core/gflow/guard.py)")
    lost_colour: bool = param(True, "the lost guard weighs the box's colour histogram too (colour frames)")
    lost_witness: bool = param(False, "G-flow's first look witnesses for the box when the edges call it lost: "
                                      "tracked while its misfit is judged the target's against the found frames' "
                                      "and the clutter's and it fits the box better than anything beside it "
                                      "(gflow_core/gflow/guard.py)")
    lost_window: float = param(1.5, "half-width of the first re-detection window, in box sizes")
    lost_growth: float = param(0.1, "the re-detection window widens by this many box sizes a lost frame")
    lost_hold: float = param(1.0, "while the target is held, the experts are kept within this many box sizes of "
                                  "where it was last found (0: wherever G-flow takes them)")
    lost_scales: tuple[float, ...] = param((1.0, 0.93, 1.07), "sizes (multiples of the held size) searched when "
                                                             "re-detecting")
    online_guard: bool = param(False, "the lost guard keeps a correlation filter of the face learnt online where the "
                                      "experts agree with it: it vouches for the experts' box and re-seats them where "
                                      "it places the face away from them (gflow_core/gflow/online_guard.py)")
    online_window: float = param(0.5, "the online guard searches within this many box sizes of the face's last place, "
                                      "plus online_growth a frame period since the last frame seen")
    online_growth: float = param(0.25, "the online guard's search widens by this many box sizes a frame period")
    online_patience: float = param(0.0, "frame periods the online guard must place the face away from the experts "
                                        "before they are re-seated there (0: never)")
    online_apart: float = param(0.25, "the online guard places the face away from the experts where its centre is "
                                      "farther than this many box sizes from theirs in x or y")
    online_cue: float = param(0.0, "sharpness kappa of the online guard's likelihood exp(kappa y) of each pose sample's "
                                   "box, a second cue in the experts' importance weights (0: not a cue)")
    online_floor: float = param(0.1, "weight of the uniform density the online guard's cue is mixed with (the factor "
                                     "it can give one box over another is at most 1 / online_floor)")
    online_mix: float = param(0.0, "share of each expert's pose samples drawn about the online guard's place of the "
                                   "face, the weights corrected for the mixture proposal (ICONDENSATION; "
                                   "gflow_core/gflow/mixture.py; 0: none)")

    def __post_init__(self) -> None:
        self.config()  # every check of GFlowConfig
        if not (math.isfinite(self.depth_ratio) and self.depth_ratio > 0):
            raise ValueError(f"depth_ratio must be positive, got {self.depth_ratio}")
        if not (math.isfinite(self.contrast_sigma) and self.contrast_sigma >= 0):
            raise ValueError(f"contrast_sigma must be finite and >= 0 (0 = off), got {self.contrast_sigma}")
        if math.isnan(self.morph_prior) or self.morph_prior <= 0:
            raise ValueError(f"morph_prior must be > 0 (inf = none), got {self.morph_prior}")
        if len(self.head_grid) != 2 or min(self.head_grid) < 2:
            raise ValueError(f"head_grid must be at least (2, 2), got {self.head_grid}")
        if len(self.init_jitter) != 3 or not all(math.isfinite(v) and v >= 0 for v in self.init_jitter):
            raise ValueError(f"init_jitter must be three finite numbers >= 0, got {self.init_jitter}")
        if not (math.isfinite(self.scale_walk) and self.scale_walk >= 0):
            raise ValueError(f"scale_walk must be finite and >= 0 (0: prior_std_coefficients' own), got {self.scale_walk}")
        if not (math.isfinite(self.lost_hold) and self.lost_hold >= 0):
            raise ValueError(f"lost_hold must be finite and >= 0 (0: the experts are not kept), got {self.lost_hold}")
        if not (self.lost_window > 0 and self.lost_growth >= 0 and self.lost_scales
                and all(math.isfinite(v) and v > 0 for v in self.lost_scales)):
            raise ValueError(f"lost_window must be positive, lost_growth >= 0 and lost_scales positive, got "
                             f"{self.lost_window}, {self.lost_growth}, {self.lost_scales}")
        if not (self.online_window > 0 and self.online_growth >= 0 and self.online_patience >= 0
                and self.online_apart > 0 and math.isfinite(self.online_window) and math.isfinite(self.online_growth)
                and math.isfinite(self.online_apart) and math.isfinite(self.online_patience)):
            raise ValueError(f"online_window and online_apart must be positive, online_growth and online_patience "
                             f">= 0, got {self.online_window}, {self.online_apart}, {self.online_growth}, "
                             f"{self.online_patience}")
        if not (math.isfinite(self.online_cue) and self.online_cue >= 0 and 0 < self.online_floor <= 1):
            raise ValueError(f"online_cue must be finite and >= 0 (0: not a cue) and online_floor in (0, 1], got "
                             f"{self.online_cue}, {self.online_floor}")
        if not 0.0 <= self.online_mix <= 1.0:
            raise ValueError(f"online_mix must be in [0, 1] (0: no samples about the online model's place), got "
                             f"{self.online_mix}")
        if self.online_mix > 0 and self.background:
            raise ValueError("online_mix needs background off (the filter, where the weights are corrected, keeps no "
                             "background textures)")
        if not 0.0 <= self.lost_below <= self.occluded_below <= 1.0:
            raise ValueError(f"need 0 <= lost_below <= occluded_below <= 1, got {self.lost_below}, "
                             f"{self.occluded_below}")
        check_memory(self)

    def config(self, model: MorphableModel | None = None, pose0: np.ndarray | None = None) -> GFlowConfig:
        """The filter's configuration; with the model and its initial pose ``(P,)``, the settings that
        depend on them filled in.

        * ``max_scale_change`` finite and no ``scale_reference``: the reference is ``c_0``, the
          initial pose's morph coefficients (the wall is relative to the initial box's scale);
        * ``scale_walk`` > 0: the random walk's std of the scale ``c_1`` is ``scale_walk * |c_1|`` at
          the initial pose (the other coefficients keep ``prior_std_coefficients``);
        * ``morph_prior`` finite, no ``morph_prior_std`` and a learned model with ``k > 1``:
          ``m_j = morph_prior * morph_std_j * |c_1|`` at the initial pose.

        Raises ``ValueError`` for settings that do not fit the model (the coefficient stds' length).
        """
        import numpy as np

        from .filter import GFlowConfig
        from .geometry import COEF

        cfg = GFlowConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(GFlowConfig)})
        if model is None:
            return cfg
        if pose0 is None:
            raise ValueError("config(model) needs the initial pose too")
        cfg.prior_std(model.n_bases)  # the coefficient stds must match k
        if self.scale_walk > 0:
            # std of c_1's walk: scale_walk * |c_1| at the initial box (the face's size changes by a fraction a frame)
            c = np.broadcast_to(np.asarray(cfg.prior_std_coefficients, dtype=np.float64), (model.n_bases,)).copy()
            c[0] = self.scale_walk * abs(float(pose0[COEF][0]))
            cfg = dataclasses.replace(cfg, prior_std_coefficients=tuple(float(v) for v in c))
        if math.isfinite(cfg.max_scale_change) and not cfg.scale_reference:
            cfg = dataclasses.replace(cfg, scale_reference=tuple(float(v) for v in pose0[COEF]))
        if (math.isfinite(self.morph_prior) and not cfg.morph_prior_std and model.morph_std is not None
                and model.n_bases > 1):
            # m_j = morph_prior * (training spread of c_j / c_1) * c_1 at the initial box
            m = self.morph_prior * np.maximum(model.morph_std[1:], 1e-9) * abs(float(pose0[COEF][0]))
            cfg = dataclasses.replace(cfg, morph_prior_std=tuple(float(v) for v in m))
        cfg.prior_std(model.n_bases)  # the morph prior's length must match k too
        return cfg


#: the paper's filter: every departure off, the generic head (with :class:`GFlowParams`'s other defaults)
PAPER: Mapping[str, Any] = MappingProxyType({
    "sigma_w": 1e-3, "psi_v": 1e-4, "prior_std_rotation": 0.1, "prior_std_translation": 10.0,
    "prior_std_coefficients": 2.0, "prior_rotation_decay": 1.0, "pyramid_levels": 1, "search_radius": 0.0,
    "search_step": 4.0, "max_rotation_deg": math.inf, "outlier_sigmas": math.inf, "max_scale_change": math.inf,
    "texture_decay": 1.0, "reset_rate": 0.0, "morph_prior": math.inf, "contrast_sigma": 0.0, "model": "",
    "lost_guard": False, "local_background": 0.0, "scale_walk": 0.0,
})

#: the generic rigid head fitted into the box (``--model ellipsoid``): a flatter head, the paper's grey levels
#: with a gain and bias per frame, texels as a random walk, rotation within 30 degrees
ELLIPSOID: Mapping[str, Any] = MappingProxyType({
    "model": "", "depth_ratio": 0.6, "sigma_w": 1e-3, "psi_v": 3e-4, "texture_decay": 1.0, "contrast_sigma": 0.0,
    "photometric": True, "reset_rate": 0.0, "max_rotation_deg": 30.0, "prior_std_rotation": 0.05,
    "local_background": 0.0, "scale_walk": 0.0,
})


def paper_config(**changes: Any) -> GFlowConfig:
    """The :class:`GFlowConfig` of the paper's filter (:data:`PAPER`) with ``changes``."""
    return make(GFlowParams, PAPER, **changes).config()
