"""Trackers that ``gflow track --tracker NAME`` can run: one per registered spec
(:func:`gflow_core.registry.trackers`, the built-in ones and those of the entry-point group
``gflow.trackers``).

Each entry has ``NAME``, ``GRAPH``, ``PARAMS``, ``add_args(group)``, ``overrides(args) -> (graph,
{stage: {param: value}})`` and ``make_plan(graph, overrides) -> Plan``, and may have ``MODEL_NAMES``: the
models its ``--model`` names by a word (:func:`check_model`). A spec that names its
options module (``TrackerSpec.cli``, one module of this package per built-in tracker) gets that
module; any other gets :class:`SpecOptions`: the options of its parameter dataclass, its stages
given the initial box, the seed and those values, its graph the one made from the spec
(:func:`pipeline.runtime.spec_graph.spec_plan`) when it has no graph file.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from typing import Any

from gflow_core.registry import broken, get, trackers
from gflow_core.spec import SpecError, TrackerSpec

from pipeline.cli.commands.common import CliError

__all__ = ["TRACKERS", "SpecOptions", "UnknownTracker", "OptionClash", "spec_of", "check_model"]


class UnknownTracker(CliError, KeyError):
    """A tracker name that is not registered, or whose registration is broken (one line)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class OptionClash(Exception):
    """A tracker's option that ``gflow track`` has already (``option``; ``where``: the parameter that
    declares it); ``gflow track --tracker NAME`` says so in one line (:mod:`pipeline.cli.commands.track`)."""

    def __init__(self, option: str, where: str) -> None:
        super().__init__(f"{option} ({where})")
        self.option, self.where = option, where


class SpecOptions:
    """The ``gflow track`` options of a tracker from its spec alone (module docstring)."""

    def __init__(self, spec: TrackerSpec) -> None:
        self.spec = spec
        self.NAME = spec.name
        self.GRAPH = spec.graph or spec.name
        self.PARAMS = spec.params
        self.__doc__ = f"``--tracker {spec.name}``: {spec.about or spec.params.__doc__ or spec.name}"

    def add_args(self, g: Any) -> None:
        """An option for every parameter of the dataclass that declares one. An option ``gflow
        track`` has already is shared when it goes by the parameter's name (``particles`` declaring
        ``--particles``: read as a parameter of that name reads it); any other is
        :class:`OptionClash`, with nothing added."""
        from gflow_core.params import describe

        from pipeline.cli.tracker_options import add_param_options

        taken = dict(getattr(g, "_option_string_actions", {}))
        shared: set[str] = set()
        for i in describe(self.PARAMS):
            if i.option is None or i.option not in taken:
                continue
            if taken[i.option].dest == i.name:
                shared.add(i.option)
            else:
                raise OptionClash(i.option, f"{self.PARAMS.__name__}.{i.name}")
        add_param_options(g, self.PARAMS, self.NAME, skip=frozenset(shared))
        model = self.spec.model_option
        if model and model not in getattr(g, "_option_string_actions", {}):  # else shared: m2's --model
            g.add_argument(model, metavar="MODEL", help=f"{self.NAME}: its model (a file, or a model's name)")

    def overrides(self, args: Any) -> tuple[str, dict[str, dict]]:
        """Both stages get the initial box and the seed; the options given set the graph's tracker
        block: its own, and those of other trackers it reads (a parameter of the option's name, as
        ``--particles``)."""
        from gflow_core.params import describe

        from pipeline.cli.tracker_options import param_values

        shared: dict = {"init": list(args.init), "seed": args.seed}
        block: dict = {}
        for i in describe(self.PARAMS):  # another tracker's option read by name
            if i.option is None and i.name not in _NOT_SHARED and getattr(args, i.name, None) is not None:
                block[i.name] = getattr(args, i.name)
        block.update(param_values(args, self.PARAMS))
        model = getattr(args, self.spec.model_dest, None) if self.spec.model_option else None
        if model is not None:  # its parameter ``model``
            block["model"] = model
        elif self.spec.model_required:
            raise CliError(f"--tracker {self.NAME} needs {self.spec.model_option} MODEL")
        return self.GRAPH, {"tracker": block, "proposal": dict(shared), "filter": dict(shared)}

    def make_plan(self, graph: str, over: dict[str, dict]) -> Any:
        """The plan of ``graph``: the spec's own when it is the tracker's (and no file of that name)."""
        from pipeline.runtime.graph import load_graph
        from pipeline.runtime.spec_graph import spec_plan

        if self.spec.graph is None and graph == self.GRAPH:
            return spec_plan(self.spec, over)
        return load_graph(graph, overrides=over)


#: what a request's options hold besides the trackers' options (never a shared option)
_NOT_SHARED = frozenset({"tracker", "init", "seed", "source"})


class _Broken:
    """A registration that cannot be used: it adds no option, and running it is its one-line error."""

    def __init__(self, name: str, why: str) -> None:
        self.NAME, self.GRAPH, self.PARAMS, self.why = name, name, None, why

    def add_args(self, g: Any) -> None:
        pass

    def overrides(self, args: Any) -> tuple[str, dict[str, dict]]:
        raise UnknownTracker(self.why)


_modules: dict[str, Any] = {}


def _entry(spec: TrackerSpec) -> Any:
    key = f"{spec.name}:{spec.cli}:{spec.origin}"
    if key not in _modules:
        _modules[key] = importlib.import_module(spec.cli) if spec.cli else SpecOptions(spec)
    return _modules[key]


class _Trackers(Mapping):
    """{name: options of that tracker}, read from the registry each time (a package installed or put
    on ``sys.path`` meanwhile is seen); a broken registration is listed and fails when run."""

    def _all(self) -> dict[str, Any]:
        out = {n: _entry(s) for n, s in trackers().items()}
        out.update({n: _Broken(n, why) for n, why in broken().items() if n not in out})
        return {n: out[n] for n in sorted(out)}

    def __getitem__(self, name: str) -> Any:
        try:
            return _entry(get(name))
        except SpecError as e:
            raise UnknownTracker(str(e)) from None

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._all()

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())

    def values(self) -> Any:
        """Every entry, a broken registration's too (it adds no option; running it says why)."""
        return self._all().values()

    def items(self) -> Any:
        return self._all().items()


TRACKERS: Mapping[str, Any] = _Trackers()


def spec_of(name: str) -> TrackerSpec:
    """The spec of tracker ``name`` (:class:`UnknownTracker` for a name not registered)."""
    try:
        return get(name)
    except SpecError as e:
        raise UnknownTracker(str(e)) from None


def check_model(name: str, model: str, option: str) -> None:
    """Refuse a model that ``option`` gives tracker ``name`` and that names nothing: no file there, and none of the
    tracker's built-in models (its options module's ``MODEL_NAMES``: G-flow's face and ellipsoid). It was said
    "model file not found: nosuch", naming neither the option nor the names there are. A tracker that does not
    list its built-in models judges a bare word itself; a path that is there (a folder, a file that is no model)
    is judged by the reader, which names it."""
    import os

    if os.path.lexists(model):
        return
    names = getattr(TRACKERS[name], "MODEL_NAMES", None)
    if model in (names or ()) or (names is None and model.isidentifier()):
        return
    built = f", and not a built-in model of --tracker {name} ({', '.join(names)})" if names else ""
    raise CliError(f"{option} {model}: model file not found{built}")
