"""The registry of trackers: the built-in ones (:mod:`gflow_core.builtin_trackers`) and those other
packages register under the entry-point group ``gflow.trackers`` (:data:`~gflow_core.spec.ENTRY_POINT_GROUP`).

``gflow.Tracker``, ``gflow track --tracker``, ``gflow info TRACKER``, ``gflow benchmark --trackers``
and the stage registry (:func:`stage_kinds`) all ask it. It is read once per ``sys.path``.
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

from .builtin_trackers import BUILTIN
from .spec import ENTRY_POINT_GROUP, SpecError, TrackerSpec

__all__ = ["trackers", "broken", "get", "names", "stage_kinds"]

_cache: dict[tuple[str, ...], tuple[dict[str, TrackerSpec], dict[str, str]]] = {}


def _entry_points() -> list[Any]:
    from importlib.metadata import entry_points

    return sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name)


def _load() -> tuple[dict[str, TrackerSpec], dict[str, str]]:
    """({name: spec}, {name: why its registration is broken}), read once per ``sys.path``."""
    key = tuple(sys.path)
    hit = _cache.get(key)
    if hit is not None:
        return hit
    specs = {s.name: s for s in BUILTIN}
    bad: dict[str, str] = {}
    for ep in _entry_points():
        where = f"entry point {ep.name} = {ep.value} (group {ENTRY_POINT_GROUP})"
        try:
            obj = ep.load()
        except Exception as e:  # noqa: BLE001 (any error of another package's import is its fault)
            bad[ep.name] = f"tracker {ep.name}: {where} cannot be loaded: {type(e).__name__}: {e}".replace("\n", " ")
            continue
        if not isinstance(obj, TrackerSpec):
            bad[ep.name] = f"tracker {ep.name}: {where} is a {type(obj).__name__}, not a gflow_core.spec.TrackerSpec"
        elif obj.name != ep.name:
            bad[ep.name] = f"tracker {ep.name}: {where} holds the spec of tracker {obj.name!r}"
        elif ep.name in specs:
            bad[ep.name] = f"tracker {ep.name}: {where} clashes with the built-in tracker {ep.name}"
        else:
            specs[ep.name] = dataclasses.replace(obj, origin=where)
    _cache[key] = (specs, bad)
    return specs, bad


def trackers() -> dict[str, TrackerSpec]:
    """Every tracker: the built-in ones and those of the entry-point group ``gflow.trackers``, by name
    (sorted). A broken registration is left out (:func:`broken` says why)."""
    specs = _load()[0]
    return {n: specs[n] for n in sorted(specs)}


def broken() -> dict[str, str]:
    """{name: one line saying why} of the entry points of ``gflow.trackers`` that cannot be used."""
    return dict(_load()[1])


def names() -> list[str]:
    """The names of the usable trackers, sorted."""
    return sorted(_load()[0])


def get(name: str) -> TrackerSpec:
    """The spec of tracker ``name``; :class:`SpecError` (one line) for a name not registered or a
    broken registration."""
    specs, bad = _load()
    if name in specs:
        return specs[name]
    if name in bad:
        raise SpecError(bad[name])
    raise SpecError(f"unknown tracker {name!r} (known: {', '.join(sorted(specs))})")


def stage_kinds() -> dict[str, tuple[str | None, str]]:
    """{kind: (the module of its stage class, or None for the generic box stages; the tracker whose spec
    gives it)} of every registered tracker's stages: the kinds its spec names a module for
    (:attr:`~gflow_core.spec.TrackerSpec.stages`), and ``proposal_kind`` / ``filter_kind`` of a spec with
    box stages. A kind several specs give (a spec copied with ``dataclasses.replace`` keeps its kinds)
    is the tracker's it is named for (``NAME.filter``), else the last one's by name."""
    out: dict[str, tuple[str | None, str]] = {}
    for s in trackers().values():
        kinds: dict[str, str | None] = {k: None for k in (s.proposal_kind, s.filter_kind) if s.box is not None}
        kinds.update(s.stages)
        for k, module in kinds.items():
            if k not in out or out[k][1] != k.split(".")[0]:
                out[k] = (module, s.name)
    return out
