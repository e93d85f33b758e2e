"""The contour trackers, chamfer and M2, on the tracker protocol of :mod:`gflow_core.tracker`.

:class:`ContourTracker` is the :class:`~gflow_core.tracker.TrackingFilter` of both (:data:`CHAMFER`,
:data:`M2`), over the filter of :mod:`gflow_core.contour.tracker`:

* ``observe`` -- the frame's grey levels (:class:`ContourFrame`). Its edges and chamfer image
  (:func:`.features.edges_and_chamfer`, what the preprocess stage computes) depend on the Canny
  thresholds, which the chamfer tracker chooses on the first frame's box: they are part of the
  track (:class:`ContourTrack`), so ``init`` and ``update`` compute them from the frame;
* ``init`` -- the thresholds, the learned model placed for the box (or the K = 1 template from the
  edges in the box), the initial cloud and the proposal's dynamics (:func:`proposal_dynamics`);
* ``propose`` -- :func:`propose_cloud`: k_t ~ M[k_{t-1}], alpha_t ~ AR(1)(alpha_{t-1}) (M2 sec.
  4.3; the chamfer tracker's is a random walk with K = 1, the M2 tracker's the learned model's);
* ``update`` -- :meth:`.tracker.ContourFilter.update`: eq. 7 (x the appearance kernel),
  resampling, the lost guard and the online bank;
* ``coast`` -- a frame that could not be used: the proposal weighed by no evidence (the posterior
  is the prior, as the filter stage does when no features arrive).

Random draws of frame ``t`` (:class:`~gflow_core.tracker.FrameRng`): the proposal from
``stream(PURPOSE_PROPOSAL)`` (:func:`gflow_core.tracker.frame_rng`, as the proposal stage draws), the
filter's as :mod:`.tracker` lists them; so a step here and a step through the stages
(``stages/preprocess.py``, ``stages/particle_proposal.py``, ``stages/particle_filter.py``) give
the same bits.

Resources (``init``): ``model``, the learned M2 model (required by M2, refused by chamfer), and
``edges``, the :class:`~gflow_core.contour.params.EdgeParams` the model was learned with
(:func:`m2_edge_params`; default: the chamfer tracker's, thresholds calibrated on the box). With a
learned contour model, ``init`` sets their ``model_scale`` from the model and the box
(:meth:`gflow_core.m2.model.M2Model.match_scale`) unless they give one other than 1, as ``gflow track``
does; ``match_resolution`` applies it.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any, Literal, Mapping, cast

import numpy as np

from .. import colour, features
from .params import ChamferParams, ContourParams, EdgeParams, M2Params
from .dynamics import PURPOSE_PROPOSAL, proposal_dynamics, propose_cloud
from .observation import exemplar_error, is_blank, reads_grey, usable_chamfer, usable_grey
from .tracker import FILTER, ContourObservation, ContourState, setup
from ..m2 import lost as lostmod
from ..m2.dynamics import ARDynamics
from ..m2.edge_settings import BLUR, CANNY_HIGH, CANNY_LOW
from ..m2.model import M2Model
from ..m2.tracking import ParticleCloud
from ..tracker import Box, Estimate, FrameRng

__all__ = ["ContourTracker", "ContourFrame", "ContourTrack", "CHAMFER", "M2", "proposal_dynamics", "propose_cloud",
           "m2_edge_params", "PURPOSE_PROPOSAL"]


@dataclass(frozen=True)
class ContourFrame:
    """What the contour trackers read of a frame: grey : (H, W) uint8 grey levels; bins : (H, W) uint8
    colour bins (:func:`gflow_core.colour.bins`) for the lost guard's colour cue, or None."""

    grey: np.ndarray
    bins: np.ndarray | None = None


