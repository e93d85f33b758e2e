"""Stage kinds by name, as graph files refer to them.

Two sources, read without importing any stage module (a stage process pays for its own stage's
imports only: importing every stage module pulls in scipy.ndimage, scipy.spatial and the G-flow
model, about 0.4 s of CPU per process at start-up):

* :data:`MODULES`, the generic stages, which belong to no tracker: the source, the preprocess and
  render stages, and the generic contour stages ``particle.proposal`` / ``particle.filter`` (graphs
  of your own, ``gflow demo``). A new generic stage module is one line here
  (``tests/test_stage_registry.py`` checks the table against the classes);
* the registry of trackers (:func:`gflow_core.registry.stage_kinds`): a tracker's spec names the
  modules of its stage classes that are modules of their own (:attr:`gflow_core.spec.TrackerSpec.stages`:
  the contour and patch trackers, G-flow, the appearance tracker's filter with its own snapshot
  Struct), and every other kind ``NAME.proposal`` / ``NAME.filter`` (``proposal_kind``,
  ``filter_kind``) of a spec with box stages (:class:`gflow_core.spec.BoxStages`) is the generic box
  stages' (:mod:`stages.spec_box`). A tracker is registered once, by its spec, and its stages follow.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping

from .base import Stage

__all__ = ["STAGES", "MODULES", "get_stage_class"]

#: {kind: module} of the generic stages (module docstring)
MODULES: dict[str, str] = {
    "source": "stages.source",
    "preprocess": "stages.preprocess",
    "render": "stages.overlay",
    "particle.proposal": "stages.particle_proposal",
    "particle.filter": "stages.particle_filter",
}


def _spec_kinds() -> dict[str, tuple[str | None, str]]:
    """:func:`gflow_core.registry.stage_kinds`, the registry read only when a kind is not in :data:`MODULES`."""
    from gflow_core.registry import stage_kinds

    return stage_kinds()


class _Stages(Mapping):
    """{kind: Stage class}, importing a stage's module when its class is first asked for."""

    def __init__(self) -> None:
        self._loaded: dict[str, type[Stage]] = {}

    def _load(self, kind: str) -> type[Stage]:
        """The class of ``kind`` (KeyError: none)."""
        module, name = (MODULES[kind], "") if kind in MODULES else _spec_kinds()[kind]
        if module is None:  # the generic box stages, made from the tracker's spec
            from gflow_core.registry import get

            from .spec_box import spec_stage_class

            return spec_stage_class(get(name), kind)
        mod = importlib.import_module(module)
        for cls in vars(mod).values():
            if isinstance(cls, type) and issubclass(cls, Stage) and cls.__dict__.get("kind") == kind:
                return cls
        raise RuntimeError(f"stage kind {kind!r}: {mod.__name__} defines no stage class of that kind")

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
