"""Stage kinds by name, as graph files refer to them.

Every module of the ``stages`` package is imported and each concrete :class:`Stage`
subclass with a ``kind`` is registered, so a new stage is one new module.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

from . import __path__ as _pkg_path
from .base import Stage

__all__ = ["STAGES", "get_stage_class"]


def _discover() -> dict[str, type[Stage]]:
    found: dict[str, type[Stage]] = {}
    for info in sorted(pkgutil.iter_modules(_pkg_path), key=lambda i: i.name):
        if info.name in ("registry", "base") or info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__package__}.{info.name}")
        for _, cls in inspect.getmembers(mod, inspect.isclass):
            if issubclass(cls, Stage) and cls is not Stage and not inspect.isabstract(cls) and "kind" in cls.__dict__:
                other = found.get(cls.kind)
                if other is not None and other is not cls:
                    raise RuntimeError(f"stage kind {cls.kind!r} defined twice: {other.__module__} and {cls.__module__}")
                found[cls.kind] = cls
    return found


STAGES: dict[str, type[Stage]] = _discover()


def get_stage_class(kind: str) -> type[Stage]:
    try:
        return STAGES[kind]
    except KeyError:
        raise KeyError(f"unknown stage kind {kind!r}; known kinds: {', '.join(sorted(STAGES))}") from None
