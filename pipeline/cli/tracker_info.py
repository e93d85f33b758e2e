"""``gflow info TRACKER``: a registered tracker's parameters with their defaults and help, and each
stage's own parameters with its graph's values."""

from __future__ import annotations

import re
from typing import Any

from gflow_core.params import describe, format_value

from pipeline.cli.tracker_options import param_table

__all__ = ["tracker_description", "print_tracker"]


def tracker_description(name: str) -> dict[str, Any]:
    """What ``gflow info TRACKER`` prints: the tracker's parameters (from its dataclass, when it has
    one) and, for every stage of its built-in graph, the stage's own parameters with the graph's
    values."""
    import msgspec

    from stages.registry import get_stage_class

    from pipeline.cli.trackers import TRACKERS, spec_of
    from pipeline.runtime.graph import RECORDER_KIND, load_graph

    mod = TRACKERS[name]  # UnknownTracker (a CliError) for a name not registered
    cls = getattr(mod, "PARAMS", None)
    shared = {i.name for i in describe(cls)} if cls is not None else set()
    make_plan = getattr(mod, "make_plan", None)  # a graph made from the spec (or gflow's shards)
    plan = make_plan(mod.GRAPH, {}) if make_plan is not None else load_graph(mod.GRAPH)
    stages = []
    for sname, sp in plan.stages.items():
        if sp.kind in (RECORDER_KIND, "source"):
            continue
        fields = msgspec.structs.fields(get_stage_class(sp.kind).Params)
        own = [{"name": f.name, "default": format_value(None if f.default is msgspec.NODEFAULT else f.default),
                "graph": format_value(sp.params.get(f.name))} for f in fields if f.name not in shared]
        stages.append({"stage": sname, "kind": sp.kind, "params": own})
    about = re.sub(r"^``--tracker \w+``(?: \(the default\))?:\s*", "", (mod.__doc__ or "").strip().splitlines()[0])
    spec = spec_of(name)
    return {"tracker": name, "about": about, "graph": mod.GRAPH, "registered": spec.origin,
            "parameters": param_table(cls) if cls is not None else [],
            "parameters_of": f"{cls.__module__}.{cls.__qualname__}" if cls is not None else "", "stages": stages}


def print_tracker(name: str, as_json: bool) -> None:
    """Print :func:`tracker_description`."""
    import json

    from pipeline.cli.trackers import spec_of

    d = tracker_description(name)
    if as_json:
        print(json.dumps(d, indent=1))
        return
    print(f"tracker {name}: {d['about']}")
    if spec_of(name).graph is None:
        print(f"graph:   made from its spec (source, {name}.proposal, {name}.filter; gflow track --tracker {name})")
    else:
        print(f"graph:   {d['graph']} (gflow run {d['graph']}; gflow track --tracker {name})")
    if not d["registered"].startswith("gflow_core."):
        print(f"from:    {d['registered']}")
    if d["parameters"]:
        rows = d["parameters"]
        print(f"parameters ({d['parameters_of']}; named once in the graph's tracker block, every stage of the "
              f"tracker takes them; gflow track sets them with the options shown or --set tracker.NAME=VALUE):")
        w = [max(len(r[k]) for r in rows) for k in ("name", "default", "option")]
        for r in rows:
            print(f"  {r['name']:{w[0]}}  {r['default']:{w[1]}}  {r['option']:{w[2]}}  {r['help']}")
    for st in d["stages"]:
        print(f"stage {st['stage']} ({st['kind']}):" + ("" if st["params"] else " no parameters of its own"))
        for p in st["params"]:
            graph = "" if p["graph"] == p["default"] else f"  (graph: {p['graph']})"
            print(f"  {p['name']} = {p['default']}{graph}")
