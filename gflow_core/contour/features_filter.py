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
adapts its calls. What the filter reads of the features and what it refuses of a proposal, the
stage's rules and the Python API's alike, are :mod:`.observation`'s.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .observation import exemplar_error
from .params import ContourParams, EdgeParams
from .protocol import CHAMFER
from .tracker import FILTER, ContourObservation, ContourSetup, ContourState, setup
from ..m2.tracking import ParticleCloud
from ..tracker import Box, Estimate, FrameRng

__all__ = ["ContourFeatureFilter", "FEATURE_FILTER"]


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
