"""Command-line options derived from a tracker's parameter dataclass (``gflow info TRACKER`` is in
:mod:`pipeline.cli.tracker_info`).

A parameter declared with an ``option`` in its tracker's dataclass (``gflow_core.params.param``)
becomes an option of ``gflow track`` with the dataclass's help and default; nothing here repeats a
default or a help text.
"""

from __future__ import annotations

import argparse
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


def add_param_options(group: Any, cls: type, tracker: str, notes: dict[str, str] | None = None,
                      skip: frozenset[str] = frozenset()) -> None:
    """Add an option for every parameter of ``cls`` that names one (but those in ``skip``); its
    default is None (not given), its help the dataclass's with the default appended (and
    ``notes[name]``, for an option other trackers read too). A number's option reads it as every
    command does ("expected a whole number"); its range is the dataclass's (:func:`check_param_values`)."""
    from pipeline.cli.commands.common import number, whole_number

    read = {int: whole_number, float: number}
    for info in describe(cls):
        if info.option is None or info.option in skip:
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
            group.add_argument(info.option, dest=option_dest(info), type=read.get(kind, kind), default=None,
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
    of each value alone, then of all of them together (``--experts 10000 --samples 1000``), before a
    graph is built from it (an option declared on one tracker's parameters and read by
    another, as ``--particles``, is checked against the one that runs)."""
    from gflow_core.params import make

    fields = {i.name for i in describe(cls)}
    given: dict[str, tuple[str, Any]] = {}
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
            given[info.name] = (f"{info.option} {format_value(value)}", value)
    try:  # each fits alone, not together (--experts and --samples: the memory of their product)
        make(cls, {name: value for name, (_, value) in given.items()})
    except ValueError as e:
        raise ValueError(f"{' '.join(how for how, _ in given.values())}: {e}") from None


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
