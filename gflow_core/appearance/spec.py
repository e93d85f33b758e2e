"""The appearance tracker's registration (:class:`gflow_core.spec.TrackerSpec`): its parameters,
its protocol object, its graph and what the box stages (``stages/box_tracker.py``) need of it:
the random walk, the particle conversions and the state as the fields of its filter's snapshot
(:mod:`.snapshot_fields`), whose Struct is its own (``gflow_msgs.snapshots.AppearanceFilterSnapshot``,
version 4: the format is older than the generic box stages', and recordings hold it), so its two
stages are the generic box stages made from this spec (``stages/spec_box.py``).

The tracker's modules are imported when a stage or the API uses them, not when the registry is
read; the proposal stage needs only the walk.

The filter stage ``appearance.filter`` adapts :class:`.tracker.AppearanceTracker` (``observe``,
``init``, ``update``, ``coast``; the mathematics and its departures from Toyama & Blake 2002 are
:mod:`.filter`'s) to the pipeline's particle messages. Inputs: ``frames`` of frame t (colour or grey;
the appearance channels are computed from the grey levels, the colour cue's bins from the colours)
and ``proposals`` for frame t from ``appearance.proposal`` (a random walk on alpha = (x, y, theta, s);
theta is ignored and s = exp(log s)). Outputs: ``particles`` (the resampled posterior of t, alpha =
(x, y, 0, s)) and ``estimate``: the box, the posterior mean and std of alpha, the ESS, the data path
``state`` -- ``init``, ``track``, ``occluded`` (the target was judged hidden: the box holds the
prediction, the exemplars are not updated and a widening region is searched), ``lost`` (hidden, and
the search covers the whole frame), ``redetect`` (the search found it again this frame) or ``coast``
(no usable frame: the particles and the model are carried over unchanged) -- and what the tracker
judges of the target: ``confidence``, P(visible) of :mod:`gflow_core.visibility`, and
``target_state`` (``tracked``, ``occluded``, ``lost``). A missing, undecodable, uniform or wrongly
sized frame, or missing proposals, make it coast and are reported; they never stop the stream. The
appearance channels of a frame depend on that frame alone, so they are the stage's ``prepare`` work
(``stages/base.py``): as its own process, the host computes the channels of frame t+1 on a second
thread while ``step`` weighs frame t (5 of the filter's 16 ms a frame on caviar1, measured before the
channels were made faster); ``--inline`` computes them in ``step``, with the same bits. Its snapshot
holds the three exemplars, the particle cloud, the velocity, the moments of the target's and the
clutter's distance distributions, the colour histograms and their distance moments, the hidden-frame
count and counters.
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
    """The tracker, with SciPy's gamma functions imported now: the filter judges visibility with them
    (:func:`gflow_core.visibility.load_gamma`), first on a frame deep in a run (caviar1's frame 111), whose
    time would otherwise hold the import (about 0.25 s of CPU)."""
    from .tracker import TRACKER
    from ..visibility import load_gamma

    load_gamma()
    return TRACKER


def _proposal(particles: np.ndarray, dt: float) -> Any:
    from .tracker import AppearanceProposal

    return AppearanceProposal(particles, dt)


def _particles(track: Any) -> np.ndarray:
    return track.core.particles


def _to_arrays(track: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The filter's snapshot fields of a track (:func:`.snapshot_fields.fields_of`): its arrays and the rest."""
    from .snapshot_fields import fields_of

    fields = fields_of(track.core)
    arrays = {k: v for k, v in fields.items() if isinstance(v, np.ndarray)}
    return arrays, {k: v for k, v in fields.items() if k not in arrays}


def _from_arrays(arrays: dict[str, np.ndarray], values: dict[str, Any], params: Any) -> Any:
    """The track of a snapshot's fields; the target as the last estimate (``values["last"]``, the summary
    the stage keeps) judged it, which is what a coasted frame reports. ValueError or KeyError when bad."""
    from .snapshot_fields import state_of
    from .tracker import AppearanceTrack

    return AppearanceTrack(state_of({**arrays, **values}), str(values["last"].get("target_state", "occluded")))


#: the tracker ``appearance`` (graph ``pipeline/graphs/appearance.yaml``, stages ``appearance.proposal``
#: and ``appearance.filter``)
SPEC = TrackerSpec("appearance", AppearanceParams, _tracker, graph="appearance",
                   cli="pipeline.cli.trackers.appearance",
                   box=BoxStages(walk=walk, purpose=PURPOSE_WALK, proposal=_proposal, particles=_particles,
                                 alpha_of=alpha_of, particles_of=particles_of, to_arrays=_to_arrays,
                                 from_arrays=_from_arrays, snapshot_version=4, snapshot="AppearanceFilterSnapshot"),
                   origin="gflow_core.builtin_trackers")
