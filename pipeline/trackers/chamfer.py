"""``--tracker chamfer``: M2 with K = 1, the template from the edges inside the initial box."""

from __future__ import annotations

NAME = "chamfer"
GRAPH = "chamfer"


def add_args(g) -> None:
    g.add_argument("--particles", type=int, default=500, help="number of particles (chamfer, m2; default 500)")


def overrides(args) -> tuple[str, dict[str, dict]]:
    box = list(args.init)
    return GRAPH, {
        "filter": {"init": box, "particles": args.particles, "seed": args.seed},
        "proposal": {"seed": args.seed},
        "preprocess": {"calibrate_box": box},
    }
