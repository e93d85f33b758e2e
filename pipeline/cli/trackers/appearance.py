"""``--tracker appearance`` (the default): M2 with online exemplars of edge-orientation channels.

See :mod:`gflow_core.appearance` for the method and its departures from Toyama & Blake.
"""

from __future__ import annotations

import math

NAME = "appearance"
GRAPH = "appearance"

#: random walk of the centre per frame, in units of sqrt(w h) of the initial box
STD_XY_REL = 0.08


def add_args(g) -> None:
    g.add_argument("--track-scale", action="store_true",
                   help="appearance: scale in the particle state (3 observed scales) instead of the default "
                        "scale search at the peak; the box drifts smaller on caviar1 and david_indoor "
                        "(README, 'Which tracker')")
    g.add_argument("--fixed-size", action="store_true",
                   help="appearance: the box keeps the size of the initial box (no scale search)")


def overrides(args) -> tuple[str, dict[str, dict]]:
    box = list(args.init)
    particles = getattr(args, "particles", None) or 300
    filt: dict = {"init": box, "particles": particles, "seed": args.seed}
    std_log_s = 0.0
    if getattr(args, "track_scale", False):
        std_log_s = 0.01
        filt.update(n_scales=3, std_log_s=std_log_s, scale_search=0)
    elif getattr(args, "fixed_size", False):
        filt.update(scale_search=0)
    return GRAPH, {
        "filter": filt,
        "proposal": {"seed": args.seed, "std_xy": STD_XY_REL * math.sqrt(max(box[2] * box[3], 1.0)),
                     "std_log_s": std_log_s},
    }
