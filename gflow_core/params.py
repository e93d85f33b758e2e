"""Tracker parameters: one frozen dataclass per tracker, the only place a default lives.

Each field of a tracker's parameter dataclass is declared with :func:`param`, which keeps its
help text beside its default (and, for the few parameters worth a command-line option of their
own, the option's name). Everything else is derived from the dataclass, never copied: the
stages' parameter structs (``gflow_msgs/params.py``), through them the validation of graph
files, the options of ``gflow track`` with their help, ``gflow info TRACKER`` and the keyword
arguments of the Python API.

A dataclass validates itself in ``__post_init__`` and raises :class:`ValueError` with a one-line
message naming the parameter; :func:`make` also refuses unknown names, in one line listing the
known ones. A parameter whose value sets the size of the run's arrays (the particles, dcf's
template) declares the memory it costs (:class:`Memory`), and :func:`check_memory`, called from
``__post_init__``, refuses a value that needs more than the machine has: such a run would spend its
time growing arrays until a stage died, never tracking a frame.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import typing
from dataclasses import dataclass
from typing import Any, Mapping, TypeVar, cast

__all__ = ["param", "ParamInfo", "describe", "defaults", "make", "UnknownParameter", "format_value", "added_later",
           "as_recorded", "Memory", "machine_memory", "check_memory"]

T = TypeVar("T")


class UnknownParameter(TypeError):
    """A parameter name the tracker does not have (the message lists the ones it has)."""


_NOT_LATER = object()


@dataclass(frozen=True)
class Memory:
    """The memory a parameter's value costs a run: ``per`` bytes for each of ``value ** power`` ``unit``,
    times the values of the parameters named in ``times`` (G-flow's pose samples: ``n_samples`` of each of
    ``n_experts``; both declare it, and a value too large is said of the one furthest above its default).

    ``per`` is measured, not derived: the slope of the peak resident memory of ``gflow track --inline``
    (every stage, and the messages between them, in one process) between two large values, so it
    counts what the whole pipeline holds, and is a floor of what a run needs with every other
    setting at its default.
    """

    per: float
    unit: str
    power: int = 1
    times: tuple[str, ...] = ()

    def need(self, value: float, times: float = 1.0) -> float:
        """Bytes a run needs for ``value``, ``times`` the product of the ``times`` parameters' values (inf past a
        float's range)."""
        try:
            return self.per * times * _float(value) ** self.power
        except OverflowError:
            return math.inf

    def most(self, have: float, times: float = 1.0) -> int:
        """The largest value whose need is within ``have`` bytes, to two significant figures (rounded down)."""
        v = int((have / (self.per * times)) ** (1.0 / self.power))
        digits = max(len(str(v)) - 2, 0)
        return v // 10 ** digits * 10 ** digits


def param(default: Any, help: str, *, option: str | None = None, before: Any = _NOT_LATER,
          memory: Memory | None = None, inf: str = "") -> Any:
    """A dataclass field with its default, its help text and, optionally, its command-line option.

    Parameters
    ----------
    default : the default value (immutable: a number, a string, a tuple, None).
    help : what the parameter does, in one sentence (shown by ``--help`` and ``gflow info``).
    option : the option of ``gflow track`` that sets it (``--experts``), if it has one of its own.
    before : for a parameter added after recordings were made, and on by default, the value that
        is what the code did before it existed: a recorded plan without the parameter is read
        with it (:func:`as_recorded`), so the recording re-runs bit for bit.
    memory : what the value costs in memory, for a parameter that sizes the run's arrays: a value
        needing more than the machine has is refused (:func:`check_memory`).
    inf : what an infinite value means (``"none"``: no wall), for a parameter that takes one; a stage
        refuses inf for every other parameter (:func:`gflow_msgs.params.refuse_nonfinite`).
    """
    meta: dict[str, Any] = {"help": help, "option": option}
    if inf:
        meta["inf"] = inf
    if before is not _NOT_LATER:
        meta["before"] = before
    if memory is not None:
        meta["memory"] = memory
    return dataclasses.field(default=default, metadata=meta)


@functools.cache
def machine_memory() -> float:
    """Bytes of physical memory of this machine (inf where the system does not say: no bound)."""
    try:
        return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return math.inf


def _bytes(n: float) -> str:
    """``25.3 GB``, ``8.1 MB``."""
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.1f} MB"


def _float(v: float) -> float:
    """``float(v)``, inf for an integer past a float's range."""
    try:
        return float(v)
    except OverflowError:
        return math.inf


def check_memory(obj: Any, have: float | None = None) -> None:
    """Refuse a parameter of the dataclass ``obj`` declared with a :class:`Memory` whose value needs
    more than ``have`` bytes (default: the machine's physical memory, :func:`machine_memory`), as a
    ``ValueError`` naming the parameter, its value and the largest value that fits (of those refused,
    the one furthest above its default: the one the user made large)."""
    have = machine_memory() if have is None else have
    refused = []
    for f in dataclasses.fields(obj):
        m, v = f.metadata.get("memory"), getattr(obj, f.name)
        if m is None or isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        times = math.prod(_float(getattr(obj, n)) for n in m.times)
        if m.need(v, times) > have:
            default = f.default if isinstance(f.default, (int, float)) else 1.0  # (a declared field has one)
            refused.append((_float(v) / max(_float(default), 1.0), f.name, m, v, times))
    if refused:
        _, name, m, v, times = max(refused, key=lambda r: r[0])
        count = " x ".join((name if m.power == 1 else f"{name}^{m.power}", *m.times))
        each = f"{m.per:g} bytes a {m.unit}" + (f", {count} of them" if count != name else "")
        raise ValueError(f"{name} must be at most {m.most(have, times)} on this machine (about {each}; it has "
                         f"{_bytes(have)} of memory), got {format_value(v)}")


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
