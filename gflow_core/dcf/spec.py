"""The correlation-filter tracker's registration (:class:`gflow_core.spec.TrackerSpec`): its
parameters, its protocol object, its graph and what the box stages (``stages/box_tracker.py``)
need of it: the random walk, the particle conversions and the state as arrays for snapshots.

The tracker's modules (its update, its state's SciPy) are imported when a stage or the API uses
them, not when the registry is read; the proposal stage needs only the walk.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..spec import BoxStages, TrackerSpec
from ..tracker import TrackingFilter
from .dynamics import PURPOSE_WALK, alpha_of, particles_of, walk
from .params import DCFParams

__all__ = ["SPEC"]


def _tracker() -> TrackingFilter[Any, Any, Any, Any]:
    from .tracker import TRACKER

    return TRACKER


def _proposal(particles: np.ndarray, dt: float) -> Any:
    from .state import DCFProposal

    return DCFProposal(particles, dt)


def _particles(state: Any) -> np.ndarray:
    return state.particles


def _to_arrays(state: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    from .state import to_arrays

    return to_arrays(state)


def _from_arrays(arrays: dict[str, np.ndarray], values: dict[str, Any], params: Any) -> Any:
    from .state import from_arrays

    return from_arrays(arrays, values, params)


#: the tracker ``dcf`` (graph ``pipeline/graphs/dcf.yaml``, stages ``dcf.proposal`` and ``dcf.filter``)
SPEC = TrackerSpec("dcf", DCFParams, _tracker, graph="dcf", cli="pipeline.cli.trackers.dcf",
                   box=BoxStages(walk=walk, purpose=PURPOSE_WALK, proposal=_proposal, particles=_particles,
                                 alpha_of=alpha_of, particles_of=particles_of, to_arrays=_to_arrays,
                                 from_arrays=_from_arrays, snapshot_version=1),
                   origin="gflow_core.builtin_trackers")
