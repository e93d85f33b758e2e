"""The m2 tracker on the tracker protocol of :mod:`gflow_core.tracker`, whatever its model.

An M2 model holds contour exemplars (chamfer distance; the filter over X = (alpha, k) of
:data:`gflow_core.contour.protocol.M2`) or patch exemplars (shuffle or L2 distance; the filter over
k alone of :data:`.patch_protocol.PATCH`, sec. 5.2). Which one runs is settled once, by the m2
registration's setup (:func:`gflow_core.builtin_trackers.m2_setup`), which reads the model and makes
:class:`~gflow_core.contour.params.M2Params` for a contour model and
:class:`~.patch_protocol.PatchParams` for a patch model. :data:`M2` hands every call to the filter
whose parameters it is given, so ``m2`` is one tracker with one registration, as the command line
has it (``gflow track --tracker m2 --model MODEL.npz`` runs graph ``m2`` or ``m2_patch``).
"""

from __future__ import annotations

from typing import Any, Mapping

from ..tracker import Box, Estimate, FrameRng, TrackingFilter
from .patch_protocol import PATCH, PatchParams

__all__ = ["M2Tracker", "M2"]


class M2Tracker:
    """M2 as one :class:`~gflow_core.tracker.TrackingFilter`: the patch filter for
    :class:`~.patch_protocol.PatchParams`, the contour filter for any other parameters (stateless)."""

    name = "m2"

    @staticmethod
    def _of(params: Any) -> TrackingFilter[Any, Any, Any, Any]:
        if isinstance(params, PatchParams):
            return PATCH
        from ..contour.protocol import M2 as CONTOUR

        return CONTOUR

    def observe(self, params: Any, image: Any) -> Any:
        return self._of(params).observe(params, image)

    def init(self, params: Any, obs: Any, box: Box, rng: FrameRng,
             resources: Mapping[str, Any]) -> tuple[Any, Estimate]:
        return self._of(params).init(params, obs, box, rng, resources)

    def propose(self, params: Any, state: Any, obs: Any, rng: FrameRng, dt: float = 1.0) -> Any:
        return self._of(params).propose(params, state, obs, rng, dt)

    def update(self, params: Any, state: Any, proposal: Any, obs: Any, rng: FrameRng) -> tuple[Any, Estimate]:
        return self._of(params).update(params, state, proposal, obs, rng)

    def coast(self, params: Any, state: Any, rng: FrameRng, obs: Any = None) -> tuple[Any, Estimate]:
        return self._of(params).coast(params, state, rng, obs)


#: the one instance (it keeps no state)
M2 = M2Tracker()
