"""A tracker as one registration: :class:`TrackerSpec` (the registry of them is
:mod:`gflow_core.registry`).

A spec says everything the rest of gflow needs of a tracker: its name, its parameter dataclass,
its :class:`~gflow_core.tracker.TrackingFilter` (made by a factory, so the tracker's modules are
imported only when it runs), how the Python API's keywords become its parameters and resources,
the graph it runs in and, for a tracker whose state is a particle cloud over a box, what the
generic box stages need (:class:`BoxStages`). ``gflow.Tracker``, ``gflow track --tracker``,
``gflow info TRACKER`` and ``gflow benchmark --trackers`` all read the registry
(:func:`gflow_core.registry.trackers`).

The built-in trackers' specs are in :mod:`gflow_core.builtin_trackers`; a tracker of another
package registers its spec under the entry-point group ``gflow.trackers``::

    [project.entry-points."gflow.trackers"]
    ncc = "gflow_ncc:SPEC"

No file is opened here: a tracker whose resources come from files (a learned model) gets them
through the ``load`` callable its :attr:`TrackerSpec.setup` is handed by the caller (the
pipeline's model-file reader).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Callable, Mapping

import numpy as np

from .params import make
from .tracker import TrackingFilter

__all__ = ["TrackerSpec", "BoxStages", "SpecError", "Loader", "ENTRY_POINT_GROUP", "plain_setup"]

#: the entry-point group other packages register their trackers' specs in
ENTRY_POINT_GROUP = "gflow.trackers"

#: ``load(name)`` -> ``(object, meta, ref)``: a model file or a built-in model's name read by the
#: pipeline (``ref``: the built-in name, or the file's absolute path); raises ``ValueError``
Loader = Callable[[str], tuple[Any, Mapping[str, Any], str]]


class SpecError(ValueError):
    """A tracker that is not registered, or whose registration is broken (one line, naming it)."""


def plain_setup(spec: "TrackerSpec", keywords: Mapping[str, Any], load: Loader) -> tuple[Any, dict[str, Any]]:
    """The setup of a tracker without resources: its parameter dataclass from the keywords."""
    return make(spec.params, keywords), {}


@dataclass(frozen=True)
class BoxStages:
    """What the generic box stages (``stages.box_tracker``) need of a tracker whose state holds a
    particle cloud over a box, beyond its :class:`~gflow_core.tracker.TrackingFilter`.

    The filter's ``observe`` must return an object with ``grey``, the frame's (H, W) grey levels;
    its estimates are :func:`gflow_core.tracker.box_estimate`'s (their extras: ``alpha``, ``mean``,
    ``std``, ``ess``, ``log_evidence``, ``score``, ``n``).

    Attributes
    ----------
    walk : (params, alpha (N, 4), size0 (w, h), rng, dt) -> alpha (N, 4)
        The proposal stage's random walk of the posterior's particles, alpha = (x, y, theta, s),
        drawn from ``rng = FrameRng(seed, crc32(stream), t).stream(purpose)``; ``size0`` is the
        initial box's size.
    purpose : int
        The constant of the walk's draws (``FrameRng.stream(purpose)``).
    proposal : (particles (N, D), dt) -> proposal
        The filter's ``update`` argument made of the proposed particles.
    particles : state -> (N, D)
        The posterior particles of a state.
    alpha_of, particles_of : (N, D) -> (N, 4) and back
        The conversions between the tracker's particles and alpha.
    to_arrays : state -> ({name: array}, {name: plain value})
        A state as arrays and msgpack-able values, for the filter's snapshots (None: a tracker
        whose stage module keeps a snapshot codec of its own; required of a spec without a graph).
    from_arrays : (arrays, values, params) -> state
        The state of a snapshot (``ValueError``, ``KeyError``, ``TypeError`` for a bad one).
    snapshot_version : int
        The version of what ``to_arrays`` writes.
    snapshot : str
        The name of the Struct of ``gflow_msgs.snapshots`` its filter's snapshots are when they are
        not the generic ``BoxFilterSnapshot`` (whose fields ``arrays`` and ``values`` hold what
        ``to_arrays`` gives): a Struct whose own fields are those arrays and values, beside
        ``version``, ``initialised``, ``steps`` and ``last`` (the appearance tracker's, whose format is
        older than the generic one). ``from_arrays`` is then handed its array fields and every other
        field, ``last`` among them. Empty: the generic Struct.
    """

    walk: Callable[[Any, np.ndarray, tuple[float, float], np.random.Generator, float], np.ndarray]
    purpose: int
    proposal: Callable[[np.ndarray, float], Any]
    particles: Callable[[Any], np.ndarray]
    alpha_of: Callable[[np.ndarray], np.ndarray]
    particles_of: Callable[[np.ndarray], np.ndarray]
    to_arrays: Callable[[Any], tuple[dict[str, np.ndarray], dict[str, Any]]] | None = None
    from_arrays: Callable[[dict[str, np.ndarray], dict[str, Any], Any], Any] | None = None
    snapshot_version: int = 1
    snapshot: str = ""


@dataclass(frozen=True)
class TrackerSpec:
    """One tracker, registered once.

    Attributes
    ----------
    name : str
        ``gflow track --tracker NAME``, ``gflow.Tracker(NAME)``.
    about : str
        One line: what the tracker is (``gflow info NAME``).
    params : type
        Its frozen parameter dataclass (:mod:`gflow_core.params`); a field declared with an
        ``option`` becomes an option of ``gflow track``.
    tracker : () -> TrackingFilter
        Its protocol object (called when the tracker is used).
    setup : (spec, keywords, load) -> (params, resources)
        The Python API's keywords as the tracker's parameters and the resources its ``init`` takes
        (``{"model": ...}``); ``load`` reads a model file (module docstring). Default: the
        parameters alone (:func:`plain_setup`).
    graph : str or None
        The built-in graph it runs in (``pipeline/graphs/GRAPH.yaml``); None: a graph made from
        the spec (source -> ``NAME.proposal`` -> ``NAME.filter``, the generic box stages).
    proposal_kind, filter_kind : str
        The stage kinds of its proposal and filter (default ``NAME.proposal``, ``NAME.filter``).
    box : BoxStages or None
        What the generic box stages need; required when ``graph`` is None.
    cli : str
        The module of its ``gflow track`` options (``NAME``, ``add_args``, ``overrides``, optionally
        ``make_plan``), for a tracker whose options are its own; empty: the options of its
        parameter dataclass, and its stages get the initial box, the seed and those values.
    model_option : str
        The ``gflow track`` option that names the tracker's model (a file or a built-in model's
        name, read through ``load``), e.g. ``"--model"``; empty: it takes none. ``gflow benchmark``
        and ``gflow export vot`` give it as ``--NAME-model``.
    model_required : bool
        It cannot run without a model: ``gflow benchmark`` skips it, and ``gflow export vot`` leaves
        it out, unless ``--NAME-model`` is given.
    preprocess : {param: value}
        What its ``preprocess`` stage reads of a frame, when the graph does not say (e.g. m2: the
        edge settings its models are learned with by default, :mod:`gflow_core.m2.edge_settings`):
        the graph loader fills the preprocess stage of a graph whose tracker block names the tracker
        with these values, under the graph's own and the command line's. Empty: the stage's defaults.
    stages : {kind: module}
        Its stage classes that are modules of their own, by kind: the dotted module that defines the
        class of each (``{"gflow.filter": "stages.gflow_filter"}``; a tracker of another package may
        name its own). The stage registry (``stages.registry``) imports a module when its kind is
        first run; a kind of ``proposal_kind`` / ``filter_kind`` not named here is the generic box
        stages' (``box``). A variant's stage (m2's ``patch.filter``) is named here too.
    variants : tuple of type
        Its other parameter dataclasses, each its setup may make instead of ``params`` (m2 with a
        patch model: :class:`~gflow_core.m2.patch_params.PatchParams`). A graph's tracker block takes
        the one its stages are made of (:mod:`pipeline.runtime.tracker_block`); ``preprocess``
        is that of ``params``.

    Options are shared by name: a tracker reads another tracker's ``gflow track`` option when its
    parameter dataclass has a field of the option's name (``--particles`` of appearance is read by
    every tracker with a parameter ``particles``, declared with that option or none), and
    ``--model`` by every tracker whose ``model_option`` it is. Any other option a tracker declares
    that another tracker (or ``gflow track``) has already is an error naming both (``gflow track
    --tracker NAME`` says it).
    """

    name: str
    params: type
    tracker: Callable[[], TrackingFilter[Any, Any, Any, Any]]
    about: str = ""
    setup: Callable[["TrackerSpec", Mapping[str, Any], Loader], tuple[Any, dict[str, Any]]] = plain_setup
    graph: str | None = None
    proposal_kind: str = ""
    filter_kind: str = ""
    box: BoxStages | None = None
    cli: str = ""
    model_option: str = ""
    model_required: bool = False
    preprocess: Mapping[str, Any] = field(default_factory=dict, hash=False)
    variants: tuple[type, ...] = ()
    stages: Mapping[str, str] = field(default_factory=dict, hash=False)
    #: where it was registered (``gflow_core.builtin_trackers`` or the entry point), for messages
    origin: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not self.name.isidentifier() or self.name != self.name.lower():
            raise SpecError(f"tracker name {self.name!r} must be a lower-case Python identifier")
        if not dataclasses.is_dataclass(self.params):
            raise SpecError(f"tracker {self.name}: params must be a dataclass, got {self.params!r}")
        if self.graph is None and self.box is None:
            raise SpecError(f"tracker {self.name}: give either the graph it runs in or its box stages (BoxStages)")
        if self.graph is None and self.box is not None and (self.box.to_arrays is None or self.box.from_arrays is None):
            raise SpecError(f"tracker {self.name}: its box stages need to_arrays and from_arrays (the filter's "
                            f"snapshots)")
        if self.box is not None and "particles" not in {f.name for f in dataclasses.fields(self.params)}:
            raise SpecError(f"tracker {self.name}: the box stages need a parameter 'particles' in "
                            f"{self.params.__name__}")
        if self.model_required and not self.model_option:
            raise SpecError(f"tracker {self.name}: model_required needs the model_option that names its model")
        if self.model_option and not self.model_option.startswith("--"):
            raise SpecError(f"tracker {self.name}: model_option must be an option such as '--model', got "
                            f"{self.model_option!r}")
        if not all(dataclasses.is_dataclass(v) and isinstance(v, type) for v in self.variants):
            raise SpecError(f"tracker {self.name}: variants must be parameter dataclasses, got {self.variants!r}")
        if not isinstance(self.preprocess, Mapping) or not all(isinstance(k, str) for k in self.preprocess):
            raise SpecError(f"tracker {self.name}: preprocess must map the preprocess stage's parameter names to "
                            f"values, got {self.preprocess!r}")
        object.__setattr__(self, "preprocess", MappingProxyType(dict(self.preprocess)))  # read-only, as the spec
        if not isinstance(self.stages, Mapping) or not all(
                isinstance(k, str) and isinstance(m, str) and all(p.isidentifier() for p in m.split("."))
                for k, m in self.stages.items()):
            raise SpecError(f"tracker {self.name}: stages must map stage kinds to dotted module names, got "
                            f"{self.stages!r}")
        object.__setattr__(self, "stages", MappingProxyType(dict(self.stages)))
        if not self.proposal_kind:
            object.__setattr__(self, "proposal_kind", f"{self.name}.proposal")
        if not self.filter_kind:
            object.__setattr__(self, "filter_kind", f"{self.name}.filter")

    @property
    def model_dest(self) -> str:
        """The name :attr:`model_option`'s value goes by among the options (``--model`` -> ``model``)."""
        return self.model_option.lstrip("-").replace("-", "_")

    def make(self, keywords: Mapping[str, Any], load: Loader) -> tuple[Any, dict[str, Any]]:
        """(params, resources) of the API's keywords (:attr:`setup`)."""
        return self.setup(self, keywords, load)
