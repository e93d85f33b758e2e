"""``--tracker chamfer``: M2 with K = 1, the template from the edges inside the initial box.

Its parameters are :class:`gflow_core.contour.params.ChamferParams` (``gflow info chamfer``): the
graph names them once, in its tracker block, and the proposal and the filter take them from it, so
every option sets both.
"""

from __future__ import annotations

from typing import Any

from gflow_core.contour.params import ChamferParams

NAME = "chamfer"
GRAPH = "chamfer"
#: the tracker's parameters (every stage of the graph but the preprocessing takes them)
PARAMS = ChamferParams


def add_args(g: Any) -> None:
    """No options of its own: ``--particles`` is added by the appearance tracker (its parameter
    dataclass holds the option) and read here too."""


def overrides(args: Any) -> tuple[str, dict[str, dict]]:
    """Both stages get the initial box and the seed, the tracker block ``--particles``; the
    preprocessing calibrates its Canny thresholds on the initial box."""
    box = list(args.init)
    shared: dict = {"init": box, "seed": args.seed}
    block: dict = {}
    if getattr(args, "particles", None) is not None:
        block["particles"] = args.particles
    return GRAPH, {"tracker": block, "filter": dict(shared), "proposal": dict(shared),
                   "preprocess": {"calibrate_box": box}}
