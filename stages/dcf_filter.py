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
with the appearance tracker's); this module holds what is the correlation filter's own: its
snapshot's Struct and codec.
"""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from gflow_core.dcf.dynamics import alpha_of, particles_of
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import DCFProposal, DCFState, from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER

from .box_tracker import BoxFilterSpec, BoxFilterStage, SnapshotCodec
from .dcf_proposal import DCFStageFields
from .messages import NDArray
from .tracker_params import stage_params

__all__ = ["DCFFilterStage", "DCFFilterParams"]

SNAPSHOT_VERSION = 1

DCFFilterParams = stage_params(
    "DCFFilterParams", DCFParams, DCFStageFields, __name__,
    "Correlation-filter settings: every field of :class:`gflow_core.dcf.params.DCFParams` (see it for "
    "meanings), ``seed`` and ``init``.")


class _Snapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    version: int
    initialised: bool
    arrays: dict[str, NDArray] = {}
    values: dict[str, Any] = {}
    steps: int = 0
    last: dict = {}


def _snapshot_fields(st: DCFState) -> dict[str, Any]:
    """The tracker's fields of a snapshot: its state as arrays and values."""
    arrays, values = to_arrays(st)
    return {"arrays": {k: NDArray.of(v) for k, v in arrays.items()}, "values": values}


def _snapshot_state(snap: _Snapshot, core: DCFParams, last: dict) -> DCFState:
    """The state of a snapshot (KeyError, IndexError, TypeError, MessageError or ValueError when bad)."""
    return from_arrays({k: v.array() for k, v in snap.arrays.items()}, snap.values, core)


def _particles(st: DCFState) -> np.ndarray:
    return st.particles


class DCFFilterStage(BoxFilterStage):
    kind = "dcf.filter"
    Params = DCFFilterParams
    box = BoxFilterSpec(name="dcf", tracker=TRACKER, params=DCFParams, proposal=DCFProposal, particles=_particles,
                        alpha_of=alpha_of, particles_of=particles_of,
                        snapshot=SnapshotCodec(_Snapshot, SNAPSHOT_VERSION, _snapshot_fields, _snapshot_state))
