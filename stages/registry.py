"""Stage kinds by name, as graph files refer to them.

Every module of the ``stages`` package is scanned and each concrete :class:`Stage`
subclass with a ``kind`` is registered, so a new stage is one new module.

A registered tracker without stage modules of its own (:class:`gflow_core.spec.TrackerSpec` with
box stages and no graph file) gets its kinds ``NAME.proposal`` and ``NAME.filter`` from its spec
(:mod:`stages.spec_box`); the registry of trackers is read only for a kind no module declares.

A module is imported only when one of its kinds is asked for: the scan reads the source
(``kind = "..."`` in a class body) without importing it, so a stage process pays for its
own stage's imports only (importing every stage module pulls in scipy.ndimage,
scipy.spatial and the G-flow model: about 0.4 s of CPU per process at start-up).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from collections.abc import Iterator, Mapping
from pathlib import Path

from . import __path__ as _pkg_path
from .base import Stage

__all__ = ["STAGES", "get_stage_class"]


#: ``kind = "..."`` (or '...') in the body of a top-level class: a line indented by 4 spaces
#: after a ``class`` line at column 0 and before the next top-level def, class or decorator
_CLASS = re.compile(r"^class \w")
_TOP_DEF = re.compile(r"^(class |def |async def |@)")
_KIND = re.compile(r"""^    kind\s*(?::\s*[\w\[\]., ]+)?=\s*(["'])([^"'\\]+)\1\s*(?:#.*)?$""")


def _declared_kinds(path: Path) -> list[str]:
    """The ``kind = "..."`` string assignments in the class bodies of one module's source.

    A line scan, not ``ast.parse``: the index is built by every process that resolves a
    stage kind (the CLI and each stage process), and parsing every stage module took
    about 45 ms of CPU there (a scan: about 1 ms)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return []
    kinds, in_class = [], False
    for line in text.splitlines():
        if _TOP_DEF.match(line):
            in_class = bool(_CLASS.match(line))
        elif in_class:
            m = _KIND.match(line)
            if m:
                kinds.append(m.group(2))
    return kinds


def _index() -> dict[str, list[str]]:
    """{kind: [module names declaring it]} from the sources of the package."""
    found: dict[str, list[str]] = {}
    for info in sorted(pkgutil.iter_modules(_pkg_path), key=lambda i: i.name):
        if info.name in ("registry", "base") or info.name.startswith("_"):
            continue
        path = Path(_pkg_path[0]) / f"{info.name}.py"
        for kind in _declared_kinds(path) if path.is_file() else []:
            found.setdefault(kind, []).append(info.name)
    return found


def _classes(module: str) -> dict[str, type[Stage]]:
    """The concrete stage classes with a ``kind`` that one module defines."""
    mod = importlib.import_module(f"{__package__}.{module}")
    out: dict[str, type[Stage]] = {}
    for _, cls in inspect.getmembers(mod, inspect.isclass):
        if (issubclass(cls, Stage) and cls is not Stage and not inspect.isabstract(cls) and "kind" in cls.__dict__
                and cls.__module__ == mod.__name__):
            out[cls.kind] = cls
    return out


def _spec_kinds() -> dict[str, str]:
    """{kind: tracker name} of the registered trackers whose stages the generic box stages are."""
    from gflow_core.registry import trackers

    return {k: s.name for s in trackers().values() if s.box is not None and s.graph is None
            for k in (s.proposal_kind, s.filter_kind)}


class _Stages(Mapping):
    """{kind: Stage class}, importing a stage's module when its class is first asked for."""

    def __init__(self) -> None:
        self._where = _index()
        self._loaded: dict[str, type[Stage]] = {}

    def _of_spec(self, kind: str) -> type[Stage]:
        """The generic box stage of kind ``kind`` of a registered tracker (KeyError: none)."""
        name = _spec_kinds().get(kind)
        if name is None:
            raise KeyError(kind)
        from gflow_core.registry import get

        from .spec_box import spec_stage_classes

        self._loaded.update(spec_stage_classes(get(name)))
        return self._loaded[kind]

    def __getitem__(self, kind: str) -> type[Stage]:
        cls = self._loaded.get(kind)
        if cls is not None:
            return cls
        modules = self._where.get(kind)
        if not modules:
            return self._of_spec(kind)
        found = {m: c for m in modules if (c := _classes(m).get(kind)) is not None}
        if len(found) > 1:
            a, b = sorted(found)
            raise RuntimeError(f"stage kind {kind!r} defined twice: {__package__}.{a} and {__package__}.{b}")
        if not found:
            raise KeyError(kind)
        self._loaded[kind] = cls = next(iter(found.values()))
        return cls

    def __contains__(self, kind: object) -> bool:
        return kind in self._where or kind in _spec_kinds()

    def __iter__(self) -> Iterator[str]:
        return iter(sorted({*self._where, *_spec_kinds()}))

    def __len__(self) -> int:
        return len({*self._where, *_spec_kinds()})


STAGES: Mapping[str, type[Stage]] = _Stages()


def get_stage_class(kind: str) -> type[Stage]:
    try:
        return STAGES[kind]
    except KeyError:
        raise KeyError(f"unknown stage kind {kind!r}; known kinds: {', '.join(sorted(STAGES))}") from None
