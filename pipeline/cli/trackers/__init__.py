"""Trackers that ``gflow track --tracker NAME`` can run.

Each module here has ``NAME``, ``add_args(group)`` and ``overrides(args) -> (graph, {stage:
{param: value}})``; every module of this package is registered, so a tracker is one module.
"""

from __future__ import annotations

import importlib
import pkgutil

TRACKERS = {}
for _info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
    _mod = importlib.import_module(f"{__name__}.{_info.name}")
    TRACKERS[_mod.NAME] = _mod

__all__ = ["TRACKERS"]
