"""``--tracker gflow``: G-flow (Marks, Hershey, Roddey & Movellan, NIPS 2004) on the graph ``gflow``.

The G-flow parameters must be equal in the proposal stage(s) and the filter: the graph names
them once, in its tracker block, which every one of them takes, and every option here sets it
(``--gflow-set NAME=VALUE``, kept for the scripts that use it, is ``--set tracker.NAME=VALUE``
for any parameter of :class:`gflow_core.gflow.GFlowParams`). ``--shards K`` builds K proposal stages
``proposal0 .. proposal{K-1}``, each proposing for one block of experts, all feeding the
filter: :func:`make_plan` generates that graph from the graph file.

``--model`` (the option is shared with ``--tracker m2``) is a morphable model file
(``pipeline.io.modelfile``, kind ``morphable``, e.g. from ``gflow learn gflow``), ``face`` (the
default: the face model shipped with gflow, ``pipeline/models/face.npz``) or ``ellipsoid`` (the
generic rigid head fitted into ``--init``).
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
from pathlib import Path
from typing import TYPE_CHECKING

from gflow_core.gflow.params import ELLIPSOID as ELLIPSOID_SETTINGS
from gflow_core.gflow.params import GFlowParams
from gflow_core.params import defaults

if TYPE_CHECKING:  # yaml and the graph (msgspec, zenoh, the stages) are imported where used: gflow track's options,
    # which every start of it builds, need neither
    from pipeline.runtime.graph import Plan

NAME = "gflow"
GRAPH = "gflow"
#: the tracker's parameters (every stage of the graph takes them)
PARAMS = GFlowParams

#: stage names of the graph
PROPOSAL, FILTER = "proposal", "filter"
#: ``--model`` names: the built-in face model (the default) and the generic ellipsoid head (its settings:
#: ``gflow_core.gflow.params.ELLIPSOID``)
DEFAULT_MODEL, ELLIPSOID = defaults(GFlowParams)["model"], "ellipsoid"
#: the models ``--model`` names by a word (:func:`pipeline.cli.trackers.check_model`)
MODEL_NAMES = (DEFAULT_MODEL, ELLIPSOID)
#: the kind of model file ``--model`` gives it (:data:`pipeline.io.modelfile.KINDS`)
MODEL_KIND = "morphable"


def add_args(g) -> None:
    """The options of G-flow's parameters that have one (``--experts``, ...; from
    :class:`gflow_core.gflow.GFlowParams`, with its help and default), ``--shards`` and ``--gflow-set``."""
    from pipeline.cli.commands.common import whole_number
    from pipeline.cli.tracker_options import add_param_options

    add_param_options(g, GFlowParams, NAME)
    g.add_argument("--shards", type=whole_number, default=1, metavar="K",
                   help="gflow: split the experts across K proposal processes (default 1)")
    g.add_argument("--gflow-set", action="append", metavar="NAME=VALUE", default=None,
                   help="gflow: set a G-flow parameter of the tracker block (every proposal stage and the filter), "
                        "e.g. psi_v=3e-4; the same as --set tracker.NAME=VALUE (`gflow info gflow` lists them)")


def _gflow_sets(items: list[str] | None) -> dict:
    import yaml

    from pipeline.cli.commands.common import CliError

    out: dict = {}
    known = {f.name for f in dataclasses.fields(GFlowParams)}
    for it in items or []:
        if "=" not in it:
            raise CliError(f"--gflow-set expects NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        if k.strip() not in known:
            close = difflib.get_close_matches(k.strip(), known, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise CliError(f"--gflow-set {it}: G-flow has no parameter {k.strip()!r} ({hint}`gflow info gflow` lists them)")
        out[k.strip()] = yaml.safe_load(v)
    return out


def _check_sets(block: dict, items: list[str] | None) -> None:
    """Refuse, naming the ``--gflow-set`` options as typed (not the graph file the values land in), a
    block of G-flow parameters they make invalid; the options named are those refused alone, else all."""
    from pipeline.cli.commands.common import CliError
    from pipeline.runtime.tracker_block import block_values

    if not items:
        return
    try:
        block_values(GFlowParams, block)
    except ValueError as e:
        names = {it: it.split("=", 1)[0].strip() for it in items}
        base = {k: v for k, v in block.items() if k not in names.values()}

        def refused(it: str) -> bool:
            try:
                block_values(GFlowParams, {**base, names[it]: block[names[it]]})
            except ValueError:
                return True
            return False

        alone = [it for it in items if refused(it)]
        raise CliError(" ".join(f"--gflow-set {it}" for it in alone or items) + f": {e}") from None


def overrides(args) -> tuple[str, dict[str, dict]]:
    """The tracker block gets the G-flow parameters, every stage the initial box and the seed, the
    filter also the number of shards."""
    from pipeline.cli.commands.common import CliError

    from pipeline.cli.tracker_options import param_values

    shared: dict = {"init": list(args.init), "seed": args.seed}
    block: dict = param_values(args, GFlowParams)
    model = getattr(args, "model", None) or DEFAULT_MODEL
    if model == ELLIPSOID:
        block.update(ELLIPSOID_SETTINGS)  # the stages fit the generic head into the initial box
    else:
        from gflow_core.gflow import MorphableModel

        from pipeline.cli.trackers import check_model
        from pipeline.io.modelfile import BUILTIN_MODELS, load_model, model_path

        check_model(NAME, model, "--model")
        path = model_path(model)
        obj = load_model(path)  # a missing or corrupt file fails here, before anything starts
        if not isinstance(obj, MorphableModel):
            raise CliError(f"{path} holds a {type(obj).__name__}; --tracker gflow needs a morphable model file "
                           f"(kind 'morphable')")
        block["model"] = model if model in BUILTIN_MODELS else str(path.resolve())
    block.update(_gflow_sets(getattr(args, "gflow_set", None)))
    _check_sets(block, getattr(args, "gflow_set", None))
    given = getattr(args, "shards", None)
    shards = 1 if given is None else int(given)  # 0 is a mistake to name, not the default
    if shards < 1:
        raise CliError(f"--shards must be >= 1, got {shards}")
    return GRAPH, {"tracker": block, PROPOSAL: dict(shared), FILTER: dict(shared, shards=shards)}


def make_plan(graph: str, over: dict[str, dict]) -> Plan:
    """The plan of ``graph`` (a file or a built-in name) with the filter's ``shards`` proposal stages.

    With one shard this is the graph as written. With K > 1 its stage ``proposal`` becomes
    ``proposal0 .. proposal{K-1}`` (params ``shard: k, shards: K``; output topic
    ``proposals{k}``) and the filter gets inputs ``proposals0 .. proposals{K-1}``;
    overrides for ``proposal`` apply to every shard.
    """
    from pipeline.runtime.graph import GRAPHS_DIR, GraphError, load_graph, parse_graph

    shards = int(over.get(FILTER, {}).get("shards", 1))
    if shards == 1:
        return load_graph(graph, overrides=over)
    p = Path(graph)
    if not p.is_file():
        p = GRAPHS_DIR / (p.name if p.suffix else p.name + ".yaml")
        if not p.is_file():
            raise GraphError(f"{graph} is a folder, not a graph file" if Path(graph).is_dir()
                             else f"graph file not found: {graph}")
    from pipeline.io.text_files import read_text

    text = sharded_graph_text(read_text(p, "graph file", GraphError), shards, str(p))
    return parse_graph(text, f"{p} ({shards} proposal shards)", ".", shard_overrides(over, shards))


def sharded_graph_text(text: str, shards: int, filename: str = "<graph>") -> str:
    """The YAML of a G-flow graph with its ``proposal`` stage split into ``shards`` stages."""
    import yaml

    from pipeline.runtime.graph import GraphError

    doc = yaml.safe_load(text)
    stages = doc.get("stages") if isinstance(doc, dict) else None
    if not isinstance(stages, dict) or PROPOSAL not in stages or FILTER not in stages:
        raise GraphError(f"{filename}: to split the proposals into {shards} shards the graph needs stages named "
                         f"{PROPOSAL!r} and {FILTER!r}")
    spec = stages[PROPOSAL]
    filt = copy.deepcopy(stages[FILTER])
    new: dict = {}
    for name, s in stages.items():
        if name == PROPOSAL:
            for k in range(shards):
                sk = copy.deepcopy(spec)
                sk["params"] = dict(sk.get("params") or {}, shard=k, shards=shards)
                sk["outputs"] = {"proposals": f"proposals{k}"}
                new[f"{PROPOSAL}{k}"] = sk
        elif name == FILTER:
            ins = {p: t for p, t in (filt.get("inputs") or {}).items() if not p.startswith("proposals")}
            ins.update({f"proposals{k}": f"proposals{k}" for k in range(shards)})
            filt["inputs"] = ins
            filt["params"] = dict(filt.get("params") or {}, shards=shards)
            new[name] = filt
        else:
            new[name] = s
    doc["stages"] = new
    return yaml.safe_dump(doc, sort_keys=False)


def shard_overrides(over: dict[str, dict], shards: int) -> dict[str, dict]:
    """Overrides for ``proposal`` copied to ``proposal0 .. proposal{K-1}`` (their shard numbers kept)."""
    out = {k: dict(v) for k, v in over.items() if k != PROPOSAL}
    for k in range(shards):
        kv = dict(over.get(PROPOSAL, {}))
        kv.update(out.get(f"{PROPOSAL}{k}", {}))
        kv.update(shard=k, shards=shards)
        out[f"{PROPOSAL}{k}"] = kv
    return out
