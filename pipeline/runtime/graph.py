"""Graph files: which stages run, with which parameters, and which topics feed which inputs.

A graph is YAML::

    name: chamfer-tracker
    stream: cam0                      # topics become gflow/<stream>/<topic>
    stages:
      source:
        kind: source
        params: {kind: folder, path: frames/, fps: 25}
      preprocess:
        kind: preprocess
        inputs: {frames: frames}      # port: topic
      filter:
        kind: particle.filter
        params: {init: [10, 20, 30, 40], seed: 0}
        inputs: {features: features, proposals: proposals}
        restart: on-failure           # or never (default); max_restarts: 3
        snapshot_every: 25            # publish the stage's state every 25 frames (for seeking)
        host: edge                    # placement: `gflow run GRAPH --host edge` starts it (optional;
                                      # all stages or none have one; see docs/deployment.md)
      recorder:
        kind: recorder
        params: {path: recordings/run-{time}.mcap}

A ``tracker:`` block names the tracker and its parameters once for every stage of it
(:mod:`pipeline.runtime.tracker_block`)::

    tracker: {name: dcf, params: {particles: 300}}

The block's tracker may also name what its ``preprocess`` stage reads of a frame
(:attr:`gflow_core.spec.TrackerSpec.preprocess`: m2's edge settings): a preprocess stage takes
those values unless the graph or an override names its own.

Outputs default to topics named after their ports; ``outputs: {port: topic}`` renames
them. ``external: {frames: Frame}`` declares topics fed from outside the graph (by
``gflow replay``, say), so a graph of live stages can run without a source.
``on_host_lost: stop`` (default) or ``wait``: what a run placed on several hosts does when one
of them disappears. The graph is validated before anything starts: an unknown stage kind, an unknown
parameter, an unconnected input and a type mismatch between producer and consumer each
raise :class:`GraphError` naming the file and line.
"""

from __future__ import annotations

import dataclasses
import json
import re
import secrets
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import msgspec

from stages.base import Params
from stages.registry import STAGES

from pipeline.io.recording_files import unique_path
from gflow_core.params import as_recorded
from pipeline.runtime.tracker_block import (TRACKER_KEY, TrackerBlock, block_class, is_main_class, own_fields,
                                            parse_block, plain_type_error, stage_tracker, tracker_fields)
from pipeline.runtime.transport import topic_key

__all__ = ["GraphError", "StagePlan", "Plan", "load_graph", "parse_graph", "RecorderParams", "RECORDER_KIND"]

RECORDER_KIND = "recorder"
#: the stage kind whose defaults a graph's tracker may name (:func:`_tracker_preprocess`)
PREPROCESS_KIND = "preprocess"
_HOST_LABEL = re.compile(r"^[A-Za-z0-9_-]+$")
_STAGE_KEYS = {"kind", "params", "inputs", "outputs", "restart", "max_restarts", "qos", "snapshot_every", "host"}
#: what a run does when a host of the graph disappears (``on_host_lost:`` in the graph)
ON_HOST_LOST = ("stop", "wait")


class RecorderParams(Params, frozen=True):  # frozen as its base (msgspec inherits it; said for mypy)
    """The recorder: every message on ``gflow/<stream>/**`` to one MCAP file.

    path may contain ``{time}`` (YYYYmmdd-HHMMSS), ``{name}`` (the graph name) and ``{run}`` (the run
    id; a path with ``{time}`` and without ``{run}`` gets ``-RUNID`` before its suffix). A name that
    is taken gets ``-2``, ``-3``...: a recording never overwrites a file.
    topics: which topics to keep, as shell patterns on the name after ``gflow/<stream>/``
    (``estimate``, ``_snapshot/*``, ``*``); errors, heartbeats and control are always kept, so
    a recording always says what went wrong.
    """

    path: str = "recordings/{name}-{time}.mcap"
    topics: tuple[str, ...] = ("*",)
    flush_interval: float = 0.5
    compression: str = "lz4"
    chunk_size: int = 4 * 1024 * 1024


class GraphError(ValueError):
    """A graph file that cannot run. The message names the file and line."""


