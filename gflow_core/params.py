"""Tracker parameters: one frozen dataclass per tracker, the only place a default lives.

Each field of a tracker's parameter dataclass is declared with :func:`param`, which keeps its
help text beside its default (and, for the few parameters worth a command-line option of their
own, the option's name). Everything else is derived from the dataclass, never copied: the
stages' parameter structs (``gflow_msgs/params.py``), through them the validation of graph
files, the options of ``gflow track`` with their help, ``gflow info TRACKER`` and the keyword
arguments of the Python API.

A dataclass validates itself in ``__post_init__`` and raises :class:`ValueError` with a one-line
message naming the parameter; :func:`make` also refuses unknown names, in one line listing the
known ones.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass
from typing import Any, Mapping, TypeVar, cast

__all__ = ["param", "ParamInfo", "describe", "defaults", "make", "UnknownParameter", "format_value", "added_later",
           "as_recorded"]

T = TypeVar("T")


class UnknownParameter(TypeError):
    """A parameter name the tracker does not have (the message lists the ones it has)."""


_NOT_LATER = object()


def param(default: Any, help: str, *, option: str | None = None, before: Any = _NOT_LATER) -> Any:
    """A dataclass field with its default, its help text and, optionally, its command-line option.

    Parameters
    ----------
    default : the default value (immutable: a number, a string, a tuple, None).
    help : what the parameter does, in one sentence (shown by ``--help`` and ``gflow info``).
    option : the option of ``gflow track`` that sets it (``--experts``), if it has one of its own.
    before : for a parameter added after recordings were made, and on by default, the value that
        is what the code did before it existed: a recorded plan without the parameter is read
        with it (:func:`as_recorded`), so the recording re-runs bit for bit.
    """
    meta = {"help": help, "option": option}
    if before is not _NOT_LATER:
        meta["before"] = before
    return dataclasses.field(default=default, metadata=meta)


def added_later(cls: type) -> dict[str, Any]:
    """``{name: value before it existed}`` of the parameters of ``cls`` declared with ``before``."""
    return {f.name: f.metadata["before"] for f in dataclasses.fields(cls) if "before" in f.metadata}


def as_recorded(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    """A recorded plan's ``values`` for ``cls``, with each parameter added later that they lack
    at the value it had before it existed (not today's default)."""
    return {**{k: v for k, v in added_later(cls).items() if k not in values}, **values}


@dataclass(frozen=True)
class ParamInfo:
    """One parameter of a tracker, as :func:`describe` reads it off the dataclass.

    Attributes
    ----------
    name : str
    type : the resolved annotation (``int``, ``float | tuple[float, ...]``, a ``Literal``...).
    default : Any
    help : str
    option : str or None, the command-line option of its own.
    """

    name: str
    type: Any
    default: Any
    help: str
    option: str | None


def describe(cls: type) -> tuple[ParamInfo, ...]:
    """Every parameter of a tracker's parameter dataclass, in declaration order."""
    hints = typing.get_type_hints(cls)
    return tuple(ParamInfo(f.name, hints[f.name], f.default, str(f.metadata.get("help", "")), f.metadata.get("option"))
                 for f in dataclasses.fields(cls))


def defaults(cls: type) -> dict[str, Any]:
    """``{name: default}`` of a parameter dataclass."""
    return {f.name: f.default for f in dataclasses.fields(cls)}


def make(cls: type[T], values: Mapping[str, Any] | None = None, **more: Any) -> T:
    """``cls(**values, **more)``, refusing unknown names in one line that lists the known ones.

    Raises
    ------
    UnknownParameter
        A name ``cls`` does not have.
    ValueError
        A value ``cls`` refuses (its ``__post_init__``).
    """
    kw = dict(values or {}, **more)
    known = [f.name for f in dataclasses.fields(cast(Any, cls))]
    unknown = sorted(set(kw) - set(known))
    if unknown:
        raise UnknownParameter(f"unknown parameter{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} of "
                               f"{cls.__name__} (known: {', '.join(known)})")
    return cls(**kw)


def format_value(v: Any) -> str:
    """A default as a user would type it (``inf``, ``1e-3``, ``[15, 15]``, ``true``)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "inf" if math.isinf(v) and v > 0 else repr(v)
    if isinstance(v, tuple):
        return "[" + ", ".join(format_value(x) for x in v) + "]"
    if v is None:
        return "none"
    if isinstance(v, str):
        return v if v else '""'
    return str(v)
