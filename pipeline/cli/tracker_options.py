"""Command-line options and ``gflow info TRACKER`` derived from a tracker's parameter dataclass.

A parameter declared with an ``option`` in its tracker's dataclass (``gflow_core.params.param``)
becomes an option of ``gflow track`` with the dataclass's help and default; nothing here repeats a
default or a help text.
"""

from __future__ import annotations

import argparse
import re
import types
import typing
from typing import Any

from gflow_core.params import ParamInfo, describe, format_value

__all__ = ["add_param_options", "param_values", "option_dest", "param_table", "check_param_values"]


def option_dest(info: ParamInfo) -> str:
    """The ``argparse`` destination of a parameter's option (``--experts`` -> ``experts``)."""
    assert info.option is not None
    return info.option.lstrip("-").replace("-", "_")


def _scalar(tp: Any) -> Any:
    """``int``, ``float``, ``bool`` or ``str`` of an annotation (None for tuples and unions of them)."""
    if tp in (int, float, bool, str):
        return tp
    if typing.get_origin(tp) is typing.Literal:
        return str
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _scalar(args[0]) if len(args) == 1 else None
    return None


def add_param_options(group: Any, cls: type, tracker: str, notes: dict[str, str] | None = None) -> None:
    """Add an option for every parameter of ``cls`` that names one; its default is None (not given),
    its help the dataclass's with the default appended (and ``notes[name]``, for an option other
    trackers read too)."""
    for info in describe(cls):
        if info.option is None:
            continue
        kind = _scalar(info.type)
        if kind is None:
            raise TypeError(f"{cls.__name__}.{info.name}: an option needs a number, a string or a switch")
        note = f"; {notes[info.name]}" if notes and info.name in notes else ""
        help_ = f"{tracker}: {info.help} (default {format_value(info.default)}{note})"
        if kind is bool:
            group.add_argument(info.option, dest=option_dest(info), action=argparse.BooleanOptionalAction,
                               default=None, help=help_)
        else:
            group.add_argument(info.option, dest=option_dest(info), type=kind, default=None,
                               metavar=info.name.upper(), help=help_)


def param_values(args: argparse.Namespace, cls: type) -> dict[str, Any]:
    """``{parameter: value}`` of the options of ``cls`` the user gave."""
    out = {}
    for info in describe(cls):
        if info.option is not None and getattr(args, option_dest(info), None) is not None:
            out[info.name] = getattr(args, option_dest(info))
    return out


def check_param_values(args: argparse.Namespace, classes: list[type], cls: type) -> None:
    """Refuse a value the options of ``classes`` were given that ``cls`` (the tracker that runs)
    would refuse, as ``ValueError("--OPTION VALUE: why")``: the dataclass's own check, in one line,
    before a graph is built from it (an option declared on one tracker's parameters and read by
    another, as ``--particles``, is checked against the one that runs)."""
    from gflow_core.params import make

    fields = {i.name for i in describe(cls)}
    for other in classes:
        for info in describe(other):
            if info.option is None or info.name not in fields:
                continue
            value = getattr(args, option_dest(info), None)
            if value is None:
                continue
            try:
                make(cls, {info.name: value})
            except ValueError as e:
                raise ValueError(f"{info.option} {format_value(value)}: {e}") from None


def _type_name(tp: Any) -> str:
    if isinstance(tp, type):
        return tp.__name__
    if typing.get_origin(tp) is typing.Literal:
        return " | ".join(str(a) for a in typing.get_args(tp))
    return str(tp).replace("typing.", "")


def param_table(cls: type) -> list[dict[str, str]]:
    """Every parameter of ``cls`` as ``{name, type, default, option, help}`` strings."""
    return [{"name": i.name, "type": _type_name(i.type), "default": format_value(i.default), "option": i.option or "",
             "help": i.help} for i in describe(cls)]


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
        print(f"parameters ({d['parameters_of']}; every stage of the tracker takes them, gflow track sets them with "
              f"the options shown or --set STAGE.NAME=VALUE):")
        w = [max(len(r[k]) for r in rows) for k in ("name", "default", "option")]
        for r in rows:
            print(f"  {r['name']:{w[0]}}  {r['default']:{w[1]}}  {r['option']:{w[2]}}  {r['help']}")
    for st in d["stages"]:
        print(f"stage {st['stage']} ({st['kind']}):" + ("" if st["params"] else " no parameters of its own"))
        for p in st["params"]:
            graph = "" if p["graph"] == p["default"] else f"  (graph: {p['graph']})"
            print(f"  {p['name']} = {p['default']}{graph}")
