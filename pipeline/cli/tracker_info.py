"""``gflow info TRACKER``: a registered tracker's parameters with their defaults and help, and each
stage's own parameters with its graph's values."""

from __future__ import annotations

import re
from typing import Any

from gflow_core.params import describe, format_value

from pipeline.cli.tracker_options import param_table

__all__ = ["tracker_description", "print_tracker"]


def _stages(plan: Any, shared: set[str]) -> list[dict[str, Any]]:
    """For every stage of ``plan`` but the source and the recorder: its own parameters (those not in
    ``shared``, the tracker's) with their defaults and the graph's values."""
    import msgspec

    from stages.registry import get_stage_class

    from pipeline.runtime.graph import RECORDER_KIND

    stages = []
    for sname, sp in plan.stages.items():
        if sp.kind in (RECORDER_KIND, "source"):
            continue
        fields = msgspec.structs.fields(get_stage_class(sp.kind).Params)
        own = [{"name": f.name, "default": format_value(None if f.default is msgspec.NODEFAULT else f.default),
                "graph": format_value(sp.params.get(f.name))} for f in fields if f.name not in shared]
        stages.append({"stage": sname, "kind": sp.kind, "params": own})
    return stages


def _takers(plan: Any, cls: type) -> list[str]:
    """The stages of ``plan`` built with every parameter of ``cls`` (for a graph without a tracker block)."""
    import msgspec

    from stages.registry import get_stage_class

    from pipeline.runtime.graph import RECORDER_KIND

    names = {i.name for i in describe(cls)}
    return [n for n, sp in plan.stages.items() if sp.kind != RECORDER_KIND
            and names <= {f.name for f in msgspec.structs.fields(get_stage_class(sp.kind).Params)}]


def _model_kinds(mod: Any) -> list[dict[str, Any]]:
    """The other kinds of model of a tracker whose options module lists them (``KINDS``, m2's patch
    model): each one's parameters, its graph and its stages."""
    from pipeline.runtime.graph import load_graph

    out = []
    for kind in getattr(mod, "KINDS", {}).values():
        if kind.params is mod.PARAMS and kind.graph == mod.GRAPH:
            continue  # the tracker's own, described first
        plan = load_graph(kind.graph)
        out.append({"model": kind.label, "graph": kind.graph, "parameters": param_table(kind.params),
                    "parameters_of": f"{kind.params.__module__}.{kind.params.__qualname__}",
                    "set_by": [] if plan.tracker is not None else _takers(plan, kind.params),
                    "stages": _stages(plan, {i.name for i in describe(kind.params)})})
    return out


def tracker_description(name: str) -> dict[str, Any]:
    """What ``gflow info TRACKER`` prints: the tracker's parameters (from its dataclass, when it has
    one) and, for every stage of its built-in graph, the stage's own parameters with the graph's
    values; for a tracker with several kinds of model (m2), the same of each other kind (``models``)."""
    from pipeline.cli.trackers import TRACKERS, spec_of
    from pipeline.runtime.graph import load_graph

    mod = TRACKERS[name]  # UnknownTracker (a CliError) for a name not registered
    cls = getattr(mod, "PARAMS", None)
    shared = {i.name for i in describe(cls)} if cls is not None else set()
    make_plan = getattr(mod, "make_plan", None)  # a graph made from the spec (or gflow's shards)
    plan = make_plan(mod.GRAPH, {}) if make_plan is not None else load_graph(mod.GRAPH)
    about = re.sub(r"^``--tracker \w+``(?: \(the default\))?:\s*", "", (mod.__doc__ or "").strip().splitlines()[0])
    spec = spec_of(name)
    kinds = getattr(mod, "KINDS", {}).values()
    model = next((k.label for k in kinds if k.params is cls and k.graph == mod.GRAPH), "")  # m2: contour
    return {"tracker": name, "about": about, "graph": mod.GRAPH, "model": model, "registered": spec.origin,
            "parameters": param_table(cls) if cls is not None else [],
            "parameters_of": f"{cls.__module__}.{cls.__qualname__}" if cls is not None else "",
            "stages": _stages(plan, shared), "models": _model_kinds(mod)}


def _print_parameters(rows: list[dict[str, str]], of: str, taken: str, where: str) -> None:
    print(f"parameters ({of}; {taken}; gflow track sets them with the options shown or --set {where}.NAME=VALUE):")
    w = [max(len(r[k]) for r in rows) for k in ("name", "default", "option")]
    for r in rows:
        print(f"  {r['name']:{w[0]}}  {r['default']:{w[1]}}  {r['option']:{w[2]}}  {r['help']}")


def _print_stages(stages: list[dict[str, Any]]) -> None:
    for st in stages:
        print(f"stage {st['stage']} ({st['kind']}):" + ("" if st["params"] else " no parameters of its own"))
        for p in st["params"]:
            graph = "" if p["graph"] == p["default"] else f"  (graph: {p['graph']})"
            print(f"  {p['name']} = {p['default']}{graph}")


def print_tracker(name: str, as_json: bool) -> None:
    """Print :func:`tracker_description`."""
    import json

    from pipeline.cli.trackers import spec_of

    d = tracker_description(name)
    if as_json:
        print(json.dumps(d, indent=1))
        return
    print(f"tracker {name}: {d['about']}")
    kinds = d["models"]
    if spec_of(name).graph is None:
        print(f"graph:   made from its spec (source, {name}.proposal, {name}.filter; gflow track --tracker {name})")
    else:
        first = f"with a {d['model']} model: " if d["model"] else ""
        print(f"graph:   {first}{d['graph']} (gflow run {d['graph']}; gflow track --tracker {name})")
    if not d["registered"].startswith("gflow_core."):
        print(f"from:    {d['registered']}")
    if d["parameters"]:
        _print_parameters(d["parameters"], d["parameters_of"], "named once in the graph's tracker block, every "
                                                                "stage of the tracker takes them", "tracker")
    _print_stages(d["stages"])
    for k in kinds:
        print(f"graph:   with a {k['model']} model: {k['graph']} (gflow run {k['graph']}; gflow track --tracker "
              f"{name} --model MODEL.npz picks it for a {k['model']} model)")
        by = k["set_by"]
        _print_parameters(k["parameters"], k["parameters_of"], f"stage {', '.join(by)} takes them" if by else
                          "named once in the graph's tracker block", by[0] if len(by) == 1 else "tracker")
        _print_stages(k["stages"])
