"""One module per ``gflow`` command (or family of commands).

Each module has ``ORDER`` (its place in ``gflow --help``) and ``register(sub)``, which adds
its subparser(s) and sets ``func``. Every module of this package except ``common`` is
registered, so a command is one new module.
"""

from __future__ import annotations

import importlib
import pkgutil


def command_modules() -> list:
    mods = []
    for info in pkgutil.iter_modules(__path__):
        if info.name == "common" or info.name.startswith("_"):
            continue
        mods.append(importlib.import_module(f"{__name__}.{info.name}"))
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 100), m.__name__))