def _line_loader():
    """A yaml SafeLoader whose mappings remember their lines. Made on first use: a stage
    process reads its plan from JSON and never pays for importing yaml."""
    global _LINE_LOADER
    if _LINE_LOADER is None:
        import yaml

        class _LineLoader(yaml.SafeLoader):
            pass

        _LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
        _LINE_LOADER = _LineLoader
    return _LINE_LOADER


_LINE_LOADER = None


def _construct_mapping(loader, node) -> dict:
    mapping = _LineDict()
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if isinstance(key, (list, dict)):  # YAML allows one ("[a]: b", "? [a]"); a dict cannot hold it
            raise GraphError(f"line {key_node.start_mark.line + 1}: a key must be a name, got {key!r}")
        if key in mapping:
            raise GraphError(f"line {key_node.start_mark.line + 1}: duplicate key {key!r}")
        mapping[key] = loader.construct_object(value_node, deep=True)
        mapping.lines[key] = key_node.start_mark.line + 1
    mapping.line = node.start_mark.line + 1
    return mapping


class _LineDict(dict):
    """A dict that remembers the line of each key (and its own)."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: dict[Any, int] = {}
        self.line = 0


def _line(d: Any, key: Any | None = None) -> int:
    if isinstance(d, _LineDict):
        return d.lines.get(key, d.line) if key is not None else d.line
    return 0


@dataclass
class StagePlan:
    """One stage, resolved: full topic keys, validated parameters."""

    name: str
    kind: str
    params: dict[str, Any]
    inputs: dict[str, str]
    outputs: dict[str, str]
    restart: str = "never"
    max_restarts: int = 3
    qos: dict[str, str] = field(default_factory=dict)
    snapshot_every: int = 0
    host: str = ""  # the host label the stage is placed on ('' : wherever the graph runs)

    def is_source(self) -> bool:
        return self.kind == "source"


@dataclass
class Plan:
    """A validated graph: what the launcher, the node processes and the inline executor run."""

    name: str
    stream: str
    stages: dict[str, StagePlan]
    source_text: str = ""
    base_dir: str = "."
    on_host_lost: str = "stop"  # stop the run, or wait for the host to come back
    #: the graph's own stream (the camera): what stages seed their random draws and stamp their
    #: headers with, so a run's results do not depend on its run id ('' : the same as ``stream``)
    camera: str = ""
    external: list[str] = field(default_factory=list)  # topic keys fed from outside the graph
    #: the tracker and its parameters, named once for every stage of it (None: a graph, or a
    #: recording's plan, that names them per stage)
    tracker: TrackerBlock | None = None

    def stage_params(self, name: str) -> dict[str, Any]:
        """Every parameter stage ``name`` is built with: its own and, for a stage of the graph's
        tracker, those of the tracker block."""
        sp = self.stages[name]
        if self.tracker is None or sp.kind == RECORDER_KIND or stage_tracker(STAGES[sp.kind].Params) is None:
            return sp.params
        return {**self.tracker.params, **sp.params}

    @property
    def seed_stream(self) -> str:
        return self.camera or self.stream

    @property
    def error_topic(self) -> str:
        return topic_key(self.stream, "errors")

    def status_topic(self, stage: str) -> str:
        return topic_key(self.stream, f"_status/{stage}")

    def progress_topic(self, stage: str) -> str:
        """Where a worker reports each step it finished (``gflow/<stream>/@progress/<stage>``).
        A verbatim chunk (``@``): no wildcard matches it, so only the sources (flow control)
        and tools that ask for it by name (``replay --lockstep``) receive these, not every
        process of the graph and not the recorder (measured: ~150-280 us of CPU per receipt)."""
        return topic_key(self.stream, f"{PROGRESS}/{stage}")

    def snapshot_topic(self, stage: str) -> str:
        return topic_key(self.stream, f"_snapshot/{stage}")

    @property
    def control_topic(self) -> str:
        return topic_key(self.stream, "_control")

    def recorder(self) -> StagePlan | None:
        for s in self.stages.values():
            if s.kind == RECORDER_KIND:
                return s
        return None

    def drop_topics(self) -> frozenset[str]:
        return frozenset(t for s in self.stages.values() for port, t in s.outputs.items() if s.qos.get(port) == "drop")

    def config_metadata(self) -> dict[str, str]:
        """MCAP metadata ``gflow.config``: every stage's resolved plan (kind, parameters with
        their defaults, wiring, restart and snapshot policy) as JSON, plus the stream, the base
        folder of relative paths and, once, the tracker block (``tracker``: its name and every
        parameter). :meth:`from_metadata` rebuilds the plan from it."""
        out = {"stream": self.stream, "graph_name": self.name, "base_dir": str(Path(self.base_dir).resolve())}
        if self.camera and self.camera != self.stream:
            out["camera"] = self.camera
        if self.tracker is not None:
            out[TRACKER_KEY] = json.dumps(dataclasses.asdict(self.tracker), sort_keys=True)
        for n, s in self.stages.items():
            out[f"stage.{n}"] = json.dumps(dataclasses.asdict(s), sort_keys=True)
        return out

    @classmethod
    def from_metadata(cls, graph: dict[str, str], config: dict[str, str]) -> "Plan":
        """The plan a recording was made with (see :meth:`config_metadata`); a recording made before
        the tracker block existed holds every stage's parameters itself, read as they are."""
        stages = {}
        for key, val in config.items():
            if key.startswith("stage."):
                d = json.loads(val)
                d.setdefault("name", key[len("stage."):])
                stages[d["name"]] = StagePlan(**{k: v for k, v in d.items() if k in StagePlan.__dataclass_fields__})
        if not stages:
            raise GraphError("the recording's gflow.config metadata names no stage")
        block = json.loads(config[TRACKER_KEY]) if TRACKER_KEY in config else None
        tracker = _as_recorded(TrackerBlock(**block) if block else None, stages)
        return cls(name=config.get("graph_name", graph.get("name", "recorded")), stream=config["stream"],
                   camera=config.get("camera", ""), tracker=tracker,
                   stages=stages, source_text=graph.get("yaml", ""), base_dir=config.get("base_dir", "."))

    def recording_path(self) -> str | None:
        rec = self.recorder()
        if rec is None:
            return None
        path = rec.params.get("path", RecorderParams().path)
        # the run id (demo-3f9c2a: pipeline/runtime/runid.py), or a fresh one for a run without
        # (--inline): two runs started in the same second never share a name
        cam = self.camera or ""
        run = self.stream[len(cam) + 1:] if cam and self.stream.startswith(cam + "-") else secrets.token_hex(3)
        p = Path(self.base_dir, path.format(name=self.name, time=time.strftime("%Y%m%d-%H%M%S"), run=run))
        if "{run}" not in path and "{time}" in path:
            p = p.with_name(f"{p.stem}-{run}{p.suffix}")
        return str(unique_path(p))


