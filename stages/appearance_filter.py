"""Filter stage of the appearance tracker: M2 with online exemplars.

An adapter of :class:`gflow_core.appearance.tracker.AppearanceTracker` (``observe``, ``init``,
``update``, ``coast``); the mathematics is :mod:`gflow_core.appearance.filter` (its docstring lists the
departures from Toyama & Blake 2002). Its parameters are every field of
:class:`gflow_core.appearance.params.AppearanceParams` (derived from it, defaults included) plus
``seed`` and ``init``. This stage adapts the tracker to the pipeline's particle messages:

* Inputs: ``frames`` of frame t (colour or grey; the appearance channels are computed here
  from the grey levels, and the colour bins of the colour cue from the colours) and ``proposals`` for frame t from ``appearance.proposal`` (a random
  walk on alpha = (x, y, theta, s); theta is ignored and s = exp(log s)).
* Outputs: ``particles`` (the resampled posterior of t, alpha = (x, y, 0, s)) and
  ``estimate``: the box, the posterior mean and std of alpha, the ESS, the data path
  ``state`` -- ``init``, ``track``, ``occluded`` (the target was judged hidden: the box holds
  the prediction, the exemplars are not updated and a widening region is searched), ``lost``
  (hidden, and the search covers the whole frame), ``redetect`` (the search found it again
  this frame) or ``coast`` (no usable frame: the particles and the model are carried over
  unchanged) -- and what the tracker judges of the target: ``confidence``, P(visible) of
  :mod:`gflow_core.visibility`, and ``target_state`` (``tracked``, ``occluded``, ``lost``).

Bad input -- a missing, undecodable, uniform or wrongly sized frame, or missing proposals --
makes the filter coast and is reported; it never stops the stream.

The appearance channels of a frame depend on that frame alone, so they are the stage's
``prepare`` work (:mod:`stages.base`): as its own process, the host computes the channels of
frame t+1 on a second thread while ``step`` weighs frame t (5 of the filter's 16 ms a frame
on caviar1, measured before the channels were made faster); ``--inline`` computes them in
``step``. The bits are the same either way.

State for ``snapshot()`` / ``restore()``: the three exemplars, the particle cloud, the velocity,
the moments of the target's and the clutter's distance distributions, the colour histograms and
their distance moments, the hidden-frame count and counters, as msgpack of
:class:`gflow_msgs.snapshots.AppearanceFilterSnapshot` (version 4; the state's fields:
:mod:`gflow_core.appearance.snapshot_fields`).

The stage is a registration of :class:`stages.box_tracker.BoxFilterStage` (the stage logic it shares
with the correlation-filter tracker's); what it needs of the tracker comes from its spec
(:mod:`gflow_core.appearance.spec`), and this module holds what is the appearance tracker's own: its
snapshot codec. Its proposal stage is made from the spec (:mod:`stages.spec_box`).
"""

from __future__ import annotations

from typing import Any

import msgspec

from gflow_core.appearance.params import AppearanceParams
from gflow_core.appearance.snapshot_fields import fields_of, state_of
from gflow_core.appearance.spec import SPEC
from gflow_core.appearance.tracker import AppearanceTrack

from .box_tracker import BoxFilterStage, SnapshotCodec
from gflow_msgs.base import packed_fields, unpacked_fields
from gflow_msgs.snapshots import AppearanceFilterSnapshot
from .tracker_params import SeedBoxFields, stage_params

__all__ = ["AppearanceFilterStage", "AppearanceFilterParams"]

SNAPSHOT_VERSION = 4


AppearanceFilterParams = stage_params(
    "AppearanceFilterParams", AppearanceParams, SeedBoxFields, __name__,
    "Appearance filter settings: every field of :class:`gflow_core.appearance.params.AppearanceParams` "
    "(see it for meanings), ``seed`` and ``init``.")


def _snapshot_fields(track: AppearanceTrack) -> dict[str, Any]:
    """The tracker's fields of a snapshot: the model's state."""
    return packed_fields(fields_of(track.core))


def _snapshot_state(snap: AppearanceFilterSnapshot, core: AppearanceParams, last: dict) -> AppearanceTrack:
    """The state of a snapshot (MessageError, ValueError or KeyError when bad); the target as the last
    estimate ``last`` judged it (what a coasted frame reports)."""
    return AppearanceTrack(state_of(unpacked_fields(msgspec.structs.asdict(snap))),
                           str(last.get("target_state", "occluded")))


class AppearanceFilterStage(BoxFilterStage):
    kind = "appearance.filter"
    Params = AppearanceFilterParams
    tracker = SPEC.tracker()
    box = SPEC.box
    codec = SnapshotCodec(AppearanceFilterSnapshot, SNAPSHOT_VERSION, _snapshot_fields, _snapshot_state)
