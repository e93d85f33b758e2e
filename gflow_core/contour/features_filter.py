"""The contour filter's side of the tracker protocol over the preprocess stage's features: what the
pipeline's filter stage (``chamfer.filter``, ``m2.filter``, ``particle.filter``) drives.

:class:`ContourFeatureFilter` (:data:`FEATURE_FILTER`) has the ``observe``, ``init``, ``update`` and
``coast`` of :class:`gflow_core.tracker.TrackingFilter`, over observations that are the frame's
features (:class:`.tracker.ContourObservation`: edges, chamfer image, grey levels, colour bins)
and states that are :class:`.tracker.ContourState`. Unlike :class:`.protocol.ContourTracker` (the
Python API's, which computes a frame's edges itself with the thresholds of the track) it takes
the features as the preprocess stage computed them, and has no ``propose``: the pipeline proposes
in a stage of its own (:func:`.dynamics.propose_cloud`), whose clouds ``update`` weighs.

The mathematics is :class:`.tracker.ContourFilter`'s (:data:`.tracker.FILTER`); this module only
adapts its calls, and says what the filter reads of the features (:func:`reads_grey`,
:func:`is_blank`, :func:`same_profile`) and what it refuses of a proposal (:func:`exemplar_error`),
for the stage that reads them from messages.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .params import ContourParams, EdgeParams
from .protocol import CHAMFER
from .tracker import FILTER, ContourObservation, ContourSetup, ContourState, setup
from ..m2.model import M2Model
from ..m2.tracking import ParticleCloud
from ..tracker import Box, Estimate, FrameRng

__all__ = ["ContourFeatureFilter", "FEATURE_FILTER", "reads_grey", "is_blank", "same_profile", "exemplar_error"]


def reads_grey(params: ContourParams, placed: ContourSetup) -> bool:
    """Whether a cue reads the frame's grey levels: the lost guard, or a learned model's appearance
    kernels."""
    return params.lost_guard or placed.app0 is not None


def is_blank(params: ContourParams, edges: np.ndarray) -> bool:
    """Fewer than ``min_edges`` edge pixels in the (H, W) edge map: a blank frame, no evidence
    (sec. 5.1.2, fig. 7)."""
    return params.min_edges > 0 and int(np.count_nonzero(edges)) < params.min_edges


def same_profile(model: M2Model, profile: str, g0: float) -> bool:
    """Whether chamfer images made with ``profile`` (and ``g0``) are the distances ``model`` was learned
    on, so its sigma_k and d_k hold for them."""
    return profile == model.profile and (model.profile != "truncated" or bool(np.isclose(g0, model.g0)))


def exemplar_error(cloud: ParticleCloud, K: int) -> str:
    """What is wrong with a proposed cloud's exemplar indices for a model of ``K`` exemplars ("": nothing)."""
    if cloud.k.size and cloud.k.max() >= K:
        return f"exemplar index {int(cloud.k.max())} beyond the model's K={K}"
    return ""


class ContourFeatureFilter:
    """The contour filter on a frame's features (module docstring); stateless."""

    name = "contour"

    def observe(self, params: ContourParams, image: np.ndarray) -> ContourObservation:
        """The features of a ``(H, W, 3)`` BGR or ``(H, W)`` grey frame as the preprocess stage
        computes them with the default edge settings (Canny thresholds chosen on the frame), the grey
        levels and the lost guard's channels included."""
        return CHAMFER.features(params, CHAMFER.observe(params, image), EdgeParams(), None, True)

    def init(self, params: ContourParams, obs: ContourObservation, box: Box, rng: FrameRng,
             resources: Mapping[str, Any]) -> tuple[ContourState, Estimate]:
        """The posterior at the first frame (:meth:`.tracker.ContourFilter.init`). ``resources``:
        ``setup``, the model already placed for ``box`` (:func:`.tracker.setup`), or ``model``, the
        learned model to place (none: the K = 1 chamfer tracker)."""
        placed = resources.get("setup")
        if not isinstance(placed, ContourSetup):
            placed = setup(params, box, resources.get("model"))
        return FILTER.init(params, obs, placed, rng)

    def update(self, params: ContourParams, state: ContourState, proposal: ParticleCloud,
               obs: ContourObservation | None, rng: FrameRng) -> tuple[ContourState, Estimate]:
        """The proposed cloud weighed by the features (no evidence when ``obs`` is None: no features
        arrived), resampled and guarded (:meth:`.tracker.ContourFilter.update`). ``ValueError`` for a
        cloud with an exemplar index beyond the model's K."""
        problem = exemplar_error(proposal, state.model.K)
        if problem:
            raise ValueError(problem)
        return FILTER.update(params, state, proposal, obs, rng)

    def coast(self, params: ContourParams, state: ContourState, rng: FrameRng,
              obs: ContourObservation | None = None) -> tuple[ContourState, Estimate]:
        """Frame ``rng.t`` with neither proposals nor usable features: the last posterior weighed by no
        evidence (phase ``coast``)."""
        return FILTER.update(params, state, state.cloud, None, rng)


#: the one instance (it keeps no state)
FEATURE_FILTER = ContourFeatureFilter()