def _as_recorded(block: TrackerBlock | None, stages: dict[str, StagePlan]) -> TrackerBlock | None:
    """A recorded plan's parameters with each parameter added since at the value the code had before
    it existed (``gflow_core.params.param(before=...)``): in the tracker block, or, in a plan recorded
    before the block, in each stage's copy. A tracker or stage kind no longer known is left as it is
    (validating the plan names it)."""
    if block is not None:
        try:
            return TrackerBlock(block.name, as_recorded(block_class(block), block.params))
        except ValueError:
            return block
    for s in stages.values():
        cls = stage_tracker(STAGES[s.kind].Params) if s.kind in STAGES else None
        if cls is not None:
            s.params = as_recorded(cls, s.params)
    return None


#: the key chunk of the per-step progress heartbeats (:meth:`Plan.progress_topic`)
PROGRESS = "@progress"

#: topics every recording keeps, whatever ``topics`` says (``captures``: what a live source
#: sent and skipped, the camera's frame numbers of the estimates)
ALWAYS_RECORDED = ("errors", "_status/*", "_control", "captures")


def recorded_topic_filter(params: dict, stream: str):
    """``keep(topic) -> bool`` for the recorder's ``topics`` patterns (see :class:`RecorderParams`)."""
    import fnmatch

    pats = tuple(params.get("topics") or ["*"]) + ALWAYS_RECORDED
    if "*" in pats:
        return lambda topic: True
    prefix = f"gflow/{stream}/"
    return lambda topic: topic.startswith(prefix) and any(fnmatch.fnmatchcase(topic[len(prefix):], p) for p in pats)


