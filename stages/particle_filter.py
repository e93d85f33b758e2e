"""Filter stage of the contour trackers (chamfer and M2 with a contour model): weighs proposals by
eq. 7 and resamples.

A registration of :class:`stages.box_tracker.BoxFilterStage` (the filter stage every tracker on the
protocol shares) driving :data:`gflow_core.contour.features_filter.FEATURE_FILTER`, the filter side
of the tracker protocol over the preprocess stage's features. The mathematics and its departures
from Toyama & Blake (initialisation from the box or the learned model, kernel calibration, the
appearance kernels and online bank, the target's shape, the lost guard, the template update, blank
frames) are :mod:`gflow_core.contour.tracker`'s. The parameters are every field of the tracker's
dataclass (:class:`gflow_core.contour.params.ChamferParams`, ``M2Params``; ``ContourParams`` for the
generic ``particle.filter``) plus ``init``, ``seed`` and ``model``.

Inputs: ``features`` of frame t (the chamfer image, the edges, the grey image and, where the
preprocess stage sends them, the colour bins of the lost guard's second cue) and ``proposals`` for
frame t. Outputs: ``particles`` (the resampled posterior of t, which the proposal stage turns into
the proposals of t+1) and ``estimate`` (MAP state, box, posterior summary, ESS, the exemplar under
alpha as the contour, and -- with the lost guard -- ``confidence`` and ``target_state``).

Bad input: missing features make the filter weigh the proposals by no evidence (state ``coast``),
unusable ones (a bad chamfer image) as well, a bad grey image or colour bins drop the cues that
need them; each is reported, none stops the stream. Missing proposals reuse the last posterior. The
lost guard's orientation channels of a frame are the stage's ``prepare`` work (:mod:`stages.base`).

State for ``snapshot()`` / ``restore()``: the K = 1 template (when there is no learned
model), the resampled particle cloud, the calibrated kernel widths and the online bank,
the lost guard's distance distributions, held estimate and anchor, the chamfer tracker's first
template and the frame its template was last taken at (template update, :mod:`gflow_core.contour.template`),
and counters: one msgpack encode of :class:`gflow_core.contour.state.ContourSnapshot`, whose module
says which older versions restore and how.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from gflow_core.contour import state as wire
from gflow_core.contour.features_filter import FEATURE_FILTER
from gflow_core.contour.observation import exemplar_error, observation_of, profile_problem
from gflow_core.builtin_trackers import CHAMFER, M2
from gflow_core.contour.params import ContourParams
from gflow_core.contour.tracker import ContourObservation, ContourSetup, setup
from gflow_core.m2 import lost as lostmod
from gflow_core.m2.tracking import ParticleCloud, weight_diagnostics
from gflow_core.tracker import Estimate as TrackerEstimate

from .base import Output, StageContext, StageInputError
from .box_tracker import FeaturesFilterStage
from gflow_msgs.messages import Features, Header, Message, MessageError, bins_of
from gflow_msgs.params import SeedBoxFields, stage_params
from .spec_box import tracker_stage

__all__ = ["FilterStage", "FilterParams", "FilterFields", "ChamferFilterStage", "ChamferFilterParams",
           "M2FilterStage", "M2FilterParams"]

SNAPSHOT_VERSION = wire.SNAPSHOT_VERSION


class FilterFields(SeedBoxFields, frozen=True):
    """What the filter stage takes besides the tracker's parameters: ``seed`` and ``init``
    (:class:`~gflow_msgs.params.SeedBoxFields`), and ``model``, the path of a learned M2 model with
    contour exemplars (empty: the K = 1 chamfer tracker)."""

    model: str = ""


FilterParams = stage_params("FilterParams", ContourParams, FilterFields, __name__,
                            "Particle filter settings: every field of :class:`gflow_core.contour.params.ContourParams` "
                            "(see it for meanings), ``init``, ``seed`` and ``model``.")


class FilterStage(FeaturesFilterStage):
    kind = "particle.filter"
    Params = FilterParams
    #: the filter side of the tracker protocol over the preprocess stage's features; the proposal is the
    #: proposed cloud itself, and the snapshot this module's own (``snapshot`` / ``restore`` below)
    tracker = FEATURE_FILTER
    #: whether the stage needs a learned model (the ``model`` resource)
    needs_model: ClassVar[bool] = False
    #: chamfer's lost guard judges visibility within a few dozen frames (:attr:`BoxFilterStage.preload_gamma`)
    preload_gamma: ClassVar[bool] = True

    def __init__(self, params: Any, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        try:
            self.setup: ContourSetup = setup(self.core, params.init, self.learned_model(self.needs_model))
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

    def _features(self, feat: Features, seq: int) -> ContourObservation:
        """The tracker's observation of a features message (:func:`~gflow_core.contour.observation.observation_of`),
        what it could not use reported."""
        obs, problems = observation_of(self.core, self.setup, lambda field: getattr(feat, field).array(),
                                       lambda shape: bins_of(feat, shape), lambda: self.prepared("features", feat))
        for problem in problems:
            self.report("bad_features", f"frame {seq}: {problem}", seq)
        return obs

    def _check_profile(self, feat: Features, seq: int) -> None:
        m = self.setup.learned
        problem = profile_problem(m, feat.profile, feat.g0) if m is not None and not self.warned else ""
        if problem:
            self.warned = True
            self.report("profile_mismatch", f"frame {seq}: {problem}", seq)

    def _first_observation(self, seq: int, feat: Any) -> ContourObservation:
        if isinstance(feat, Features):
            try:
                feat.edges.array()
            except MessageError as e:
                raise StageInputError(f"frame {seq}: {e}") from None
            self._check_profile(feat, seq)
        return super()._first_observation(seq, feat)

    def _proposed(self, seq: int, prop: Message | None) -> ParticleCloud:
        cloud = super()._proposed(seq, prop)
        problem = exemplar_error(cloud, self.state.model.K)
        if problem:
            raise StageInputError(f"proposals {seq}: {problem}")
        return cloud

    def _last(self, header: Header, est: TrackerEstimate) -> dict:
        e = est.extras
        return {"seq": header.seq, "alpha": np.round(np.asarray(e["alpha"]), 3).tolist(), "ess": round(e["ess"], 1),
                "state": est.phase, "k": int(e["k"])}

    def _posterior(self) -> ParticleCloud:
        return self.state.cloud

    def _outputs(self, header: Header, est: TrackerEstimate, proposed: Any = None) -> list[Output]:
        """The posterior and the estimate messages (and the weights' diagnostics of ``proposed``)."""
        if proposed is not None:  # for summary() (stepping); not part of any output
            self.diagnostics = weight_diagnostics(proposed, np.asarray(est.extras["log_lik"]))
        return super()._outputs(header, est)

    def summary(self) -> dict:
        """The last estimate (seq, MAP alpha, ESS, state), the histogram of the relative weights
        N W_i before resampling, and the best particle with its log-likelihood."""
        return dict(self.last, steps=self.steps, **self.diagnostics)

    # -- snapshot / restore: one encode of the state (gflow_core.contour.state) -----------
    def snapshot(self) -> bytes:
        return wire.encode(wire.snapshot_of(self.state, self.steps, self.warned, self.last))

    def restore(self, data: bytes) -> None:
        snap = self._restored(data, wire.decode, lambda s: wire.state_of(s, self.setup, self.core, self.params.init))
        self.steps, self.warned, self.last = snap.steps, snap.warned, wire.last_of(snap)


#: the chamfer and m2 trackers' filters, made from their specs (a learned contour model required where the spec's is)
ChamferFilterStage, M2FilterStage = (tracker_stage(FilterStage, s, "Filter", FilterFields, __name__,
                                                   needs_model=s.model_required) for s in (CHAMFER, M2))
ChamferFilterParams, M2FilterParams = ChamferFilterStage.Params, M2FilterStage.Params
