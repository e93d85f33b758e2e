"""``--tracker m2``: the Metric Mixture tracker with a learned model (``gflow learn m2``).

Contour models run the graph ``m2`` (particle filter over X = (alpha, k)); patch models
(shuffle / L2, e.g. mouths) run ``m2_patch`` (no alpha transform, sec. 5.2). The
preprocessing the model was learned with (chamfer profile and g0, Canny thresholds and
blur; the patch crop) is read from the model file and applied.

Each kind of model has its parameter dataclass (:data:`KINDS`): a contour model
:class:`gflow_core.contour.params.M2Params` (the graph's tracker block), a patch model
:class:`gflow_core.m2.patch_params.PatchParams` (graph ``m2_patch``'s tracker block). The options of both
derive from them; an option of one kind given with a model of the other is a one-line error, given
before anything starts.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, NamedTuple

from gflow_core.contour.params import M2Params
from gflow_core.m2.patch_params import PatchParams

NAME = "m2"
#: the tracker's parameters of a contour model (graph ``m2``; every stage but the preprocessing takes them)
PARAMS = M2Params
#: the built-in graph of a contour model (a patch model runs ``m2_patch``)
GRAPH = "m2"
#: no model is built in: ``--model`` names a file (:func:`pipeline.cli.trackers.check_model`)
MODEL_NAMES: tuple[str, ...] = ()
#: the kind of model file ``--model`` gives it (:data:`pipeline.io.modelfile.KINDS`)
MODEL_KIND = "m2"


class ModelKind(NamedTuple):
    """What a kind of model runs with: its name as the docs say it, its parameter dataclass, its graph."""

    label: str
    params: type
    graph: str


#: ``M2Model.kind`` -> what a model of that kind runs with (``gflow info m2`` lists each)
KINDS: dict[str, ModelKind] = {"curve": ModelKind("contour", M2Params, GRAPH),
                               "patch": ModelKind("patch", PatchParams, "m2_patch")}


def add_args(g: Any) -> None:
    """``--model``, and the options of each kind's parameter dataclass that declares one (``--crop``,
    ``--blank-std`` of a patch model); ``--particles`` is the appearance tracker's, read by name."""
    from pipeline.cli.tracker_options import add_param_options

    # --model is shared with --tracker gflow (a morphable model file there)
    g.add_argument("--model", metavar="MODEL.npz",
                   help="model file: m2 needs one learned by `gflow learn m2`; gflow takes a morphable model "
                        "file (`gflow learn gflow`), `face` (its default, the built-in face model) or `ellipsoid` "
                        "(a generic rigid head fitted into --init)")
    taken = frozenset(getattr(g, "_option_string_actions", {}))
    for kind in KINDS.values():
        add_param_options(g, kind.params, f"m2 with a {kind.label} model", skip=taken,
                          notes={"crop": "a model file's own: as its training patches were cut"})
        taken = frozenset(getattr(g, "_option_string_actions", {}))


def check_kind(args: Any, kind: str, path: Path) -> None:
    """An option of another kind of model than ``kind`` (the model file's, ``path``) is a ``CliError``
    naming it; so is a value the kind's parameters refuse (``--crop middle``)."""
    from gflow_core.params import describe

    from pipeline.cli.commands.common import CliError
    from pipeline.cli.tracker_options import check_param_values, option_dest

    own = KINDS[kind]
    mine = {i.name for i in describe(own.params)}
    for other in KINDS.values():
        for info in describe(other.params):
            if info.option is None or info.name in mine or getattr(args, option_dest(info), None) is None:
                continue
            raise CliError(f"{info.option} is an option of --tracker m2 with a {other.label} model; {path} holds a "
                           f"{own.label} model")
    try:
        check_param_values(args, [own.params], own.params)
    except ValueError as e:
        raise CliError(str(e)) from None


def overrides(args: Any) -> tuple[str, dict[str, dict]]:
    from gflow_core.m2.model import M2Model
    from gflow_core.params import make

    from pipeline.cli.commands.common import CliError
    from pipeline.cli.tracker_options import param_values
    from pipeline.cli.trackers import check_model
    from pipeline.io.modelfile import load_meta, load_model

    if not args.model:
        raise CliError("--tracker m2 needs --model MODEL.npz (learn one with `gflow learn m2`)")
    check_model(NAME, args.model, "--model")
    path = Path(args.model)
    model = load_model(path)  # a bad file fails here, before anything starts
    if not isinstance(model, M2Model):
        raise CliError(f"{path} holds a {type(model).__name__}, not an M2 model")
    check_kind(args, model.kind, path)
    meta = load_meta(path)
    mpath = str(path.resolve())
    box = list(args.init)
    particles = {"particles": args.particles} if getattr(args, "particles", None) is not None else {}
    if model.kind == "patch":
        from gflow_core.m2.patch_params import crop_of

        # the crop as the model's training patches were cut, unless given (as the Python API's setup reads it);
        # the filter reads the grey image alone (the graph's preprocess computes no edges)
        p = make(PatchParams, {"crop": crop_of(meta), **particles, **param_values(args, PatchParams)})
        return KINDS["patch"].graph, {
            "tracker": dataclasses.asdict(p),  # the graph's tracker block (PatchParams)
            "filter": {"model": mpath, "init": box, "seed": args.seed},
            "proposal": {"model": mpath, "seed": args.seed},
        }
    from gflow_core.contour.protocol import m2_edge_params

    # the edge settings the model was learned with, read from its file in one place (the Python API's too)
    try:
        edges = m2_edge_params(model, meta)
    except ValueError as e:  # the file's metadata: a one-line error naming it, before anything starts
        raise CliError(f"{path}: {e}") from None
    # and the factor that resamples the frame to the model's resolution (applied with preprocess.match_resolution)
    pre = dict(profile=edges.profile, g0=edges.g0, canny_low=edges.canny_low, canny_high=edges.canny_high,
               blur=edges.blur, model_scale=model.match_scale(tuple(box)))
    shared = {"model": mpath, "init": box, "seed": args.seed}
    block: dict = {**particles, **param_values(args, M2Params)}  # the tracker block: both stages take it
    return GRAPH, {"tracker": block, "filter": dict(shared), "proposal": dict(shared), "preprocess": pre}
