"""Filter stage of the correlation-filter tracker.

An adapter of :class:`gflow_core.dcf.tracker.DCFTracker` (``observe``, ``init``, ``update``, ``coast``);
the mathematics is :mod:`gflow_core.dcf` (its docstring lists the papers and the departures). Its
parameters are every field of :class:`gflow_core.dcf.params.DCFParams` plus ``seed`` and ``init``.

* Inputs: ``frames`` of frame t (colour or grey) and ``proposals`` for frame t from ``dcf.proposal``
  (a random walk on alpha = (x, y, theta, s); theta is ignored and s = exp(log s)).
* Outputs: ``particles`` (the resampled posterior of t, alpha = (x, y, 0, s)) and ``estimate``: the
  box, the posterior's mean and std of alpha, the ESS, the data path ``state`` -- ``init``, ``track``,
  ``occluded``, ``lost``, ``redetect`` or ``coast`` -- and what the tracker judges of the target:
  ``confidence`` (P(visible)) and ``target_state`` (``tracked``, ``occluded``, ``lost``).

Bad input -- a missing, undecodable, uniform or wrongly sized frame, or missing proposals -- makes
the filter coast and is reported; it never stops the stream. The frame's observation (its grey
levels) is the stage's ``prepare`` work (:mod:`stages.base`).

State for ``snapshot()`` / ``restore()``: the tracker's state as arrays and values
(:func:`gflow_core.dcf.state.to_arrays`), the step count and the last estimate, as msgpack.

The stage is a registration of :class:`stages.box_tracker.BoxFilterStage` (the stage logic it shares
with the appearance tracker's); what it needs of the tracker (its protocol object, conversions and
state as arrays) is the tracker's spec, :mod:`gflow_core.dcf.spec` (:func:`stages.spec_box.box_filter_spec`;
the snapshot's Struct is :mod:`stages.spec_box`'s, version 1).
"""

from __future__ import annotations

from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.spec import SPEC

from .box_tracker import BoxFilterStage
from .dcf_proposal import DCFStageFields
from .spec_box import box_filter_spec
from .tracker_params import stage_params

__all__ = ["DCFFilterStage", "DCFFilterParams"]

DCFFilterParams = stage_params(
    "DCFFilterParams", DCFParams, DCFStageFields, __name__,
    "Correlation-filter settings: every field of :class:`gflow_core.dcf.params.DCFParams` (see it for "
    "meanings), ``seed`` and ``init``.")


class DCFFilterStage(BoxFilterStage):
    kind = "dcf.filter"
    Params = DCFFilterParams
    box = box_filter_spec(SPEC)