@dataclass(frozen=True)
class ContourTrack:
    """The posterior after a frame (``filter``, :class:`.tracker.ContourState`) and what is
    fixed for the track: the edge settings and the Canny thresholds chosen on the first frame (None:
    chosen on every frame), the proposal's Markov matrix (K, K) and AR(1) dynamics."""

    filter: ContourState
    edges: EdgeParams
    thresholds: tuple[float, float] | None
    markov: np.ndarray
    dynamics: ARDynamics


def m2_edge_params(model: M2Model, meta: Mapping[str, Any]) -> EdgeParams:
    """The edge settings an M2 model was learned with: its chamfer profile and g0, and the Canny
    thresholds and blur of its file's ``meta`` (when absent, those models are learned with by
    default, :data:`gflow_core.m2.edge_settings.LEARN_EDGES`), as ``gflow track --tracker m2`` sets
    the preprocess stage."""
    if ("canny_low" in meta) != ("canny_high" in meta):  # the defaults for both would stand for the one given
        raise ValueError(f"the model's metadata has canny_{'low' if 'canny_low' in meta else 'high'} without "
                         f"canny_{'high' if 'canny_low' in meta else 'low'}: Canny's thresholds are a pair")
    low, high = _edge_number(meta, "canny_low", CANNY_LOW), _edge_number(meta, "canny_high", CANNY_HIGH)
    if low > high:
        raise ValueError(f"the model's metadata has canny_low {low:g} above canny_high {high:g}")
    profile = cast(Literal["quadratic", "truncated", "linear"], model.profile)  # M2Model checks it
    return EdgeParams(profile=profile, g0=float(model.g0), canny_low=low, canny_high=high,
                      blur=_edge_number(meta, "blur", BLUR))


def _edge_number(meta: Mapping[str, Any], key: str, default: float) -> float:
    """The edge setting ``key`` of a model file's metadata (``default`` where it has none): a finite number >= 0,
    as ``gflow learn m2`` writes it; anything else (text, a list, NaN, a negative number) a ValueError naming it,
    where it would have failed as a bug or found no edge on any frame."""
    v = meta.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < float("inf"):
        raise ValueError(f"the model's metadata {key} must be a number >= 0 (as gflow learn m2 writes it), got {v!r}")
    return float(v)