def _params_struct(kind: str) -> type[Params]:
    if kind == RECORDER_KIND:
        return RecorderParams
    return STAGES[kind].Params


def params_error(kind: str, params: dict[str, Any]) -> str | None:
    """Why the stage kind ``kind`` refuses ``params`` (an unknown name, a wrong type, a value out of
    range), in one line; None when it takes them."""
    typ = _params_struct(kind)
    try:
        msgspec.convert(dict(params), typ, strict=False)
    except (msgspec.ValidationError, ValueError, TypeError) as e:
        unknown = _UNKNOWN_FIELD.fullmatch(str(e))
        if unknown is not None:
            # the names a stage takes help with a mistyped name, not with a value out of range
            known = ', '.join(f.name for f in msgspec.structs.fields(typ))
            return f"no parameter {unknown.group(1)!r} (known parameters: {known})"
        return plain_type_error(str(e), params)
    return None


#: msgspec's wording of a name the struct does not have
_UNKNOWN_FIELD = re.compile(r"Object contains unknown field `([^`]+)`")


def validate_params(kind: str, params: dict[str, Any], where: str) -> dict[str, Any]:
    """Convert params to the stage's struct (unknown keys and wrong types are errors); return plain data."""
    why = params_error(kind, params)
    if why is not None:
        raise GraphError(f"{where}: bad parameter for stage kind {kind!r}: {why}")
    return msgspec.to_builtins(msgspec.convert(dict(params), _params_struct(kind), strict=False))


def _read_doc(text: str, filename: str) -> dict:
    """The graph's YAML as a mapping whose parts remember their lines (:func:`_line`)."""
    import yaml

    try:
        doc = yaml.load(text, Loader=_line_loader())
    except GraphError as e:
        raise GraphError(f"{filename}: {e}") from None
    except yaml.YAMLError as e:
        raise GraphError(f"{filename}: not valid YAML: {e}") from None
    if not isinstance(doc, dict):
        raise GraphError(f"{filename}: a graph must be a mapping with 'name', 'stream' and 'stages'")
    return doc


def _check_top_level(doc: dict, filename: str, overrides: dict[str, dict]) -> tuple[str, str, str, dict]:
    """The graph's top-level keys checked: returns its name, stream, ``on_host_lost`` and the mapping
    of stages (which every stage ``overrides`` names must be in)."""
    unknown = set(doc) - {"name", "stream", "stages", "description", "external", "on_host_lost", TRACKER_KEY}
    if unknown:
        k = sorted(unknown)[0]
        raise GraphError(f"{filename}:{_line(doc, k)}: unknown top-level key {k!r} "
                         f"(expected name, stream, tracker, stages, external, on_host_lost, description)")
    on_host_lost = doc.get("on_host_lost", "stop")
    if on_host_lost not in ON_HOST_LOST:
        raise GraphError(f"{filename}:{_line(doc, 'on_host_lost')}: on_host_lost must be stop or wait, "
                         f"got {on_host_lost!r}")
    name = _name_of(doc, "name", Path(filename).stem, filename)
    stream = _name_of(doc, "stream", "cam0", filename)
    try:
        topic_key(stream, "x")
    except ValueError as e:
        raise GraphError(f"{filename}:{_line(doc, 'stream')}: {e}") from None
    stages_doc = doc.get("stages")
    if not isinstance(stages_doc, dict) or not stages_doc:
        raise GraphError(f"{filename}:{_line(doc, 'stages')}: 'stages' must be a non-empty mapping of stage name -> spec")
    for sname in overrides:
        if sname not in stages_doc and sname != TRACKER_KEY:
            raise GraphError(f"{filename}: override for stage {sname!r}, which the graph does not have "
                             f"(stages: {', '.join(stages_doc)})")
    return name, stream, on_host_lost, stages_doc


@dataclass
class _ParsedStage:
    """One stage of a graph file, checked on its own: its plan, the lines of the stage and of each of
    its inputs (for errors), and its input and output port types (port -> message type)."""

    plan: StagePlan
    line: int
    input_lines: dict[str, int]
    in_types: Mapping[str, type]
    out_types: Mapping[str, type]


