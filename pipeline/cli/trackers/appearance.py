"""``--tracker appearance``: M2 with online exemplars of edge-orientation channels.

See :mod:`gflow_core.appearance.filter` for the method and its departures from Toyama & Blake. Its
parameters are :class:`gflow_core.appearance.params.AppearanceParams` (``gflow info appearance``):
the graph names them once, in its tracker block, and both stages take them from it, so every
option here sets both.
"""

from __future__ import annotations

from typing import Any

from gflow_core.appearance.params import FIXED_SIZE, TRACK_SCALE, AppearanceParams

NAME = "appearance"
GRAPH = "appearance"
#: the tracker's parameters (every stage of the graph takes them)
PARAMS = AppearanceParams
#: stage names of the graph
PROPOSAL, FILTER = "proposal", "filter"


def _preset(values: Any) -> str:
    return ", ".join(f"{k}={v}" for k, v in values.items())


def add_args(g: Any) -> None:
    """The options of the appearance parameters that have one (``--particles``, from the dataclass with
    its help and default; shared with chamfer and m2) and the two size presets."""
    from pipeline.cli.tracker_options import add_param_options

    from gflow_core.params import defaults
    from gflow_core.registry import trackers

    # the other trackers with a parameter ``particles`` read --particles too: their defaults
    others = {n: defaults(s.params)["particles"] for n, s in trackers().items()
              if n != NAME and "particles" in defaults(s.params)}
    add_param_options(g, AppearanceParams, NAME, notes={"particles": ", ".join(f"{n} {v}" for n, v in others.items())})
    g.add_argument("--track-scale", action="store_true",
                   help=f"appearance: scale in the particle state ({_preset(TRACK_SCALE)}) instead of the default "
                        "scale search at the peak; the box drifts smaller on caviar1 and david_indoor "
                        "(docs/trackers.md)")
    g.add_argument("--fixed-size", action="store_true",
                   help=f"appearance: the box keeps the size of the initial box ({_preset(FIXED_SIZE)})")


def overrides(args: Any) -> tuple[str, dict[str, dict]]:
    """The tracker block gets the appearance parameters, both stages the initial box and the seed."""
    from pipeline.cli.tracker_options import param_values

    shared: dict = {"init": list(args.init), "seed": args.seed}
    block: dict = param_values(args, AppearanceParams)
    if getattr(args, "track_scale", False):
        block.update(TRACK_SCALE)
    elif getattr(args, "fixed_size", False):
        block.update(FIXED_SIZE)
    return GRAPH, {"tracker": block, PROPOSAL: dict(shared), FILTER: dict(shared)}
