"""The stages of a registered tracker that has no stage modules of its own: the generic box stages
(:mod:`stages.box_tracker`) driven by its spec (:class:`gflow_core.spec.TrackerSpec` with
:class:`gflow_core.spec.BoxStages`).

:func:`spec_stage_classes` makes, for one spec, the proposal stage (kind ``NAME.proposal``) and
the filter stage (kind ``NAME.filter``): their parameters are every field of the tracker's
parameter dataclass plus ``seed`` and ``init`` (and ``timed`` for the proposal), as the built-in
box trackers' stages take; the filter's snapshot holds the state as the spec's ``to_arrays``
gives it. The stages know the tracker only through its spec (:mod:`stages.registry` asks
:func:`gflow_core.spec.trackers` for a kind no stage module declares).
"""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from gflow_core.spec import TrackerSpec

from .base import Stage
from .box_tracker import BoxFilterSpec, BoxFilterStage, BoxProposalSpec, BoxProposalStage, SnapshotCodec
from .messages import NDArray
from .tracker_params import SeedBoxFields, stage_params

__all__ = ["spec_stage_classes", "SpecProposalFields"]


class SpecProposalFields(SeedBoxFields, frozen=True):
    """The proposal's own fields: ``seed``, ``init`` and ``timed`` (also read the frames: the noise
    grows with the time to the next frame)."""

    timed: bool = False


class _Snapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    version: int
    initialised: bool
    arrays: dict[str, NDArray] = {}
    values: dict[str, Any] = {}
    steps: int = 0
    last: dict = {}


def _codec(spec: TrackerSpec) -> SnapshotCodec:
    box = spec.box
    assert box is not None

    def fields(state: Any) -> dict[str, Any]:
        arrays, values = box.to_arrays(state)
        return {"arrays": {k: NDArray.of(np.asarray(v)) for k, v in arrays.items()}, "values": dict(values)}

    def state(snap: _Snapshot, core: Any, last: dict) -> Any:
        return box.from_arrays({k: v.array() for k, v in snap.arrays.items()}, dict(snap.values), core)

    return SnapshotCodec(_Snapshot, box.snapshot_version, fields, state)


def _title(name: str) -> str:
    return "".join(w.capitalize() for w in name.split("_"))


def spec_stage_classes(spec: TrackerSpec) -> dict[str, type[Stage]]:
    """{kind: stage class} of the proposal and the filter stage of ``spec``'s tracker."""
    box = spec.box
    if box is None:
        raise ValueError(f"tracker {spec.name} has no box stages (BoxStages) in its spec")
    cap, cls = _title(spec.name), spec.params
    filter_params = stage_params(f"{cap}FilterParams", cls, SeedBoxFields, __name__,
                                 f"Filter settings of tracker {spec.name}: every field of {cls.__name__}, ``seed`` "
                                 f"and ``init``.")
    proposal_params = stage_params(f"{cap}ProposalParams", cls, SpecProposalFields, __name__,
                                   f"Proposal settings of tracker {spec.name}: every field of {cls.__name__} (the "
                                   f"filter's values), ``seed``, ``init`` and ``timed``.")
    filt = BoxFilterSpec(name=spec.name, tracker=spec.tracker(), params=cls, proposal=box.proposal,
                         particles=box.particles, alpha_of=box.alpha_of, particles_of=box.particles_of,
                         snapshot=_codec(spec))
    prop = BoxProposalSpec(name=spec.name, params=cls, walk=box.walk, purpose=box.purpose)
    doc = f"The {{}} stage of tracker {spec.name} ({spec.origin or 'registered'}): :mod:`stages.spec_box`."
    fcls = type(f"{cap}FilterStage", (BoxFilterStage,),
                {"kind": spec.filter_kind, "Params": filter_params, "box": filt, "__module__": __name__,
                 "__doc__": doc.format("filter")})
    pcls = type(f"{cap}ProposalStage", (BoxProposalStage,),
                {"kind": spec.proposal_kind, "Params": proposal_params, "box": prop, "__module__": __name__,
                 "__doc__": doc.format("proposal")})
    return {spec.filter_kind: fcls, spec.proposal_kind: pcls}
