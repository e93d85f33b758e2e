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

import typing
from typing import Any, TypeVar

from gflow_core.spec import TrackerSpec

from .base import Stage
from .box_tracker import BoxFilterStage, BoxProposalStage
from gflow_msgs.params import SeedBoxFields, StageFields, stage_params
from gflow_msgs.snapshots import SnapshotCodec, arrays_codec

__all__ = ["spec_stage_class", "SpecProposalFields", "tracker_stage"]

S = TypeVar("S", bound=type)


class SpecProposalFields(SeedBoxFields, frozen=True):
    """The proposal's own fields: ``seed``, ``init`` and ``timed`` (also read the frames: the noise
    grows with the time to the next frame)."""

    timed: bool = False


def _codec(spec: TrackerSpec) -> SnapshotCodec:
    """The filter's snapshot codec of the state the spec gives as arrays (:func:`gflow_msgs.snapshots.arrays_codec`)."""
    box = spec.box
    assert box is not None
    if box.to_arrays is None or box.from_arrays is None:
        raise ValueError(f"tracker {spec.name}: its spec gives no state as arrays; its filter stage needs a "
                         f"snapshot codec of its own")
    try:
        return arrays_codec(box.to_arrays, box.from_arrays, box.snapshot_version, box.snapshot)
    except ValueError as e:
        raise ValueError(f"tracker {spec.name}: {e}") from None


class _Loaded:
    """A class attribute made by ``load()`` when first read: the filter stage's tracker, whose modules (the update,
    SciPy for some) are imported when the stage runs, not when a graph that names the stage is checked (every
    ``gflow track`` and ``gflow run`` parses its graph, also to find a mistake in the command, and its launcher
    never runs the tracker)."""

    def __init__(self, load: Any) -> None:
        self._load, self._value = load, None

    def __get__(self, obj: object, owner: type | None = None) -> Any:
        if self._value is None:
            self._value = self._load()
        return self._value


def spec_stage_class(spec: TrackerSpec, kind: str) -> type[Stage]:
    """The proposal stage (``kind == spec.proposal_kind``) or the filter stage (``spec.filter_kind``)
    of ``spec``'s tracker."""
    if spec.box is None:
        raise ValueError(f"tracker {spec.name} has no box stages (BoxStages) in its spec")
    base: type[Stage]
    fields: type[SeedBoxFields]
    if kind == spec.filter_kind:
        role, base, fields = "Filter", BoxFilterStage, SeedBoxFields
        what = {"tracker": _Loaded(spec.tracker), "codec": _codec(spec)}
    elif kind == spec.proposal_kind:
        role, base, fields, what = "Proposal", BoxProposalStage, SpecProposalFields, {}
    else:
        raise KeyError(kind)
    return tracker_stage(base, spec, role, fields, __name__, ": :mod:`stages.spec_box`", box=spec.box, **what)


def tracker_stage(base: S, spec: TrackerSpec, role: str, fields: type[StageFields], module: str, about: str = "",
                  **attrs: Any) -> S:
    """The ``role`` (``"Proposal"`` or ``"Filter"``) stage of ``spec``'s tracker, a subclass of ``base``
    named ``{Name}{role}Stage`` in ``module``: its kind ``spec.proposal_kind`` or ``spec.filter_kind``,
    its ``Params`` the struct ``{Name}{role}Params`` of every field of ``spec.params`` and those of
    ``fields`` (:func:`gflow_msgs.params.stage_params`), its docstring naming the tracker and ending with
    ``about``, and the class attributes ``attrs``."""
    cap = "".join(w.capitalize() for w in spec.name.split("_"))
    kind = {"Proposal": spec.proposal_kind, "Filter": spec.filter_kind}[role]
    cls, own = spec.params, fields
    params = stage_params(f"{cap}{role}Params", cls, fields, module,
                          f"{role} settings of tracker {spec.name}: every field of :class:`{cls.__module__}."
                          f"{cls.__qualname__}` and those of :class:`{own.__module__}.{own.__qualname__}`.")
    doc = f"The {role.lower()} stage of tracker {spec.name} ({spec.origin or 'registered'}){about}."
    return typing.cast(S, type(f"{cap}{role}Stage", (base,), {"kind": kind, "Params": params, "__module__": module,
                                                              "__doc__": doc, **attrs}))
