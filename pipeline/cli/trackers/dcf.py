"""``--tracker dcf`` (the default): a particle filter whose likelihood is a correlation filter learnt online.

See :mod:`gflow_core.dcf` for the method, its papers and its departures. Its parameters are
:class:`gflow_core.dcf.params.DCFParams` (``gflow info dcf``): the graph names them once, in its
tracker block, and both stages take them from it, so every option here sets both.
"""

from __future__ import annotations

from typing import Any

from gflow_core.dcf.params import DCFParams

NAME = "dcf"
GRAPH = "dcf"
#: the tracker's parameters (every stage of the graph takes them)
PARAMS = DCFParams
#: stage names of the graph
PROPOSAL, FILTER = "proposal", "filter"


def add_args(g: Any) -> None:
    """No options of its own: ``--particles`` is added by the appearance tracker (its parameter
    dataclass holds the option) and read here too; every other parameter is set with
    ``--set tracker.NAME=VALUE``."""


def overrides(args: Any) -> tuple[str, dict[str, dict]]:
    """Both stages get the initial box and the seed, the tracker block ``--particles``."""
    shared: dict = {"init": list(args.init), "seed": args.seed}
    block: dict = {}
    if getattr(args, "particles", None):
        block["particles"] = args.particles
    return GRAPH, {"tracker": block, PROPOSAL: dict(shared), FILTER: dict(shared)}