def _stage_kind(sname: str, spec: Any, where: str, filename: str) -> str:
    """The kind of stage ``sname``, whose ``spec`` must be a mapping of known keys naming a known kind."""
    if not isinstance(spec, dict):
        raise GraphError(f"{where}: stage {sname!r} must be a mapping with at least 'kind'")
    bad = set(spec) - _STAGE_KEYS
    if bad:
        k = sorted(bad)[0]
        raise GraphError(f"{filename}:{_line(spec, k)}: stage {sname!r}: unknown key {k!r} "
                         f"(expected {', '.join(sorted(_STAGE_KEYS))})")
    kind = spec.get("kind")
    if not isinstance(kind, str) or (kind != RECORDER_KIND and kind not in STAGES):  # a list or mapping: no name
        known = ", ".join(sorted([*STAGES, RECORDER_KIND]))
        raise GraphError(f"{filename}:{_line(spec, 'kind')}: stage {sname!r}: unknown stage kind {kind!r} (known: {known})")
    assert isinstance(kind, str)  # the recorder's kind or a registered one
    return kind


def _check_ports(sname: str, kind: str, inputs_doc: dict, outputs_doc: dict, in_types: Mapping[str, type],
                 out_types: Mapping[str, type], where: str, filename: str) -> None:
    """Every port the stage's ``inputs`` and ``outputs`` name exists, and every input port is connected."""
    for port in inputs_doc:
        if port not in in_types:
            raise GraphError(f"{filename}:{_line(inputs_doc, port)}: stage {sname!r} ({kind}) has no input "
                             f"port {port!r} (ports: {', '.join(in_types) or 'none'})")
    for port in outputs_doc:
        if port not in out_types:
            raise GraphError(f"{filename}:{_line(outputs_doc, port)}: stage {sname!r} ({kind}) has no output "
                             f"port {port!r} (ports: {', '.join(out_types) or 'none'})")
    for port in in_types:
        if port not in inputs_doc:
            raise GraphError(f"{where}: stage {sname!r} ({kind}): input port {port!r} is not connected "
                             f"(add inputs: {{{port}: <topic>}})")


def _stage_policy(sname: str, spec: dict, filename: str) -> tuple[str, dict, int, str]:
    """The stage's restart policy, qos per port, snapshot period (frames) and host label, checked."""
    restart = spec.get("restart", "never")
    if restart not in ("never", "on-failure"):
        raise GraphError(f"{filename}:{_line(spec, 'restart')}: stage {sname!r}: restart must be 'never' or 'on-failure'")
    qos = spec.get("qos") or {}
    if not isinstance(qos, dict):
        raise GraphError(f"{filename}:{_line(spec, 'qos')}: stage {sname!r}: qos must be a mapping port -> reliable "
                         f"or drop, got {qos!r}")
    qos = dict(qos)
    for port, q in qos.items():
        if q not in ("reliable", "drop"):
            raise GraphError(f"{filename}:{_line(spec, 'qos')}: stage {sname!r}: qos of {port!r} must be reliable or drop")
    snap = spec.get("snapshot_every", 0)
    if not isinstance(snap, int) or snap < 0:
        raise GraphError(f"{filename}:{_line(spec, 'snapshot_every')}: stage {sname!r}: snapshot_every must be "
                         f"a whole number of frames >= 0, got {snap!r}")
    host = spec.get("host", "")
    if not isinstance(host, str) or (host and not _HOST_LABEL.match(host)):
        raise GraphError(f"{filename}:{_line(spec, 'host')}: stage {sname!r}: host must be a label of letters, "
                         f"digits, '-' or '_', got {host!r}")
    return restart, qos, snap, host


def _max_restarts(sname: str, spec: dict, filename: str) -> int:
    """The stage's ``max_restarts`` (default 3): a whole number >= 0. Text there was "invalid literal for int()"
    naming no file, and a negative number a policy that restarts nothing."""
    n = spec.get("max_restarts", 3)
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise GraphError(f"{filename}:{_line(spec, 'max_restarts')}: stage {sname!r}: max_restarts must be a whole "
                         f"number >= 0, got {n!r}")
    return n


