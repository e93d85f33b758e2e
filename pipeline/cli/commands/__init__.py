"""One module per ``gflow`` command (or family of commands).

Each module has ``ORDER`` (its place in ``gflow --help``) and ``register(sub)``, which adds
its subparser(s) and sets ``func``. Every module of this package except ``common`` is
registered, so a command is one new module; :data:`COMMANDS` says which module registers each
command, so that ``gflow COMMAND`` imports that module alone (importing all of them and building
every subparser cost about 0.15 s of CPU at every start; ``tests/test_cli_startup.py`` checks the
table against what the modules register).
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

#: command -> the module of this package that registers it
COMMANDS = {
    "demo": "demo", "track": "track", "frame": "frame", "learn": "learn", "eval": "evaluate",
    "benchmark": "benchmark", "trax": "trax", "export": "export", "run": "run", "info": "recording",
    "replay": "recording", "rerun": "rerun", "step": "step", "diff": "diff", "verify": "verify",
    "recover": "recover", "boxes": "boxes", "clean": "clean", "render": "render", "foxglove": "foxglove",
    "plot": "plot", "ps": "inspect", "topics": "inspect", "echo": "inspect", "hz": "inspect", "pub": "inspect",
    "view": "view", "router": "router",
}


def command_modules() -> list:
    mods = []
    for info in pkgutil.iter_modules(__path__):
        if info.name == "common" or info.name.startswith("_"):
            continue
        mods.append(importlib.import_module(f"{__name__}.{info.name}"))
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 100), m.__name__))


def command_module(command: str) -> ModuleType | None:
    """The module that registers ``command`` (None for a name that is no command)."""
    name = COMMANDS.get(command)
    return importlib.import_module(f"{__name__}.{name}") if name else None
