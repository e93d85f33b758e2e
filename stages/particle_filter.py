"""Filter stage of the contour particle filter: weighs proposals by eq. 7 and resamples.

An adapter of :class:`gflow_core.contour.tracker.ContourFilter`, where the mathematics below
lives; its parameters are every field of :class:`gflow_core.contour.params.ContourParams`
(derived from it, defaults included) plus ``init``, ``seed`` and ``model``.

Inputs: ``features`` of frame t (the chamfer image) and ``proposals`` for frame t.
Outputs: ``particles`` (the resampled posterior of t, which the proposal stage turns into
the proposals of t+1) and ``estimate`` (MAP state, box, posterior summary, ESS).

Initialisation (first frame): with no learned model this is the chamfer tracker: the
template contour is the edge pixels inside ``init`` (x, y, w, h), the
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
estimate is verified against the initial box by the correlation of edge-orientation channels
and, where the features carry the frame's colour bins (the preprocess stage's ``colour``, on in
the chamfer and m2 graphs), by the distance of the box's colour histogram to the initial box's
(``lost_colour``), and judged from the distributions of those distances (the target's,
chi-squared as in the paper's sec. 3, and the clutter's around it, :mod:`gflow_core.visibility`). A lost target
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
the lost guard's distance distributions, held estimate and anchor, the chamfer tracker's first
template and the frame its template was last taken at (template update, :mod:`gflow_core.contour.template`),
and counters, as msgpack of a small Struct (version 5; version-1 and -2 snapshots still restore, with a
fresh guard, version-3 ones with a guard that weighs no colour, and versions 1-4, from before the
template update, with their template as the first one).
"""

from __future__ import annotations

import functools
import math
from typing import Any, ClassVar, Mapping

import msgspec
import numpy as np

from gflow_core.contour.params import ChamferParams, ContourParams, M2Params
from gflow_core.contour.features_filter import FEATURE_FILTER
from gflow_core.contour.tracker import ContourObservation, ContourSetup, ContourState, restore_model, setup
from gflow_core.m2 import lost as lostmod
from gflow_core.m2.appearance_metric import OnlineBank
from gflow_core.m2.lost import LostState
from gflow_core.m2.tracking import ParticleCloud
from gflow_core.particles import weight_histogram
from gflow_core.tracker import Estimate as TrackerEstimate
from gflow_core.tracker import FrameRng

from .base import Output, StageContext, StageInputError
from .box_tracker import BoxFilterSpec, BoxFilterStage, cloud_of
from .messages import ColourFeatures, Estimate, Features, Header, Message, MessageError, NDArray, Particles
from .lost_snapshot import pack_guard, unpack_anchor, unpack_lost
from .tracker_params import StageFields, stage_params

__all__ = ["FilterStage", "FilterParams", "FilterFields", "ChamferFilterStage", "ChamferFilterParams",
           "M2FilterStage", "M2FilterParams"]

SNAPSHOT_VERSION = 5