class ContourTracker:
    """The contour trackers' :class:`gflow_core.tracker.TrackingFilter` (stateless: everything is in
    :class:`ContourTrack`). ``needs_model``: M2 (a learned model resource); chamfer takes none."""

    def __init__(self, name: str, params: type[ContourParams], needs_model: bool) -> None:
        self.name, self.Params, self.needs_model = name, params, needs_model

    def observe(self, params: ContourParams, image: np.ndarray) -> ContourFrame:
        """The grey levels of a ``(H, W, 3)`` BGR or ``(H, W)`` grey frame (``ValueError`` for one that
        is not an image), and its colour bins where the lost guard weighs colour (a frame with colour:
        not a grey one, whose grey levels the edges already read). A uniform frame is not
        refused: it has no edges, a blank frame (no evidence)."""
        grey = features.to_grey(image)
        use = params.lost_guard and params.lost_colour and not colour.is_grey(image)
        return ContourFrame(grey, colour.bins(image) if use else None)

    def features(self, params: ContourParams, frame: ContourFrame, edges: EdgeParams,
                 thresholds: tuple[float, float] | None, wants_grey: bool) -> ContourObservation:
        """The filter's observation of a frame, as the preprocess stage and the filter stage make it:
        edges and chamfer image, blank below ``min_edges`` edge pixels, the grey levels and the lost
        guard's orientation channels (computed when first asked) where a cue needs them."""
        grey = frame.grey
        e, cham = features.edges_and_chamfer(grey, thresholds, edges.blur, edges.canny_percentile, edges.profile,
                                             edges.g0, edges.resample)
        # the filter stage's rules (.observation): the chamfer image's, the blank frame's, the grey image's
        chamfer: np.ndarray | None = cham if usable_chamfer(cham) else None
        blank = chamfer is not None and is_blank(params, e)
        g = grey if wants_grey and usable_grey(grey) else None
        channels = functools.cache(functools.partial(lostmod.channels, g)) if g is not None else None
        return ContourObservation(edges=e, chamfer=chamfer, blank=blank, grey=g, channels=channels,
                                  bins=frame.bins if g is not None else None)

    def init(self, params: ContourParams, obs: ContourFrame, box: Box, rng: FrameRng,
             resources: Mapping[str, Any]) -> tuple[ContourTrack, Estimate]:
        """The thresholds (calibrated on ``box`` unless the edge settings fix them), the model placed
        for ``box`` and the posterior at the first frame. ``ValueError`` for a missing or wrong model, a
        box outside the frame or a template with no edges."""
        model = resources.get("model")
        if self.needs_model and model is None:
            raise ValueError(f"tracker {self.name} needs a learned model (`gflow learn m2`)")
        if not self.needs_model and model is not None:
            raise ValueError(f"tracker {self.name} takes no model")
        edges = resources.get("edges") or EdgeParams()
        if isinstance(model, M2Model) and model.kind == "curve" and edges.model_scale == 1.0:
            # the resolution a larger target is matched at with match_resolution (as gflow track sets it)
            edges = dataclasses.replace(edges, model_scale=model.match_scale(box))
        thresholds = ((edges.canny_low, edges.canny_high) if edges.canny_low is not None and edges.canny_high is not None
                      else features.canny_calibrated(obs.grey, edges.blur, edges.canny_percentile, box))
        setup_ = setup(params, box, model)
        walk = (params.std_xy, params.std_theta, params.std_log_s) if isinstance(params, ChamferParams) else None
        markov, dynamics, fixed = proposal_dynamics(model, box, walk)
        assert not fixed  # setup refuses patch models
        fobs = self.features(params, obs, edges, thresholds, reads_grey(params, setup_))
        st, est = FILTER.init(params, fobs, setup_, rng)
        return ContourTrack(st, edges, thresholds, markov, dynamics), est

    def propose(self, params: ContourParams, state: ContourTrack, obs: ContourFrame | None, rng: FrameRng,
                dt: float = 1.0) -> ParticleCloud:
        """:func:`propose_cloud` of the posterior, from ``rng.stream(PURPOSE_PROPOSAL)`` (the frame is not read)."""
        return propose_cloud(state.filter.cloud, state.markov, state.dynamics, rng.stream(PURPOSE_PROPOSAL), dt)

    def update(self, params: ContourParams, state: ContourTrack, proposal: ParticleCloud, obs: ContourFrame | None,
               rng: FrameRng) -> tuple[ContourTrack, Estimate]:
        """The filter's update of ``proposal`` on the frame's features (no evidence when ``obs`` is None).
        The estimate's phase is ``track``, ``coast`` (a blank frame), ``lost`` or ``redetect``."""
        problem = exemplar_error(proposal, state.filter.model.K)
        if problem:
            raise ValueError(problem)
        fobs = None if obs is None else self.features(params, obs, state.edges, state.thresholds,
                                                      reads_grey(params, state.filter.setup))
        st, est = FILTER.update(params, state.filter, proposal, fobs, rng)
        return dataclasses.replace(state, filter=st), est

    def coast(self, params: ContourParams, state: ContourTrack, rng: FrameRng,
              obs: ContourFrame | None = None) -> tuple[ContourTrack, Estimate]:
        """Frame ``rng.t`` could not be used: the proposal weighed by no evidence (phase ``coast``)."""
        return self.update(params, state, self.propose(params, state, None, rng), None, rng)


#: the chamfer tracker (K = 1, the template from the edges in the box; a random walk)
CHAMFER = ContourTracker("chamfer", ChamferParams, needs_model=False)
#: the M2 tracker (a learned contour model, resource ``model``)
M2 = ContourTracker("m2", M2Params, needs_model=True)
