"""``--tracker m2``: the Metric Mixture tracker with a learned model (``gflow learn m2``).

Contour models run the graph ``m2`` (particle filter over X = (alpha, k)); patch models
(shuffle / L2, e.g. mouths) run ``m2_patch`` (no alpha transform, sec. 5.2). The
preprocessing the model was learned with (chamfer profile and g0, Canny thresholds and
blur; the patch crop) is read from the model file and applied.
"""

from __future__ import annotations

from pathlib import Path

from gflow_core.contour.params import M2Params

NAME = "m2"
#: the tracker's parameters of a contour model (graph ``m2``; every stage but the preprocessing takes them)
PARAMS = M2Params
#: the built-in graph of a contour model (a patch model runs ``m2_patch``)
GRAPH = "m2"


def add_args(g) -> None:
    # --particles is shared with the appearance tracker (it adds the option); --model is shared
    # with --tracker gflow (a morphable model file there)
    g.add_argument("--model", metavar="MODEL.npz",
                   help="model file: m2 needs one learned by `gflow learn m2`; gflow takes a morphable model "
                        "file (`gflow learn gflow`), `face` (its default, the built-in face model) or `ellipsoid` "
                        "(a generic rigid head fitted into --init)")


def overrides(args) -> tuple[str, dict[str, dict]]:
    from gflow_core.m2.model import M2Model

    from pipeline.cli.commands.common import CliError
    from pipeline.io.modelfile import load_meta, load_model

    if not args.model:
        raise CliError("--tracker m2 needs --model MODEL.npz (learn one with `gflow learn m2`)")
    path = Path(args.model)
    model = load_model(path)  # a missing or bad file fails here, before anything starts
    if not isinstance(model, M2Model):
        raise CliError(f"{path} holds a {type(model).__name__}, not an M2 model")
    meta = load_meta(path)
    mpath = str(path.resolve())
    box = list(args.init)
    if model.kind == "patch":
        from gflow_core.m2.patch_protocol import PatchParams, crop_of

        # the filter reads the grey image alone (the graph's preprocess computes no edges)
        particles = args.particles if getattr(args, "particles", None) is not None else PatchParams().particles
        crop = crop_of(meta)  # as the Python API's setup reads it
        return "m2_patch", {
            "filter": {"model": mpath, "init": box, "particles": particles, "seed": args.seed, "crop": crop},
            "proposal": {"model": mpath, "seed": args.seed},
        }
    from gflow_core.contour.protocol import m2_edge_params

    # the edge settings the model was learned with, read from its file in one place (the Python API's too)
    edges = m2_edge_params(model, meta)
    pre = dict(profile=edges.profile, g0=edges.g0, canny_low=edges.canny_low, canny_high=edges.canny_high,
               blur=edges.blur)
    shared = {"model": mpath, "init": box, "seed": args.seed}
    block: dict = {}
    if getattr(args, "particles", None) is not None:
        block["particles"] = args.particles  # the tracker block: both stages take it
    return GRAPH, {"tracker": block, "filter": dict(shared), "proposal": dict(shared), "preprocess": pre}