class FilterFields(StageFields, frozen=True):
    """What the filter stage takes besides the tracker's parameters.

    init : (x, y, w, h) initial box of the target, 0-based pixels.
    seed : random seed (frame ``t`` draws from ``[seed, crc32(stream), t, purpose]``).
    model : path of a learned M2 model with contour exemplars (empty: the K = 1 chamfer tracker).
    """

    init: tuple[float, float, float, float] | None = None
    seed: int = 0
    model: str = ""

    def check(self, tracker: Any) -> None:
        if self.init is not None and not (self.init[2] > 0 and self.init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got {self.init}")
        if self.init is not None and not all(math.isfinite(v) for v in self.init):
            raise ValueError(f"init box has NaN or infinite values: {self.init}")


FilterParams = stage_params("FilterParams", ContourParams, FilterFields, __name__,
                            "Particle filter settings: every field of :class:`gflow_core.contour.params.ContourParams` "
                            "(see it for meanings), ``init``, ``seed`` and ``model``.")
ChamferFilterParams = stage_params("ChamferFilterParams", ChamferParams, FilterFields, __name__,
                                   "The chamfer tracker's filter: every field of "
                                   ":class:`gflow_core.contour.params.ChamferParams`, ``init`` and ``seed``.")
M2FilterParams = stage_params("M2FilterParams", M2Params, FilterFields, __name__,
                              "The M2 tracker's filter: every field of :class:`gflow_core.contour.params.M2Params`, "
                              "``init``, ``seed`` and ``model`` (a learned contour model, required).")


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
    anchor_colour: NDArray | None = None  # lost guard (version 4): (N_BINS,) colour histogram of the initial box
    lost_ctarget: tuple[float, float, int] = (0.0, 0.0, 0)  # ... moments of the target's colour distance
    lost_cclutter: tuple[float, float, int] = (0.0, 0.0, 0)  # ... and of the clutter's best colour distance
    first: NDArray | None = None  # (P, 2) float64 (version 5): the first K = 1 template, T_1 of the drift correction
    template_clock: int = 0  # (version 5) the frame the template update counts its frames from
    first_anchor: NDArray | None = None  # (th, tw, 4) float32 (version 5): the lost guard's channels of the first box
    first_fit: tuple[float, int] = (0.0, 0)  # (version 5) sum and count of the first template's rho on the first frames


def _spec(name: str, params: type[ContourParams]) -> BoxFilterSpec:
    """The contour trackers' filter on the generic stage: the protocol object over the features
    (:data:`gflow_core.contour.features_filter.FEATURE_FILTER`); the proposal is the proposed cloud
    itself, and the snapshot this module's own (``snapshot`` / ``restore`` below)."""
    return BoxFilterSpec(name=name, tracker=FEATURE_FILTER, params=params, proposal=lambda cloud, dt: cloud,
                         particles=lambda st: st.cloud.alpha, alpha_of=lambda a: a, particles_of=lambda a: a,
                         snapshot=None)


class FilterStage(BoxFilterStage):
    kind = "particle.filter"
    Params = FilterParams
    box = _spec("contour", ContourParams)
    #: whether the stage needs a learned model (the ``model`` resource)
    needs_model: ClassVar[bool] = False
    port = "features"
    inputs = {"features": Features, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"features"})
    prepare_ports = frozenset()

    def __init__(self, params: Any, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        if self.needs_model and ctx.resources.get("model") is None:
            raise ValueError(f"stage {ctx.name!r}: {self.kind} needs a learned model: set model: MODEL.npz "
                             f"(`gflow learn m2`)")
        try:
            self.setup: ContourSetup = setup(self.core, params.init, ctx.resources.get("model"))
        except ValueError as e:
            raise ValueError(f"stage {ctx.name!r}: model {params.model!r}: {e}") from None
        self.resources = {"setup": self.setup}
        # the lost guard's orientation channels of a frame depend on the frame alone: a stage
        # process computes them ahead, on the host's second thread (stages.base, Stage.prepare)
        self.prepare_ports = frozenset({"features"}) if self.core.lost_guard else frozenset()
        self.warned = False
        self.diagnostics: dict = {}

    def prepare(self, port: str, msg: Message) -> Any:
        """The lost guard's (H, W, 4) orientation channels of a feature frame's grey image."""
        assert isinstance(msg, Features)
        return lostmod.channels(msg.grey.array())

    def _chamfer(self, feat: Features, seq: int) -> np.ndarray | None:
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
        if self.core.min_edges <= 0:
            return False
        try:
            edges = feat.edges.array()
        except MessageError:
            return False  # the chamfer image decides whether the frame is usable
        return int(np.count_nonzero(edges)) < self.core.min_edges

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

    def _observe(self, feat: Any, seq: int) -> ContourObservation | None:
        """The tracker's observation of a features message (None, reported: none arrived). The grey
        image is read only where a cue needs it: the appearance kernels, the lost guard."""
        if feat is None:
            self.report("missing_features", f"frame {seq}: no features arrived; coasting on the dynamics", seq)
            return None
        cham = self._chamfer(feat, seq)
        blank = cham is not None and self._blank(feat)
        wants_grey = self.core.lost_guard or (self.setup.app0 is not None)
        grey = self._grey(feat, seq) if wants_grey else None
        channels = functools.cache(lambda: self.prepared("features", feat)) if grey is not None else None
        try:
            edges = feat.edges.array()
        except MessageError:
            edges = None
        bins = self._bins(feat, grey, seq) if self.core.lost_guard and self.core.lost_colour else None
        return ContourObservation(edges=edges, chamfer=cham, blank=blank, grey=grey, channels=channels, bins=bins)

    def _bins(self, feat: Features, grey: np.ndarray | None, seq: int) -> np.ndarray | None:
        """The frame's colour bins (None: not sent -- a recording made before them -- or unusable, reported:
        the lost guard then weighs the edges alone)."""
        if not isinstance(feat, ColourFeatures) or grey is None:
            return None
        try:
            return feat.bins_array(grey.shape)
        except MessageError as e:
            self.report("bad_features", f"frame {seq}: {e}; edges only", seq)
            return None

    def _check_profile(self, feat: Features, seq: int) -> None:
        m = self.setup.learned
        if m is None or self.warned:
            return
        if feat.profile != m.profile or (m.profile == "truncated" and not np.isclose(feat.g0, m.g0)):
            self.warned = True
            self.report("profile_mismatch", f"frame {seq}: features use the {feat.profile} chamfer profile "
                        f"(g0 {feat.g0:g}) but the model was learned with {m.profile} (g0 {m.g0:g}); sigma_k and "
                        "d_k do not match these distances (set preprocess.profile / g0)", seq)

    def _first_observation(self, seq: int, feat: Any) -> ContourObservation:
        if not isinstance(feat, Features):
            raise StageInputError(f"frame {seq}: cannot initialise without features")
        try:
            feat.edges.array()
        except MessageError as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        self._check_profile(feat, seq)
        obs = self._observe(feat, seq)
        assert obs is not None
        return obs

    def _started(self, obs: Any) -> None:
        pass

    def _proposed(self, seq: int, prop: Message | None) -> ParticleCloud:
        if isinstance(prop, Particles):
            cloud = cloud_of(prop)
        else:
            # The proposals of this frame were lost: weigh the last posterior instead, so the
            # proposal -> filter cycle keeps turning.
            self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
            cloud = self.state.cloud
        if cloud.k.size and cloud.k.max() >= self.state.model.K:
            raise StageInputError(f"proposals {seq}: exemplar index {int(cloud.k.max())} beyond the model's "
                                  f"K={self.state.model.K}")
        return cloud

    def _coast(self, proposed: Any, rng: FrameRng) -> tuple[Any, TrackerEstimate]:
        """No features arrived: the proposals weighed by no evidence (the posterior is the prior)."""
        return self.box.tracker.update(self.core, self.state, proposed, None, rng)

    def _last(self, header: Header, est: TrackerEstimate) -> dict:
        e = est.extras
        return {"seq": header.seq, "alpha": np.round(np.asarray(e["alpha"]), 3).tolist(), "ess": round(e["ess"], 1),
                "state": est.phase, "k": int(e["k"])}

    def _posterior(self) -> ParticleCloud:
        return self.state.cloud

    def _outputs(self, header: Header, est: TrackerEstimate, proposed: Any = None) -> list[Output]:
        """The posterior and the estimate messages (and the weights' diagnostics of ``proposed``)."""
        if proposed is not None:
            self._diagnose(proposed, np.asarray(est.extras["log_lik"]))
        return super()._outputs(header, est)

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
        return dict(self.last, steps=self.steps, **self.diagnostics)

    # -- snapshot / restore ---------------------------------------------------------------
    def snapshot(self) -> bytes:
        st = self.state
        c = st.cloud if st is not None else None
        last = (_LastSummary(seq=int(self.last["seq"]), alpha=list(self.last["alpha"]), ess=float(self.last["ess"]),
                             state=str(self.last["state"]), k=int(self.last["k"])) if self.last else None)
        lost = st.lost if st is not None else LostState()
        snap = _FilterSnapshot(
            version=SNAPSHOT_VERSION, initialised=st is not None,
            template=NDArray.of(st.template) if st is not None and st.template is not None else None,
            alpha=NDArray.of(c.alpha) if c is not None else None, k=NDArray.of(c.k) if c is not None else None,
            log_w=NDArray.of(c.log_w) if c is not None else None, steps=self.steps, warned=self.warned, last=last,
            bank=None if st is None or st.bank is None else _BankSnapshot(
                patches=NDArray.of(st.bank.patches), usage=NDArray.of(st.bank.usage),
                frame=NDArray.of(st.bank.frame), last_add=st.bank.last_add),
            sigma=NDArray.of(st.model.sigma) if st is not None and self.setup.learned is not None else None,
            app_sigma=NDArray.of(st.app.sigma) if st is not None and st.app is not None else None,
            judged=st.judged if st is not None else (1.0, "tracked"),
            first=NDArray.of(st.first) if st is not None and st.first is not None else None,
            template_clock=st.template_clock if st is not None else 0,
            first_anchor=NDArray.of(st.first_anchor) if st is not None and st.first_anchor is not None else None,
            first_fit=st.first_fit if st is not None else (0.0, 0),
            **pack_guard(None if st is None else st.anchor, lost))
        return msgspec.msgpack.encode(snap)

    def restore(self, data: bytes) -> None:
        p = self.params
        name = self.ctx.name
        try:
            snap = msgspec.msgpack.decode(data, type=_FilterSnapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"stage {name!r}: not a particle.filter snapshot: {e}") from None
        # 1: no online bank, learned widths; 1-2: older guard; 3: no colour in the guard (it restores without);
        # 1-4: no template update (the template is the first one)
        if snap.version not in (1, 2, 3, 4, SNAPSHOT_VERSION):
            raise ValueError(f"stage {name!r}: filter snapshot version {snap.version}, expected {SNAPSHOT_VERSION}")
        learned = self.setup.learned
        if snap.initialised and (snap.template is None) != (learned is not None):
            raise ValueError(f"stage {name!r}: the snapshot was taken " +
                             ("without" if snap.template is not None else "with") + " a learned model, but this "
                             "stage runs " + ("with" if learned is not None else "without") + " one")
        try:
            cloud = (ParticleCloud(alpha=snap.alpha.array().copy(), k=snap.k.array().copy(),
                                   log_w=snap.log_w.array().copy())
                     if snap.alpha is not None and snap.k is not None and snap.log_w is not None else None)
            template = snap.template.array().copy() if snap.template is not None else None
            first = snap.first.array().copy() if snap.first is not None else template
            if first is not None and (first.ndim != 2 or first.shape[1] != 2 or first.shape[0] < 1):
                raise ValueError(f"first template of shape {first.shape}, not (P, 2)")
            first_anchor = snap.first_anchor.array().copy() if snap.first_anchor is not None else None
            bank = None
            if snap.bank is not None:
                bank = OnlineBank(patches=snap.bank.patches.array().copy(), usage=snap.bank.usage.array().copy(),
                                  frame=snap.bank.frame.array().copy(), last_add=snap.bank.last_add)
                if self.setup.app0 is None or bank.patches.shape[1:] != self.setup.app0.patches.shape[1:]:
                    raise ValueError("online exemplars that do not fit this model's appearance exemplars")
            sigma = snap.sigma.array().copy() if snap.sigma is not None else None
            app_sigma = snap.app_sigma.array().copy() if snap.app_sigma is not None else None
        except (MessageError, ValueError) as e:
            raise ValueError(f"stage {name!r}: bad filter snapshot: {e}") from None
        if snap.initialised and cloud is None:
            raise ValueError(f"stage {name!r}: filter snapshot is initialised but holds no particles")
        self.steps = snap.steps
        self.warned = snap.warned
        self.last = ({"seq": snap.last.seq, "alpha": list(snap.last.alpha), "ess": snap.last.ess,
                      "state": snap.last.state, "k": snap.last.k} if snap.last is not None else {})
        if not snap.initialised or cloud is None:
            self.state = None
            return
        try:
            model, app = restore_model(self.setup, self.core, template, sigma, app_sigma)
        except ValueError as e:
            raise ValueError(f"stage {name!r}: bad filter snapshot: {e}") from None
        if cloud.k.size and cloud.k.max() >= model.K:
            raise ValueError(f"stage {name!r}: snapshot particles use exemplar {int(cloud.k.max())} but the model "
                             f"has K={model.K}")
        # a snapshot of the older guard (version 1-2, a level and thresholds) restores with a fresh one
        lost = (LostState() if snap.lost_target is None or snap.lost_clutter is None else
                unpack_lost(snap.lost_target, snap.lost_clutter, snap.lost_runs, snap.held, snap.lost_ctarget,
                            snap.lost_cclutter))
        anchor = None
        if p.init is not None:
            try:
                anchor = unpack_anchor(snap.anchor, snap.anchor_colour, (float(p.init[2]), float(p.init[3])))
            except ValueError as e:
                raise ValueError(f"stage {name!r}: bad filter snapshot: {e}") from None
        if first_anchor is None and template is not None and anchor is not None:
            first_anchor = anchor.channels  # before version 5 the anchor was never taken again
        if first_anchor is not None and (anchor is None or first_anchor.shape != anchor.channels.shape):
            raise ValueError(f"stage {name!r}: bad filter snapshot: first anchor of shape {first_anchor.shape}, not "
                             f"the anchor's")
        self.state = ContourState(self.setup, model, cloud, template=template, app=app, bank=bank, lost=lost,
                                  anchor=anchor, judged=(float(snap.judged[0]), str(snap.judged[1])),
                                  first=first, template_clock=snap.template_clock, first_anchor=first_anchor,
                                  first_fit=(float(snap.first_fit[0]), int(snap.first_fit[1])))


class ChamferFilterStage(FilterStage):
    """The chamfer tracker's filter (graph ``chamfer``): its parameters derive from ``ChamferParams``."""

    kind = "chamfer.filter"
    Params = ChamferFilterParams
    box = _spec("chamfer", ChamferParams)


class M2FilterStage(FilterStage):
    """The M2 tracker's filter (graph ``m2``): its parameters derive from ``M2Params``; a learned
    contour model is required."""

    kind = "m2.filter"
    Params = M2FilterParams
    box = _spec("m2", M2Params)
    needs_model = True
