"""Filter stage of the contour particle filter: weighs proposals by eq. 7 and resamples.

Inputs: ``features`` of frame t (the chamfer image) and ``proposals`` for frame t.
Outputs: ``particles`` (the resampled posterior of t, which the proposal stage turns into
the proposals of t+1) and ``estimate`` (MAP state, box, posterior summary, ESS).

Initialisation (first frame): with no learned model this is the chamfer tracker of the
runtime issue: the template contour is the edge pixels inside ``init`` (x, y, w, h), the
model is M2 with K = 1 and likelihood exp(-lambda rho). With a learned M2 model (resource
``model``, contour exemplars) the exemplars, sigma_k and d_k come from the model and
``init`` places it: alpha_0 = (box centre, 0, s) with s the box size over the model's
reference size, exemplar indices drawn from pi, and the first frame is weighed at once.
The estimate's box is then the bounding box of the MAP exemplar under its transform,
T_alpha x~_k (sec. 5.1.2: X^_t = argmax p_t(X_t), taken over the particles).

Transfer to video the model was not learned on (departures, :mod:`gflow_core.m2.appearance_metric`):
frame 0's estimate is the ``init`` box itself; on frame 0 the learned kernels are widened so
the init box is a typical match (``calibrate``, :func:`gflow_core.m2.kernel.calibrate_sigma`);
with a model that has appearance exemplars (``appearance``) each particle's chamfer kernel is
multiplied by an appearance kernel (orientation-channel correlation under T_alpha of the
reference box, nearest of the learned exemplars and a bounded online bank that starts with
the init box's region and adds the estimate's region on confident frames, ``online``,
``online_every``, ``confident_r``). The widened sigmas and the bank are part of the snapshot.

Shape of the target (departure, :mod:`gflow_core.m2.target_shape`): with ``fit_shape`` the
learned model's item frame (exemplar contours, reference box, appearance grid) is stretched
to the ``init`` box's aspect ratio, area kept (a caviar1 pedestrian model on a face kept a
tall box: success 0.02 on jumping). With ``box: reference`` (default) the estimate's box is
the reference box under the MAP alpha (centre u, size s * ref_size, so frame 0's box is the
init box); ``box: exemplar`` is the paper's bounding box of T_alpha x~_k.

Lost target (departure: the paper is silent; :mod:`gflow_core.m2.lost`): each tracked frame's
estimate is verified against the initial box by the correlation of edge-orientation channels,
and judged from the distributions of that distance (the target's, chi-squared as in the
paper's sec. 3, and the clutter's around it, :mod:`gflow_core.visibility`). A lost target
(state ``lost``) has the estimate of the last found frame held, the particles kept within
``lost_window`` box sizes of it, and the initial box searched for over a window that widens by
``lost_growth`` box sizes a frame up to the whole frame, at the sizes ``lost_scales``; a
candidate that looks as the target did resumes tracking from it (state ``redetect``). The online
bank is not updated while lost. ``lost_guard: false`` is the paper's filter. The estimate's
``confidence`` is P(visible) of the verification and its ``target_state`` is ``tracked``,
``occluded`` (lost, the search still local) or ``lost`` (the search covers the whole frame);
without the guard they keep their defaults (``tracked``, 1).

Blank frames (sec. 5.1.2, fig. 7): a frame whose edge map has fewer than ``min_edges``
edge pixels carries no evidence; the particles coast on the dynamics (state ``coast``),
"forced to rely on the prior". Weighing such a frame by eq. 7 would not be neutral with a
learned model: every rho is the same large value, and -rho / 2 sigma_k^2 - d_k log sigma_k
then favours the exemplars with the widest kernels.

Bad input: a missing or unusable feature frame makes the filter coast as well, and the
problem is reported; it never stops the stream.

State for ``snapshot()`` / ``restore()``: the K = 1 template (when there is no learned
model), the resampled particle cloud, the calibrated kernel widths and the online bank,
the lost guard's distance distributions, held estimate and anchor, and counters, as msgpack of a
small Struct (version 3; version-1 and -2 snapshots still restore, with a fresh guard).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import msgspec
import numpy as np

from gflow_core import similarity
from gflow_core.m2 import dynamics as dyn
from gflow_core.m2.appearance_metric import (OnlineBank, appearance_log_lik, bank_update, new_bank,
                                             sample_patches_near)
from gflow_core.m2.dynamics import sample_categorical
from gflow_core.m2.kernel import calibrate_sigma
from gflow_core.m2 import lost as lostmod
from gflow_core.m2.lost import Anchor, LostParams, LostState
from gflow_core.m2.model import M2Model
from gflow_core.m2.target_shape import fit_to_box
from gflow_core.m2.tracking import (ContourExemplars, ParticleCloud, curve_box, init_particles, posterior,
                                    template_from_edges, weigh)
from gflow_core.particles import weight_histogram
from gflow_core.visibility import ChiSquare

from .base import Output, Params, Stage, StageInputError
from .messages import Estimate, Features, Message, MessageError, NDArray, Particles
from .particle_proposal import cloud_of, particles_msg
from .rng import frame_rng

__all__ = ["FilterStage", "FilterParams"]

PURPOSE_INIT = 0x1417
PURPOSE_RESAMPLE = 0x2E5A
PURPOSE_INIT_K = 0x1418
SNAPSHOT_VERSION = 3


class FilterParams(Params):
    """Particle filter settings.

    init : (x, y, w, h) initial box of the target, 0-based pixels.
    particles : number of particles N.
    lam : lambda of the K = 1 chamfer likelihood exp(-lambda rho) (no learned model).
    max_points : template points kept from the edges inside the box (no learned model).
    init_spread : std of (ux, uy, theta, log s) of the initial cloud.
    model : path of a learned M2 model with contour exemplars (empty: the K = 1 chamfer tracker).
    min_edges : a frame with fewer edge pixels is blank: no evidence, coast on the dynamics.
    appearance : with a learned model that has appearance exemplars, multiply the chamfer
        kernel by the appearance kernel (:mod:`gflow_core.m2.appearance_metric`).
    online : bound of the online appearance exemplar bank (0: no online exemplars).
    online_every : at most one online exemplar added every this many frames.
    confident_r : the estimate is confident (its region may become an online exemplar) when
        its appearance correlation with the nearest exemplar is at least this.
    calibrate : widen the learned kernels so the initial box is a typical match on frame 0
        (:func:`gflow_core.m2.kernel.calibrate_sigma`).
    scale_prior : std of a prior N(0, .) on log s of the K = 1 chamfer tracker (0: none).
    lost_guard : verify the estimate against the initial box and hold, search and re-detect a
        lost target (:mod:`gflow_core.m2.lost`; false: no guard, the paper's filter).
    lost_window : half-width of the hold window and of the first re-detection window, in box sizes.
    lost_growth : the re-detection window widens by this many box sizes a lost frame.
    lost_scales : sizes (multiples of the held size) searched when re-detecting (1.0 first).
    fit_shape : stretch a learned model's item frame to the init box's aspect ratio.
    box : "reference" (the reference box under alpha) or "exemplar" (bounding box of T_alpha x~_k).
    """

    init: tuple[float, float, float, float] | None = None
    particles: int = 500
    lam: float = 0.5
    max_points: int = 200
    init_spread: tuple[float, float, float, float] = (2.0, 2.0, 0.01, 0.01)
    seed: int = 0
    model: str = ""
    min_edges: int = 1
    appearance: bool = True
    online: int = 6
    online_every: int = 5
    confident_r: float = 0.6
    calibrate: bool = True
    scale_prior: float = 0.0
    lost_guard: bool = True
    lost_window: float = 1.5
    lost_growth: float = 0.1
    lost_scales: tuple[float, ...] = (1.0,)
    fit_shape: bool = True
    box: str = "reference"

    def __post_init__(self) -> None:
        if not self.lost_window > 0 or self.lost_growth < 0 or not self.lost_scales or min(self.lost_scales) <= 0:
            raise ValueError(f"lost_window must be positive, lost_growth >= 0 and lost_scales positive, got "
                             f"{self.lost_window}, {self.lost_growth}, {self.lost_scales}")
        if self.online < 0 or self.online_every < 1:
            raise ValueError(f"online must be >= 0 and online_every >= 1, got {self.online}, {self.online_every}")
        if not -1.0 <= self.confident_r <= 1.0:
            raise ValueError(f"confident_r must be a correlation in [-1, 1], got {self.confident_r}")
        if self.particles < 1:
            raise ValueError(f"particles must be >= 1, got {self.particles}")
        if not self.lam > 0:
            raise ValueError(f"lam must be positive, got {self.lam}")
        if self.init is not None and not (self.init[2] > 0 and self.init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got {self.init}")
        if self.min_edges < 0:
            raise ValueError(f"min_edges must be >= 0, got {self.min_edges}")
        if self.box not in ("reference", "exemplar"):
            raise ValueError(f"box must be 'reference' or 'exemplar', got {self.box!r}")


class _LastSummary(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    seq: int
    alpha: list[float]
    ess: float
    state: str
    k: int


class _BankSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    patches: NDArray  # (n, th, tw, C) float32
    usage: NDArray  # (n,) float64
    frame: NDArray  # (n,) int64
    last_add: int


class _FilterSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything the filter carries from one frame to the next."""

    version: int
    initialised: bool
    template: NDArray | None  # (P, 2) float64, K = 1 chamfer template; None with a learned model
    alpha: NDArray | None  # (N, 4) float64 resampled posterior
    k: NDArray | None  # (N,) int64
    log_w: NDArray | None  # (N,) float64
    steps: int
    warned: bool
    last: _LastSummary | None
    bank: _BankSnapshot | None = None  # online appearance exemplars (version 2)
    sigma: NDArray | None = None  # (K,) chamfer kernel widths after calibration on frame 0
    app_sigma: NDArray | None = None  # (K,) appearance kernel widths after calibration
    lost: tuple[float, float, int, int] | None = None  # lost guard (version 2, not restored): level, var, found, lost_run
    lost_target: tuple[float, float, int] | None = None  # lost guard: moments m1, m2, count of the target's distance
    lost_clutter: tuple[float, float, int] | None = None  # ... and of the clutter's best distance
    lost_runs: tuple[int, int] = (0, 0)  # lost guard: found frames, consecutive lost frames
    held: tuple[float, ...] | None = None  # lost guard: box (x, y, w, h), alpha (4) and k of the last found frame
    anchor: NDArray | None = None  # lost guard: (th, tw, 4) channels of the initial box
    judged: tuple[float, str] = (1.0, "tracked")  # confidence and target_state of the last estimate


class FilterStage(Stage):
    kind = "particle.filter"
    Params = FilterParams
    inputs = {"features": Features, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"features"})

    def __init__(self, params: FilterParams, ctx) -> None:
        super().__init__(params, ctx)
        if params.init is None:
            raise ValueError("the filter stage needs an initial box: set init: [x, y, w, h]")
        learned = ctx.resources.get("model")
        if learned is not None:
            if not isinstance(learned, M2Model):
                raise ValueError(f"stage {ctx.name!r}: model {params.model!r} is a {type(learned).__name__}, "
                                 "not an M2 model")
            if learned.kind != "curve":
                raise ValueError(f"stage {ctx.name!r}: model {params.model!r} has {learned.metric} patch "
                                 "exemplars; use the patch.filter stage (graph m2_patch) for patch models")
            if params.fit_shape:
                # the model's item frame stretched to the user's box shape (gflow_core.m2.target_shape)
                learned = fit_to_box(learned, params.init)
        self.learned: M2Model | None = learned
        self.learned_ex: ContourExemplars | None = learned.to_contour_exemplars() if learned is not None else None
        # the appearance kernels beside chamfer, and the online bank (set on the first frame)
        self.app = learned.appearance if learned is not None and params.appearance else None
        self.bank: OnlineBank | None = None
        self.model: ContourExemplars | None = None  # set on the first frame
        self.template: np.ndarray | None = None
        self.last_cloud: ParticleCloud | None = None
        self.ref_size = np.array(params.init[2:], dtype=np.float64)
        # the lost guard's orientation channels of a frame depend on the frame alone: a stage
        # process computes them ahead, on the host's second thread (stages.base, Stage.prepare)
        self.prepare_ports = frozenset({"features"}) if params.lost_guard else frozenset()  # type: ignore[misc]
        self.last: dict = {}
        self.steps = 0
        self.warned = False
        self.lost = LostState()
        self.anchor: Anchor | None = None
        self.judged: tuple[float, str] = (1.0, "tracked")  # confidence and target_state of the last estimate

    def _guard_params(self) -> LostParams | None:
        p: FilterParams = self.params  # type: ignore[assignment]
        return LostParams(window=p.lost_window, growth=p.lost_growth) if p.lost_guard else None

    def prepare(self, port: str, msg: Message) -> np.ndarray:
        """The lost guard's (H, W, 4) orientation channels of a feature frame's grey image."""
        assert isinstance(msg, Features)
        return lostmod.channels(msg.grey.array())

    def _set_anchor(self, feat: Features, seq: int) -> None:
        """The lost guard's anchor: orientation channels of the initial box on the first frame."""
        p: FilterParams = self.params  # type: ignore[assignment]
        gp = self._guard_params()
        grey = self._grey(feat, seq) if gp is not None else None
        if gp is not None and grey is not None:
            self.anchor = lostmod.anchor_of(self.prepared("features", feat), p.init, gp)  # type: ignore[arg-type]

    def _guard(self, seq: int, feat: Features, post, state: str):
        """Verify the estimate against the initial box; hold, bound and re-detect while lost
        (:mod:`gflow_core.m2.lost`). Returns the (possibly changed) posterior and state."""
        gp = self._guard_params()
        if gp is None or self.anchor is None or state != "track":
            if state == "coast" and self.judged[1] == "tracked":
                self.judged = (0.0, "tracked")  # no evidence this frame
            return post, state
        grey = self._grey(feat, seq)
        if grey is None:
            return post, state
        ch = self.prepared("features", feat)
        box = self._box(post.map_alpha, post.map_k)
        obs = lostmod.observe(ch, self.anchor, box, gp)
        self.lost, vis, lost = lostmod.judge(self.lost, obs, (*box, *post.map_alpha, post.map_k), gp)
        if not lost:
            self.judged = (vis.visible if self.lost.found > gp.warmup else 1.0 - vis.hidden, "tracked")
            return post, state
        held = self.lost.held
        assert held is not None
        h_box, h_alpha, h_k = held[:4], np.array(held[4:8]), int(held[8])
        p: FilterParams = self.params  # type: ignore[assignment]
        cand, cvis, covers = lostmod.search(ch, self.anchor, h_box, self.lost, gp, tuple(p.lost_scales),  # type: ignore[arg-type]
                                            None if obs.clutter is None else obs.clutter[1])
        alpha = post.resampled.alpha.copy()
        centre = np.array([h_box[0] + (h_box[2] - 1) / 2.0, h_box[1] + (h_box[3] - 1) / 2.0])
        if cand is not None and cvis is not None and cvis.present:
            # re-detected: the held state moved onto the candidate (and to its size), the particles with it
            f = float(np.exp(cand.log_f))
            shift = cand.centre - centre
            new_alpha = h_alpha.copy()
            new_alpha[:2] += shift
            new_alpha[3] *= f
            alpha[:, 3] *= f
            alpha[:, :2] = lostmod.bound_positions(alpha[:, :2] - post.mean_alpha[:2] + new_alpha[:2],
                                                   (float(new_alpha[0]), float(new_alpha[1])),
                                                   (0.25 * h_box[2] * f, 0.25 * h_box[3] * f))
            w, h = h_box[2] * f, h_box[3] * f
            new_box = (h_box[0] + shift[0] + (h_box[2] - w) / 2.0, h_box[1] + shift[1] + (h_box[3] - h) / 2.0, w, h)
            self.lost = lostmod.found_again(self.lost, cand.r, (*new_box, *new_alpha, h_k), gp)
            self.judged = (cvis.visible, "tracked")
            state = "redetect"
        else:
            # hold the last found estimate; keep the particles within the window around it
            new_alpha = h_alpha
            half = (gp.window * h_box[2], gp.window * h_box[3])
            alpha[:, :2] = lostmod.bound_positions(alpha[:, :2] - centre + h_alpha[:2],
                                                   (float(h_alpha[0]), float(h_alpha[1])), half)
            self.judged = (vis.visible, "lost" if covers else "occluded")
            state = "lost"
        post = replace(post, map_alpha=new_alpha, map_k=h_k,
                       resampled=ParticleCloud(alpha=alpha, k=post.resampled.k, log_w=post.resampled.log_w))
        return post, state

    # the first frame only needs features; afterwards both
    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"features"}) if self.model is None else frozenset(self.inputs)

    def _chamfer(self, feat: Features | None, seq: int) -> np.ndarray | None:
        if feat is None:
            self.report("missing_features", f"frame {seq}: no features arrived; coasting on the dynamics", seq)
            return None
        try:
            cham = feat.chamfer.array()
        except MessageError as e:
            self.report("bad_features", f"frame {seq}: {e}; coasting", seq)
            return None
        if cham.ndim != 2 or cham.size == 0 or not np.isfinite(cham).all():
            self.report("bad_features", f"frame {seq}: chamfer image is {cham.shape} {cham.dtype} with "
                        f"non-finite values or wrong shape; coasting", seq)
            return None
        return cham

    def _blank(self, feat: Features) -> bool:
        """Fewer than ``min_edges`` edge pixels: a blank frame (sec. 5.1.2, fig. 7)."""
        p: FilterParams = self.params  # type: ignore[assignment]
        if p.min_edges <= 0:
            return False
        try:
            edges = feat.edges.array()
        except MessageError:
            return False  # the chamfer image decides whether the frame is usable
        return int(np.count_nonzero(edges)) < p.min_edges

    def _check_profile(self, feat: Features, seq: int) -> None:
        m = self.learned
        if m is None or self.warned:
            return
        if feat.profile != m.profile or (m.profile == "truncated" and not np.isclose(feat.g0, m.g0)):
            self.warned = True
            self.report("profile_mismatch", f"frame {seq}: features use the {feat.profile} chamfer profile "
                        f"(g0 {feat.g0:g}) but the model was learned with {m.profile} (g0 {m.g0:g}); sigma_k and "
                        "d_k do not match these distances (set preprocess.profile / g0)", seq)

    def _initialise(self, seq: int, feat: Features) -> list[Output]:
        p: FilterParams = self.params  # type: ignore[assignment]
        x, y, w, h = p.init  # type: ignore[misc]
        try:
            edges = feat.edges.array()
        except MessageError as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        H, W = edges.shape
        if x >= W or y >= H or x + w <= 0 or y + h <= 0:
            raise StageInputError(f"initial box {p.init} lies outside the {W}x{H} frame")
        if self.learned is not None:
            return self._initialise_learned(seq, feat)
        try:
            pts = template_from_edges(edges, p.init, p.max_points)  # type: ignore[arg-type]
        except ValueError as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        self.template = pts
        self.model = ContourExemplars.single(pts, p.lam, dyn.random_walk(1.0, 0.01, 0.01))
        alpha0 = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0, 0.0, 1.0])
        rng = frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_INIT)
        cloud = init_particles(alpha0, 0, p.particles, np.array(p.init_spread), rng)
        self.last_cloud = cloud
        self._set_anchor(feat, seq)
        est = self._estimate(feat.header, alpha0, 0, alpha0, np.zeros(4), float(p.particles), 0.0, "init")
        return [("particles", particles_msg(feat.header, "posterior", cloud)), ("estimate", est)]

    def _initialise_learned(self, seq: int, feat: Features) -> list[Output]:
        """Place the learned model on the initial box, draw k ~ pi, and weigh the first frame."""
        p: FilterParams = self.params  # type: ignore[assignment]
        assert self.learned is not None and self.learned_ex is not None
        self._check_profile(feat, seq)
        self.model = self.learned_ex
        alpha0 = self.learned.alpha_from_box(p.init)  # type: ignore[arg-type]
        rng = frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_INIT)
        cloud = init_particles(alpha0, 0, p.particles, np.array(p.init_spread), rng)
        # k_0 ~ pi (sec. 4.1, step 6: the mixture weights are the prior over exemplars)
        k0 = sample_categorical(self.model.pi, p.particles, frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_INIT_K))
        cloud = ParticleCloud(alpha=cloud.alpha, k=k0, log_w=np.zeros(p.particles))
        self._calibrate(seq, feat, alpha0)
        self._set_anchor(feat, seq)
        if self.app is not None and p.online > 0:
            grey = self._grey(feat, seq)
            if grey is not None:
                # online slot 0: the region of the user's box, kept for the whole track
                z0 = sample_patches_near(grey, alpha0, self.learned.ref_size, self.app.res)[0]
                self.bank = new_bank(z0, seq)
        return self._update(seq, feat, cloud, first=True)

    def _calibrate(self, seq: int, feat: Features, alpha0: np.ndarray) -> None:
        """Widen the kernels so the user's box on frame 0 is a typical match (:func:`calibrate_sigma`)."""
        p: FilterParams = self.params  # type: ignore[assignment]
        assert self.learned is not None and self.model is not None
        if not p.calibrate:
            return
        K = self.model.K
        at = ParticleCloud(alpha=np.tile(alpha0, (K, 1)), k=np.arange(K), log_w=np.zeros(K))
        cham = self._chamfer(feat, seq)
        if cham is not None and not self._blank(feat):
            # rho_0 = min_k rho(T_alpha0 x~_k, z_0)
            rho0 = float(weigh(at, self.model, cham)[1].min())
            self.model = replace(self.model, sigma=calibrate_sigma(self.model.sigma, self.model.d, rho0))
        grey = self._grey(feat, seq) if self.app is not None else None
        if grey is not None and self.app is not None:
            z = sample_patches_near(grey, alpha0, self.learned.ref_size, self.app.res)
            rho_a0 = float(1.0 - appearance_log_lik(np.repeat(z, K, axis=0), np.arange(K), self.app, None)[1].max())
            self.app = replace(self.app, sigma=calibrate_sigma(self.app.sigma, self.app.d, rho_a0))

    def _grey(self, feat: Features, seq: int) -> np.ndarray | None:
        try:
            grey = feat.grey.array()
        except MessageError as e:
            self.report("bad_features", f"frame {seq}: {e}; chamfer only", seq)
            return None
        if grey.ndim != 2 or min(grey.shape) < 3:
            self.report("bad_features", f"frame {seq}: grey image has shape {grey.shape}; chamfer only", seq)
            return None
        return grey

    def _box(self, alpha: np.ndarray, k: int) -> tuple[float, float, float, float]:
        p: FilterParams = self.params  # type: ignore[assignment]
        if self.learned is not None and p.box == "reference":
            # the reference box under alpha (its centre u and size s * ref_size; theta is left out)
            w, h = self.learned.ref_size * alpha[3]
            return (float(alpha[0] - (w - 1) / 2.0), float(alpha[1] - (h - 1) / 2.0), float(w), float(h))
        if self.learned is not None:
            # the bounding box of the MAP exemplar under its transform, T_alpha x~_k
            assert self.model is not None
            return curve_box(similarity.apply(alpha, self.model.curves[k, : self.model.n_points[k]]))
        # the initial box carried by T_alpha: centre u, size s * (w0, h0)
        w, h = self.ref_size * alpha[3]
        return (float(alpha[0] - (w - 1) / 2.0), float(alpha[1] - (h - 1) / 2.0), float(w), float(h))

    def _estimate(self, header, alpha, k, mean, std, ess, log_ev, state) -> Estimate:
        assert self.model is not None
        p: FilterParams = self.params  # type: ignore[assignment]
        if state == "init" and self.learned is not None:
            # frame 0's estimate is the box the user gave, placed by alpha_0 (the posterior
            # of frame 0 only chooses the exemplar)
            alpha = self.learned.alpha_from_box(p.init)  # type: ignore[arg-type]
        box = tuple(float(v) for v in p.init) if state == "init" else self._box(alpha, k)  # type: ignore[union-attr]
        contour = similarity.apply(alpha, self.model.curves[k, : self.model.n_points[k]]).astype(np.float32)
        self.last = {"seq": header.seq, "alpha": np.round(alpha, 3).tolist(), "ess": round(ess, 1), "state": state,
                     "k": int(k)}
        confidence, target_state = (1.0, "tracked") if state == "init" or self._guard_params() is None else self.judged
        return Estimate(header=header, box=box, alpha=tuple(float(v) for v in alpha), k=int(k),
                        mean=tuple(float(v) for v in mean), std=tuple(float(v) for v in std), ess=float(ess),
                        n=self.params.particles, log_evidence=float(log_ev), contour=NDArray.of(contour), state=state,  # type: ignore[attr-defined]
                        confidence=float(confidence), target_state=target_state)

    def _update(self, seq: int, feat: Features | None, cloud: ParticleCloud, first: bool = False) -> list[Output]:
        """Weigh ``cloud`` on the frame by eq. 7 (or coast), summarise, resample."""
        p: FilterParams = self.params  # type: ignore[assignment]
        assert self.model is not None
        rng = frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_RESAMPLE)
        cham = self._chamfer(feat, seq)
        if cham is None:
            log_lik = np.zeros(cloud.n)
            state = "coast"
        elif feat is not None and self._blank(feat):
            # no evidence: p(y_t | X_t) is the same for every X_t, so the posterior is the prior
            log_lik = np.zeros(cloud.n)
            state = "coast"
        else:
            # log p(y | alpha, k) = -rho / (2 sigma_k^2) - d_k log sigma_k            (eq. 7)
            log_lik, _ = weigh(cloud, self.model, cham)
            state = "track"
            if p.scale_prior > 0 and self.learned is None:
                # explicit prior on the size, log s ~ N(0, scale_prior^2) (s relative to the first box):
                # the directed chamfer distance alone is smallest for a template shrunk onto dense edges
                log_lik = log_lik - np.log(cloud.alpha[:, 3]) ** 2 / (2.0 * p.scale_prior ** 2)
        grey = None
        if state == "track" and self.app is not None and feat is not None:
            grey = self._grey(feat, seq)
            if grey is not None:
                # x log K_app(rho_a(a_k or the online bank, z_alpha))      (product of the two kernels)
                assert self.learned is not None
                Z = sample_patches_near(grey, cloud.alpha, self.learned.ref_size, self.app.res)
                log_lik = log_lik + appearance_log_lik(Z, cloud.k, self.app, self.bank)[0]
        if first:
            state = "init"
        post = posterior(cloud, log_lik, self.model.K, rng, p.particles)
        if feat is not None and not first:
            post, state = self._guard(seq, feat, post, state)
        if grey is not None and self.bank is not None and not first and state == "track":
            self._update_bank(seq, grey, post.map_alpha, post.map_k)
        self._diagnose(cloud, log_lik)
        header = feat.header if feat is not None else self.header(seq, 0)
        self.last_cloud = post.resampled
        self.steps += 1
        est = self._estimate(header, post.map_alpha, post.map_k, post.mean_alpha, post.std_alpha, post.ess,
                             post.log_evidence, state)
        return [("particles", particles_msg(header, "posterior", post.resampled)), ("estimate", est)]

    def _update_bank(self, seq: int, grey: np.ndarray, alpha: np.ndarray, k: int) -> None:
        """Count the estimate's nearest online exemplar; add its region when confident."""
        p: FilterParams = self.params  # type: ignore[assignment]
        assert self.learned is not None and self.app is not None and self.bank is not None
        z = sample_patches_near(grey, alpha, self.learned.ref_size, self.app.res)
        _, r_best, nearest = appearance_log_lik(z, np.array([k]), self.app, self.bank)
        self.bank = bank_update(self.bank, z[0], int(nearest[0]), bool(r_best[0] >= p.confident_r), seq,
                                bound=p.online, every=p.online_every)

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        feat = inputs.get("features")
        if self.model is None:
            if not isinstance(feat, Features):
                raise StageInputError(f"frame {seq}: cannot initialise without features")
            return self._initialise(seq, feat)
        prop = inputs.get("proposals")
        if isinstance(prop, Particles):
            cloud = cloud_of(prop)
        else:
            # The proposals of this frame were lost: weigh the last posterior instead, so the
            # proposal -> filter cycle keeps turning.
            self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
            cloud = self.last_cloud
        if cloud.k.size and cloud.k.max() >= self.model.K:
            raise StageInputError(f"proposals {seq}: exemplar index {int(cloud.k.max())} beyond the model's "
                                  f"K={self.model.K}")
        return self._update(seq, feat if isinstance(feat, Features) else None, cloud)

    def _diagnose(self, cloud: ParticleCloud, log_lik: np.ndarray) -> None:
        """Weights before resampling, for ``summary()`` (stepping); not part of any output."""
        lw = cloud.log_w + log_lik
        if not np.isfinite(lw).any():
            self.diagnostics = {}
            return
        best = int(np.argmax(lw))
        self.diagnostics = {
            "weights_N*W": weight_histogram(lw),
            "best_particle": {"alpha": np.round(cloud.alpha[best], 3).tolist(), "k": int(cloud.k[best]),
                              "log_lik": round(float(log_lik[best]), 4)},
            "log_lik_range": [round(float(log_lik.min()), 4), round(float(log_lik.max()), 4)],
        }

    def summary(self) -> dict:
        """The last estimate (seq, MAP alpha, ESS, state), the histogram of the relative weights
        N W_i before resampling, and the best particle with its log-likelihood."""
        return dict(self.last, steps=self.steps, **getattr(self, "diagnostics", {}))

    # -- snapshot / restore ---------------------------------------------------------------
    def snapshot(self) -> bytes:
        c = self.last_cloud
        last = (_LastSummary(seq=int(self.last["seq"]), alpha=list(self.last["alpha"]), ess=float(self.last["ess"]),
                             state=str(self.last["state"]), k=int(self.last["k"])) if self.last else None)
        snap = _FilterSnapshot(
            version=SNAPSHOT_VERSION, initialised=self.model is not None,
            template=NDArray.of(self.template) if self.template is not None else None,
            alpha=NDArray.of(c.alpha) if c is not None else None, k=NDArray.of(c.k) if c is not None else None,
            log_w=NDArray.of(c.log_w) if c is not None else None, steps=self.steps, warned=self.warned, last=last,
            bank=None if self.bank is None else _BankSnapshot(
                patches=NDArray.of(self.bank.patches), usage=NDArray.of(self.bank.usage),
                frame=NDArray.of(self.bank.frame), last_add=self.bank.last_add),
            sigma=NDArray.of(self.model.sigma) if self.learned is not None and self.model is not None else None,
            app_sigma=NDArray.of(self.app.sigma) if self.app is not None else None,
            lost_target=(self.lost.target.m1, self.lost.target.m2, self.lost.target.n),
            lost_clutter=(self.lost.clutter.m1, self.lost.clutter.m2, self.lost.clutter.n),
            lost_runs=(self.lost.found, self.lost.lost_run), judged=self.judged,
            held=self.lost.held, anchor=None if self.anchor is None else NDArray.of(self.anchor.channels))
        return msgspec.msgpack.encode(snap)

    def restore(self, data: bytes) -> None:
        p: FilterParams = self.params  # type: ignore[assignment]
        name = self.ctx.name
        try:
            snap = msgspec.msgpack.decode(data, type=_FilterSnapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"stage {name!r}: not a particle.filter snapshot: {e}") from None
        if snap.version not in (1, 2, SNAPSHOT_VERSION):  # 1: no online bank, learned widths; 1-2: older guard
            raise ValueError(f"stage {name!r}: filter snapshot version {snap.version}, expected {SNAPSHOT_VERSION}")
        if snap.initialised and (snap.template is None) != (self.learned is not None):
            raise ValueError(f"stage {name!r}: the snapshot was taken " +
                             ("without" if snap.template is not None else "with") + " a learned model, but this "
                             "stage runs " + ("with" if self.learned is not None else "without") + " one")
        try:
            cloud = (ParticleCloud(alpha=snap.alpha.array().copy(), k=snap.k.array().copy(),
                                   log_w=snap.log_w.array().copy())
                     if snap.alpha is not None and snap.k is not None and snap.log_w is not None else None)
            template = snap.template.array().copy() if snap.template is not None else None
            bank = None
            if snap.bank is not None:
                bank = OnlineBank(patches=snap.bank.patches.array().copy(), usage=snap.bank.usage.array().copy(),
                                  frame=snap.bank.frame.array().copy(), last_add=snap.bank.last_add)
                if self.app is None or bank.patches.shape[1:] != self.app.patches.shape[1:]:
                    raise ValueError("online exemplars that do not fit this model's appearance exemplars")
            sigma = snap.sigma.array().copy() if snap.sigma is not None else None
            app_sigma = snap.app_sigma.array().copy() if snap.app_sigma is not None else None
        except (MessageError, ValueError) as e:
            raise ValueError(f"stage {name!r}: bad filter snapshot: {e}") from None
        if snap.initialised and cloud is None:
            raise ValueError(f"stage {name!r}: filter snapshot is initialised but holds no particles")
        if not snap.initialised:
            self.model = None
            self.app = self.learned.appearance if self.learned is not None and p.appearance else None
        elif template is not None:
            self.model = ContourExemplars.single(template, p.lam, dyn.random_walk(1.0, 0.01, 0.01))
        else:
            self.model = self.learned_ex
            app0 = self.learned.appearance if self.learned is not None and p.appearance else None
            try:
                if sigma is not None and self.model is not None:
                    self.model = replace(self.model, sigma=sigma)
                self.app = replace(app0, sigma=app_sigma) if app0 is not None and app_sigma is not None else app0
            except ValueError as e:
                raise ValueError(f"stage {name!r}: bad filter snapshot: {e}") from None
        if self.model is not None and cloud is not None and cloud.k.size and cloud.k.max() >= self.model.K:
            raise ValueError(f"stage {name!r}: snapshot particles use exemplar {int(cloud.k.max())} but the model "
                             f"has K={self.model.K}")
        self.template = template
        self.bank = bank
        self.last_cloud = cloud
        self.steps = snap.steps
        self.warned = snap.warned
        # a snapshot of the older guard (version 1-2, a level and thresholds) restores with a fresh one
        self.lost = (LostState() if snap.lost_target is None or snap.lost_clutter is None else
                     LostState(target=ChiSquare(*snap.lost_target), clutter=ChiSquare(*snap.lost_clutter),
                               found=snap.lost_runs[0], lost_run=snap.lost_runs[1],
                               held=None if snap.held is None else tuple(snap.held)))
        self.judged = (float(snap.judged[0]), str(snap.judged[1]))
        self.anchor = None
        if snap.anchor is not None and p.init is not None:
            try:
                ch = snap.anchor.array().copy()
            except MessageError as e:
                raise ValueError(f"stage {name!r}: bad filter snapshot: {e}") from None
            if ch.ndim != 3:
                raise ValueError(f"stage {name!r}: bad filter snapshot: anchor of shape {ch.shape}")
            self.anchor = Anchor(channels=ch, size=(float(p.init[2]), float(p.init[3])), res=(ch.shape[1], ch.shape[0]))
        self.last = ({"seq": snap.last.seq, "alpha": list(snap.last.alpha), "ess": snap.last.ess,
                      "state": snap.last.state, "k": snap.last.k} if snap.last is not None else {})
