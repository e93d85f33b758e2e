"""Stage kinds by name, as graph files refer to them.

Two sources, read without importing any stage module (a stage process pays for its own stage's
imports only: importing every stage module pulls in scipy.ndimage, scipy.spatial and the G-flow
model, about 0.4 s of CPU per process at start-up):

* :data:`MODULES`, the stage modules and the kinds each declares: the generic stages (source,
  preprocess, render) and the trackers whose stages are modules of their own (the contour and patch
  trackers, G-flow, and the appearance tracker's filter with its own snapshot Struct). A new stage
  module is one line here (``tests/test_stage_registry.py`` checks the table against the classes);
* the registry of trackers (:func:`gflow_core.registry.trackers`): every tracker whose spec has box
  stages (:class:`gflow_core.spec.BoxStages`) gets its kinds ``NAME.proposal`` and ``NAME.filter``
  (``proposal_kind``, ``filter_kind``) from its spec, as the generic box stages
  (:mod:`stages.spec_box`), unless :data:`MODULES` names a module for the kind. A tracker is
  registered once, by its spec, and its stages follow.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping

from .base import Stage

__all__ = ["STAGES", "MODULES", "get_stage_class"]

#: {kind: module of the ``stages`` package that defines its class}
MODULES: dict[str, str] = {
    "source": "source",
    "preprocess": "preprocess",
    "render": "overlay",
    "particle.proposal": "particle_proposal", "chamfer.proposal": "particle_proposal", "m2.proposal": "particle_proposal",
    "particle.filter": "particle_filter", "chamfer.filter": "particle_filter", "m2.filter": "particle_filter",
    "patch.filter": "patch_filter",
    "appearance.filter": "appearance_filter",
    "gflow.proposal": "gflow_proposal", "gflow.filter": "gflow_filter",
}


def _spec_kinds() -> dict[str, str]:
    """{kind: tracker name} of the registered trackers whose stages are the generic box stages."""
    from gflow_core.registry import trackers

    return {k: s.name for s in trackers().values() if s.box is not None
            for k in (s.proposal_kind, s.filter_kind) if k not in MODULES}


class _Stages(Mapping):
    """{kind: Stage class}, importing a stage's module when its class is first asked for."""

    def __init__(self) -> None:
        self._loaded: dict[str, type[Stage]] = {}

    def _load(self, kind: str) -> type[Stage]:
        """The class of ``kind`` (KeyError: none)."""
        module = MODULES.get(kind)
        if module is not None:
            mod = importlib.import_module(f"{__package__}.{module}")
            for cls in vars(mod).values():
                if isinstance(cls, type) and issubclass(cls, Stage) and cls.__dict__.get("kind") == kind:
                    return cls
            raise RuntimeError(f"stage kind {kind!r}: {mod.__name__} defines no stage class of that kind")
        name = _spec_kinds().get(kind)
        if name is None:
            raise KeyError(kind)
        from gflow_core.registry import get

        from .spec_box import spec_stage_class

        return spec_stage_class(get(name), kind)

    def __getitem__(self, kind: str) -> type[Stage]:
        cls = self._loaded.get(kind)
        if cls is None:
            self._loaded[kind] = cls = self._load(kind)
        return cls

    def __contains__(self, kind: object) -> bool:
        return kind in MODULES or kind in _spec_kinds()

    def __iter__(self) -> Iterator[str]:
        return iter(sorted({*MODULES, *_spec_kinds()}))

    def __len__(self) -> int:
        return len({*MODULES, *_spec_kinds()})


STAGES: Mapping[str, type[Stage]] = _Stages()


def get_stage_class(kind: str) -> type[Stage]:
    try:
        return STAGES[kind]
    except KeyError:
        raise KeyError(f"unknown stage kind {kind!r}; known kinds: {', '.join(sorted(STAGES))}") from None