def _wiring_doc(sname: str, spec: dict, where: str, filename: str) -> tuple[dict, dict]:
    """The stage's ``inputs`` and ``outputs``: mappings of port names to topic names (none: empty). A list or a
    mapping for a port or a topic was an internal error, or a topic named by its text ("gflow/demo/['frames']")."""
    docs = spec.get("inputs") or {}, spec.get("outputs") or {}
    if not all(isinstance(d, dict) for d in docs):
        raise GraphError(f"{where}: stage {sname!r}: inputs and outputs must be mappings port -> topic")
    for d in docs:
        for port, topic in d.items():
            if not isinstance(port, str) or isinstance(topic, (list, dict)) or topic is None:
                raise GraphError(f"{filename}:{_line(d, port) if isinstance(port, str) else _line(spec, 'inputs')}: "
                                 f"stage {sname!r}: {port!r}: {topic!r}: a port and its topic are names")
    return docs


def _stage_values(sname: str, kind: str, params: dict[str, Any], block: TrackerBlock | None,
                  overrides: dict[str, dict], pwhere: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """(every parameter the stage is built with, the stage's own ones) of the stage's ``params`` (with
    its overrides) and the graph's tracker ``block``: a stage of the block's tracker takes the block's
    values and may name none of them itself; without a block, overrides of ``tracker`` are applied
    to every stage of a tracker."""
    cls = stage_tracker(_params_struct(kind))
    if cls is None:
        full = validate_params(kind, params, pwhere)
        return full, full
    if block is None:
        full = validate_params(kind, {**params, **overrides.get(TRACKER_KEY, {})}, pwhere)
        return full, full
    shared = sorted(set(params) & set(block.params))
    if shared:
        raise GraphError(f"{pwhere}: {shared[0]} is a parameter of tracker {block.name}, set once for all its stages "
                         f"in the graph's tracker block: set tracker.{shared[0]} (--set tracker.{shared[0]}=VALUE)")
    if set(tracker_fields(cls)) != set(block.params):  # another tracker's block
        raise GraphError(f"{pwhere}: a stage of the tracker of {cls.__name__}, but the graph's tracker block is "
                         f"{block.name}'s")
    full = validate_params(kind, {**block.params, **params}, pwhere)
    return full, own_fields(full, cls)


def _tracker_preprocess(block: TrackerBlock) -> dict[str, Any]:
    """The preprocess parameters the registered tracker of ``block`` names
    (:attr:`gflow_core.spec.TrackerSpec.preprocess`; a block's tracker is registered), for its own
    parameter dataclass (none for a variant: m2 with a patch model reads no edges)."""
    from gflow_core.registry import get

    return dict(get(block.name).preprocess) if is_main_class(block) else {}


def _name_of(doc: dict, key: str, default: str, filename: str) -> str:
    """The graph's ``name`` or ``stream``: a word or a number, not a list or a mapping (whose text, "['demo']",
    would have named the run and its topics)."""
    v = doc.get(key, default)
    if isinstance(v, (list, dict)) or v is None:
        raise GraphError(f"{filename}:{_line(doc, key)}: {key} must be a word or a number, got {v!r}")
    return str(v)


def _params_doc(sname: str, spec: dict, filename: str) -> dict:
    """A copy of the ``params`` of stage ``sname`` (none: empty), which must be a mapping of names to values."""
    params = spec.get("params") or {}
    if not isinstance(params, dict):
        raise GraphError(f"{filename}:{_line(spec, 'params')}: stage {sname!r}: params must be a mapping name -> "
                         f"value, got {params!r}")
    return dict(params)


def _parse_stage(sname: str, spec: Any, stages_doc: dict, stream: str, overrides: dict[str, dict],
                 filename: str, block: TrackerBlock | None = None) -> _ParsedStage:
    """Stage ``sname`` of the graph: its kind, its parameters (with ``overrides`` applied; a stage of
    the tracker of ``block`` takes that tracker's from it) validated, its ports, its wiring to topics
    of ``stream`` and its policies."""
    where = f"{filename}:{_line(stages_doc, sname)}"
    kind = _stage_kind(sname, spec, where, filename)
    params = _params_doc(sname, spec, filename)
    if kind == PREPROCESS_KIND and block is not None:
        params = {**_tracker_preprocess(block), **params}
    params.update(overrides.get(sname, {}))
    pwhere = f"{filename}:{_line(spec, 'params') or _line(stages_doc, sname)}: stage {sname!r}"
    full, params = _stage_values(sname, kind, params, block, overrides, pwhere)
    cls = None if kind == RECORDER_KIND else STAGES[kind]
    in_types, out_types = cls.ports(msgspec.convert(full, cls.Params)) if cls else ({}, {})
    inputs_doc, outputs_doc = _wiring_doc(sname, spec, where, filename)
    if cls is not None:
        _check_ports(sname, kind, inputs_doc, outputs_doc, in_types, out_types, where, filename)
    restart, qos, snap, host = _stage_policy(sname, spec, filename)
    outs = {p: topic_key(stream, str(outputs_doc.get(p, p))) for p in out_types}
    ins = {p: topic_key(stream, str(t)) for p, t in inputs_doc.items()}
    plan = StagePlan(name=sname, kind=kind, params=params, inputs=ins, outputs=outs, restart=restart,
                     max_restarts=_max_restarts(sname, spec, filename), qos=qos, snapshot_every=snap, host=host)
    return _ParsedStage(plan=plan, line=_line(stages_doc, sname), input_lines={p: _line(inputs_doc, p) for p in inputs_doc},
                        in_types=in_types, out_types=out_types)


def _producers(doc: dict, stages: dict[str, _ParsedStage], stream: str, filename: str
               ) -> tuple[dict, dict[str, tuple[str, str, type]]]:
    """The graph's ``external`` topics (topic -> message type name) and the producer of every topic:
    topic key -> (stage or "outside the graph", port, message type). Two stages may not publish one topic."""
    from gflow_msgs.messages import MESSAGE_TYPES

    producers: dict[str, tuple[str, str, type]] = {}
    external = doc.get("external") or {}
    if not isinstance(external, dict):
        raise GraphError(f"{filename}:{_line(doc, 'external')}: 'external' must map topic -> message type")
    for topic, tname in external.items():
        if tname not in MESSAGE_TYPES:
            raise GraphError(f"{filename}:{_line(external, topic)}: external topic {topic!r}: unknown message type "
                             f"{tname!r} (known: {', '.join(sorted(MESSAGE_TYPES))})")
        producers[topic_key(stream, str(topic))] = ("outside the graph", "external", MESSAGE_TYPES[tname])
    for ps in stages.values():
        s = ps.plan
        if s.kind == RECORDER_KIND:
            continue
        for port, topic in s.outputs.items():
            if topic in producers:
                other = producers[topic][0]
                raise GraphError(f"{filename}:{ps.line}: stages {other!r} and {s.name!r} both publish {topic}")
            producers[topic] = (s.name, port, ps.out_types[port])
    return external, producers


def _check_inputs(stages: dict[str, _ParsedStage], producers: dict[str, tuple[str, str, type]], filename: str) -> None:
    """Every input is fed by some producer with the message type it expects, and not by its own stage."""
    for ps in stages.values():
        s = ps.plan
        if s.kind == RECORDER_KIND:
            continue
        for port, topic in s.inputs.items():
            line = ps.input_lines.get(port, ps.line)
            if topic not in producers:
                raise GraphError(f"{filename}:{line}: stage {s.name!r} input {port!r} is not connected: no stage "
                                 f"publishes {topic} (published: {', '.join(sorted(producers)) or 'nothing'})")
            pname, pport, ptype = producers[topic]
            want = ps.in_types[port]
            if ptype is not want:
                raise GraphError(f"{filename}:{line}: type mismatch: stage {s.name!r} input {port!r} expects "
                                 f"{want.__name__}, but {topic} carries {ptype.__name__} from {pname}.{pport}")
            if pname == s.name:
                # frame t would wait for the stage's own output of frame t: it can never start
                raise GraphError(f"{filename}:{line}: stage {s.name!r} input {port!r} is fed by its own output "
                                 f"{pport!r} ({topic}): a cycle that can never start (feed it through a stage "
                                 f"that predicts the next frame, as particle.proposal does)")


def _check_whole(stages: dict[str, _ParsedStage], external: dict, filename: str) -> None:
    """What the graph as a whole needs: something to start from, at most one recorder, and a host for
    every stage or for none."""
    plans = [ps.plan for ps in stages.values()]
    if not any(s.is_source() for s in plans) and not external:
        raise GraphError(f"{filename}: the graph has no source stage and no external topics")
    if sum(1 for s in plans if s.kind == RECORDER_KIND) > 1:
        raise GraphError(f"{filename}: at most one recorder per graph")
    placed = [s for s in plans if s.host]
    if placed and len(placed) != len(plans):
        s = next(s for s in plans if not s.host)
        raise GraphError(f"{filename}:{stages[s.name].line}: stage {s.name!r} has no host, but other stages do: in a "
                         f"graph placed on hosts every stage needs one (host: {placed[0].host}, say)")


def parse_graph(text: str, filename: str = "<graph>", base_dir: str = ".", overrides: dict[str, dict] | None = None) -> Plan:
    """Parse and validate a graph. ``overrides`` = {stage: {param: value}} is applied before validation.

    The checks run in order, the first failing one raising :class:`GraphError`: the YAML
    (:func:`_read_doc`), the top-level keys (:func:`_check_top_level`), each stage on its own
    (:func:`_parse_stage`), the topics' producers (:func:`_producers`), the wiring of every input
    (:func:`_check_inputs`) and the graph as a whole (:func:`_check_whole`).
    """
    doc = _read_doc(text, filename)
    overrides = overrides or {}
    name, stream, on_host_lost, stages_doc = _check_top_level(doc, filename, overrides)
    block = _tracker_block(doc, overrides, filename)
    stages = {sname: _parse_stage(sname, spec, stages_doc, stream, overrides, filename, block)
              for sname, spec in stages_doc.items()}
    external, producers = _producers(doc, stages, stream, filename)
    _check_inputs(stages, producers, filename)
    _check_whole(stages, external, filename)
    return Plan(name=name, stream=stream, stages={n: ps.plan for n, ps in stages.items()}, source_text=text,
                base_dir=base_dir, on_host_lost=str(on_host_lost), external=[topic_key(stream, str(t)) for t in external],
                tracker=block)


def _tracker_block(doc: dict, overrides: dict[str, dict], filename: str) -> TrackerBlock | None:
    """The graph's tracker block with the overrides of ``tracker`` applied (None: the graph has none)."""
    kinds = [s.get("kind") for s in (doc.get("stages") or {}).values() if isinstance(s, dict)]
    classes = frozenset(c for k in kinds if isinstance(k, str) and k in STAGES
                        and (c := stage_tracker(STAGES[k].Params)) is not None)
    if TRACKER_KEY not in doc:
        if overrides.get(TRACKER_KEY) and not classes:
            raise GraphError(f"{filename}: tracker.{next(iter(overrides[TRACKER_KEY]))}: the graph runs no tracker "
                             f"whose parameters it could set")
        return None
    try:
        return parse_block(doc[TRACKER_KEY], overrides.get(TRACKER_KEY, {}), classes)
    except ValueError as e:
        raise GraphError(f"{filename}:{_line(doc, TRACKER_KEY)}: {e}") from None


#: The graphs that ship with gflow (package data, ``pipeline/graphs/*.yaml``).
GRAPHS_DIR = Path(__file__).resolve().parent.parent / "graphs"


def load_graph(path: str | Path, overrides: dict[str, dict] | None = None, base_dir: str | None = None) -> Plan:
    """Read and validate a graph file. Relative paths inside it resolve against ``base_dir`` (default: cwd)."""
    p = Path(path)
    if not p.is_file():
        builtin = GRAPHS_DIR / (p.name if p.suffix else p.name + ".yaml")
        if builtin.is_file():
            p = builtin
        elif p.is_dir():  # there, so "not found" would send the user looking for a file that exists
            raise GraphError(f"{path} is a folder, not a graph file (give a .yaml file, or a built-in graph: "
                             f"{', '.join(builtin_graphs())})")
        else:
            raise GraphError(f"graph file not found: {path} (built-in graphs: {', '.join(builtin_graphs())})")
    from pipeline.io.text_files import read_text

    return parse_graph(read_text(p, "graph file", GraphError), str(p), base_dir or ".", overrides)


def builtin_graphs() -> list[str]:
    return sorted(q.stem for q in GRAPHS_DIR.glob("*.yaml"))
