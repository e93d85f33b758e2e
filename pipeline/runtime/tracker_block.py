"""A graph's ``tracker:`` block: the tracker's parameters, named once for every stage of it.

A graph names its tracker and that tracker's parameter values once::

    tracker:
      name: dcf
      params: {particles: 300}     # optional: the parameter dataclass's defaults fill in the rest

(``tracker: dcf`` alone takes every default). The block is checked against the tracker's
parameter dataclass (:attr:`gflow_core.spec.TrackerSpec.params`, or the one of its
:attr:`~gflow_core.spec.TrackerSpec.variants` the graph's stages are made of: m2's ``PatchParams``
in graph ``m2_patch``) as its stages check them
(:func:`gflow_msgs.params.block_params`), and every stage whose parameter struct is made of
that dataclass (:func:`gflow_msgs.params.tracker_of`) takes its values from it: such a stage's
entry in the graph keeps only its own fields (``seed``, ``init``, ``timed``, ``shards``...). A
stage naming a tracker parameter itself is refused with a line naming ``tracker.PARAM``, so the
stages of one run can never disagree. ``--set tracker.PARAM=VALUE`` (an override of the
pseudo-stage ``tracker``) changes the block.

A graph without a block (older graph files, and the plans of recordings made before the block
existed) keeps its per-stage values as they are; overrides of ``tracker`` are then applied to
every stage of a tracker, as the per-stage copies were set before.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from dataclasses import dataclass
from typing import Any, Mapping

import msgspec

from stages.base import Params
from gflow_msgs.params import block_params, tracker_of

__all__ = ["TRACKER_KEY", "TrackerBlock", "parse_block", "tracker_fields", "own_fields", "stage_tracker",
           "block_class", "is_main_class"]

#: the graph's top-level key of the block, and the pseudo-stage ``--set tracker.PARAM=VALUE`` names
TRACKER_KEY = "tracker"


@dataclass
class TrackerBlock:
    """The tracker of a graph and its parameters: ``params`` holds every field of its parameter
    dataclass (defaults filled in) as plain data, as a stage's struct of that dataclass holds it."""

    name: str
    params: dict[str, Any]


def _classes_of(name: str) -> tuple[type, ...]:
    """The parameter dataclasses of the registered tracker ``name``, its own first, then its variants
    (``ValueError``, one line)."""
    from gflow_core.registry import get

    spec = get(name)  # SpecError (a ValueError) names an unknown tracker
    return (spec.params, *spec.variants)


def _dataclass_of(name: str, stages: frozenset[type] = frozenset()) -> type:
    """The parameter dataclass of the registered tracker ``name`` a graph's block takes: the variant
    its tracker stages are made of (``stages``), else the tracker's own."""
    own, *variants = _classes_of(name)
    return next((v for v in variants if v in stages), own)


def block_class(block: TrackerBlock) -> type:
    """The parameter dataclass of ``block`` (of a graph or a recorded plan): of its tracker's, the one
    whose fields the block holds."""
    from gflow_core.params import added_later

    classes = _classes_of(block.name)
    held = set(block.params)  # a block recorded before a parameter was added lacks it
    return next((c for c in classes if held <= set(tracker_fields(c)) and set(tracker_fields(c)) - held
                 <= set(added_later(c))), classes[0])


def is_main_class(block: TrackerBlock) -> bool:
    """Whether ``block`` holds its tracker's own parameter dataclass (not one of its variants)."""
    return block_class(block) is _classes_of(block.name)[0]


def tracker_fields(cls: type) -> list[str]:
    """The names of the fields of a tracker's parameter dataclass, in declaration order."""
    return [f.name for f in dataclasses.fields(cls)]


def block_values(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` checked as parameters of ``cls`` and completed with its defaults, as plain data.
    ``ValueError`` (one line, naming the parameter) for an unknown name or a bad value."""
    known = tracker_fields(cls)
    unknown = [k for k in values if k not in known]
    if unknown:
        close = difflib.get_close_matches(unknown[0], known, n=1)  # a typo is named first, before the whole list
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise ValueError(f"{cls.__name__} has no parameter {unknown[0]!r} ({hint}known: {', '.join(known)})")
    try:
        return msgspec.to_builtins(msgspec.convert(dict(values), block_params(cls), strict=False))
    except msgspec.ValidationError as e:
        raise ValueError(plain_type_error(str(e), values)) from None
    except (ValueError, TypeError) as e:
        raise ValueError(str(e)) from None


#: msgspec's names of the types a parameter can have, as a user reads them
_KINDS = {"int": "a whole number", "float": "a number", "bool": "true or false", "str": "a string",
          "array": "a list", "object": "a mapping"}
_MSGSPEC_TYPE_ERROR = re.compile(r"Expected `([^`]+)`, got `[^`]+` - at `\$\.(\w+)`")


def plain_type_error(message: str, values: Mapping[str, Any]) -> str:
    """msgspec's ``Expected `int`, got `str` - at `$.particles``` as ``particles must be a whole
    number, got 'nan'``; any other message as it is."""
    m = _MSGSPEC_TYPE_ERROR.fullmatch(message)
    if m is None or m.group(2) not in values:
        return message
    kinds = [_KINDS.get(k.strip(), k.strip()) for k in m.group(1).split("|")]
    return f"{m.group(2)} must be {' or '.join(kinds)}, got {values[m.group(2)]!r}"


def parse_block(doc: Any, override: Mapping[str, Any], stages: frozenset[type] = frozenset()) -> TrackerBlock:
    """The block of a graph's ``tracker:`` entry (a name, or ``{name: ..., params: {...}}``) with
    ``override`` ({param: value}) applied; ``ValueError`` (one line) for a bad one. ``stages``: the
    parameter dataclasses the graph's tracker stages are made of, which settle a tracker's variant."""
    values: dict[str, Any] = {}
    name: Any = doc
    if isinstance(doc, str):
        pass
    elif isinstance(doc, dict):
        extra = sorted(set(doc) - {"name", "params"})
        if extra:
            raise ValueError(f"tracker: unknown key {extra[0]!r} (expected name and params)")
        name, values = doc.get("name"), doc.get("params") or {}
        if not isinstance(values, dict):
            raise ValueError("tracker: params must be a mapping of parameter -> value")
    else:
        raise ValueError("tracker: give the tracker's name (tracker: dcf) or {name: NAME, params: {...}}")
    if not isinstance(name, str) or not name:
        raise ValueError("tracker: the block needs the tracker's name (name: dcf)")
    cls = _dataclass_of(name, stages)
    try:
        return TrackerBlock(name=name, params=block_values(cls, {**values, **override}))
    except ValueError as e:
        raise ValueError(f"tracker {name}: {e}") from None


def stage_tracker(struct: type[Params] | None) -> type | None:
    """The tracker dataclass a stage's parameter struct is made of (None: a stage of no tracker)."""
    return tracker_of(struct) if struct is not None else None


def own_fields(params: Mapping[str, Any], cls: type) -> dict[str, Any]:
    """A stage's parameters without those of the tracker dataclass ``cls`` (they live in the block)."""
    shared = set(tracker_fields(cls))
    return {k: v for k, v in params.items() if k not in shared}
