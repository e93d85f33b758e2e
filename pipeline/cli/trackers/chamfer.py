"""``--tracker chamfer``: M2 with K = 1, the template from the edges inside the initial box."""

from __future__ import annotations

NAME = "chamfer"
GRAPH = "chamfer"


def add_args(g) -> None:
    """No options of its own: ``--particles`` is added by the appearance tracker (its parameter
    dataclass holds the option) and read here too."""


def overrides(args) -> tuple[str, dict[str, dict]]:
    box = list(args.init)
    return GRAPH, {
        "filter": {"init": box, "particles": args.particles or 500, "seed": args.seed},
        "proposal": {"seed": args.seed},
        "preprocess": {"calibrate_box": box},
    }
