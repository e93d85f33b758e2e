"""The stages of every registered tracker whose spec has box stages: the generic box stages
(:mod:`stages.box_tracker`) driven by its spec (:class:`gflow_core.spec.TrackerSpec` with
:class:`gflow_core.spec.BoxStages`). The correlation-filter tracker (``dcf``) and the appearance
tracker have such stages, as has a tracker another package registers.

:func:`spec_stage_class` makes, for one spec, the proposal stage (kind ``NAME.proposal``) and
the filter stage (kind ``NAME.filter``): their parameters are every field of the tracker's
parameter dataclass plus ``seed`` and ``init`` (and ``timed`` for the proposal: also read the
frames, the noise grows with the time to the next frame), from the graph's tracker block
(``tracker: NAME``, the same for both stages: :mod:`pipeline.runtime.tracker_block`); the filter's
snapshot (:class:`gflow_msgs.snapshots.BoxFilterSnapshot`, the spec's ``snapshot_version``) holds
the state as the spec's ``to_arrays`` gives it, or, for a spec that names a snapshot Struct of its own
(``BoxStages.snapshot``: the appearance tracker's ``AppearanceFilterSnapshot``, version 4), is that
Struct with the arrays and values as its fields. The stages know the tracker only through its spec
(:mod:`stages.registry` asks :func:`gflow_core.registry.trackers`).
"""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from gflow_core.spec import TrackerSpec

from .base import Stage
from .box_tracker import BoxFilterStage, BoxProposalStage, SnapshotCodec
from gflow_msgs.messages import NDArray
from gflow_msgs import snapshots
from gflow_msgs.snapshots import BoxFilterSnapshot
from .tracker_params import SeedBoxFields, tracker_stage

__all__ = ["spec_stage_class", "SpecProposalFields"]


class SpecProposalFields(SeedBoxFields, frozen=True):
    """The proposal's own fields: ``seed``, ``init`` and ``timed`` (also read the frames: the noise
    grows with the time to the next frame)."""

    timed: bool = False


def _codec(spec: TrackerSpec) -> SnapshotCodec:
    box = spec.box
    assert box is not None
    to_arrays, from_arrays = box.to_arrays, box.from_arrays
    if to_arrays is None or from_arrays is None:
        raise ValueError(f"tracker {spec.name}: its spec gives no state as arrays; its filter stage needs a "
                         f"snapshot codec of its own")

    if box.snapshot:  # a Struct of the tracker's own, whose fields are the state's arrays and values
        struct = getattr(snapshots, box.snapshot, None)
        if not isinstance(struct, type):
            raise ValueError(f"tracker {spec.name}: gflow_msgs.snapshots has no snapshot Struct {box.snapshot!r}")

        def flat(state: Any) -> dict[str, Any]:
            arrays, values = to_arrays(state)
            return {**{k: NDArray.of(np.asarray(v)) for k, v in arrays.items()}, **values}

        def of_flat(snap: Any, core: Any, last: dict) -> Any:
            fields = msgspec.structs.asdict(snap)
            arrays = {k: v.array() for k, v in fields.items() if isinstance(v, NDArray)}
            return from_arrays(arrays, {k: v for k, v in fields.items() if k not in arrays}, core)

        return SnapshotCodec(struct, box.snapshot_version, flat, of_flat)

    def fields(state: Any) -> dict[str, Any]:
        arrays, values = to_arrays(state)
        return {"arrays": {k: NDArray.of(np.asarray(v)) for k, v in arrays.items()}, "values": dict(values)}

    def state(snap: BoxFilterSnapshot, core: Any, last: dict) -> Any:
        return from_arrays({k: v.array() for k, v in snap.arrays.items()}, dict(snap.values), core)

    return SnapshotCodec(BoxFilterSnapshot, box.snapshot_version, fields, state)


def spec_stage_class(spec: TrackerSpec, kind: str) -> type[Stage]:
    """The proposal stage (``kind == spec.proposal_kind``) or the filter stage (``spec.filter_kind``)
    of ``spec``'s tracker."""
    if spec.box is None:
        raise ValueError(f"tracker {spec.name} has no box stages (BoxStages) in its spec")
    base: type[Stage]
    fields: type[SeedBoxFields]
    if kind == spec.filter_kind:
        role, base, fields, own = "Filter", BoxFilterStage, SeedBoxFields, ""
        what = {"tracker": spec.tracker(), "codec": _codec(spec)}
    elif kind == spec.proposal_kind:
        role, base, fields, what = "Proposal", BoxProposalStage, SpecProposalFields, {}
        own = " (the filter's values), ``seed``, ``init`` and ``timed``"
    else:
        raise KeyError(kind)
    return tracker_stage(base, spec, role, fields, __name__, f"{role} settings of tracker {spec.name}: every field of "
                         f"{spec.params.__name__}{own or ', ``seed`` and ``init``'}.",
                         f"The {role.lower()} stage of tracker {spec.name} ({spec.origin or 'registered'}): "
                         f":mod:`stages.spec_box`.", box=spec.box, **what)
