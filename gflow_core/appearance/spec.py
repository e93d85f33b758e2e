"""The appearance tracker's registration (:class:`gflow_core.spec.TrackerSpec`): its parameters,
its protocol object, its graph and what the box stages (``stages/box_tracker.py``) need of it:
the random walk and the particle conversions. Its snapshot keeps the Struct of its filter stage
(``stages/appearance_filter.py``, version 4), so the spec gives no state as arrays and names that
module as its filter's (``stages``).

The tracker's modules are imported when a stage or the API uses them, not when the registry is
read; the proposal stage needs only the walk.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .dynamics import PURPOSE_WALK, alpha_of, particles_of, walk
from .params import AppearanceParams
from ..spec import BoxStages, TrackerSpec
from ..tracker import TrackingFilter

__all__ = ["SPEC"]


def _tracker() -> TrackingFilter[Any, Any, Any, Any]:
    from .tracker import TRACKER

    return TRACKER


def _proposal(particles: np.ndarray, dt: float) -> Any:
    from .tracker import AppearanceProposal

    return AppearanceProposal(particles, dt)


def _particles(track: Any) -> np.ndarray:
    return track.core.particles


#: the tracker ``appearance`` (graph ``pipeline/graphs/appearance.yaml``, stages ``appearance.proposal``
#: and ``appearance.filter``)
SPEC = TrackerSpec("appearance", AppearanceParams, _tracker, graph="appearance",
                   cli="pipeline.cli.trackers.appearance",
                   box=BoxStages(walk=walk, purpose=PURPOSE_WALK, proposal=_proposal, particles=_particles,
                                 alpha_of=alpha_of, particles_of=particles_of),
                   stages={"appearance.filter": "stages.appearance_filter"}, origin="gflow_core.builtin_trackers")
