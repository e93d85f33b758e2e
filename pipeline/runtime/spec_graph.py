"""The graph of a registered tracker that has no graph file: made from its spec.

A tracker whose spec (:class:`gflow_core.spec.TrackerSpec`) gives box stages and no ``graph``
runs in the graph of the built-in box trackers (``pipeline/graphs/dcf.yaml``): a source, its
proposal stage (kind ``NAME.proposal``, input ``particles``), its filter stage (kind
``NAME.filter``, inputs ``frames`` and ``proposals``) and the recorder. ``gflow track --tracker
NAME`` fills in the source and, in both stages, the initial box and the seed; the tracker's
parameters are the graph's tracker block (``tracker: NAME``), which both stages take.
"""

from __future__ import annotations

from gflow_core.spec import TrackerSpec

from pipeline.runtime.graph import Plan, parse_graph

__all__ = ["spec_graph_text", "spec_plan"]


def spec_graph_text(spec: TrackerSpec) -> str:
    """The YAML of the graph tracker ``spec`` runs in."""
    return f"""\
name: {spec.name}
stream: cam0
tracker: {spec.name}
stages:
  source:
    kind: source
    restart: on-failure
    params: {{kind: folder, path: "frames", fps: 25}}
  proposal:
    kind: {spec.proposal_kind}
    restart: on-failure
    inputs: {{particles: particles}}
    params: {{seed: 0}}
  filter:
    kind: {spec.filter_kind}
    restart: on-failure
    inputs: {{frames: frames, proposals: proposals}}
    snapshot_every: 25
    params: {{seed: 0}}
  recorder:
    kind: recorder
    restart: on-failure
    params: {{path: "recordings/track-{{time}}.mcap"}}
"""


def spec_plan(spec: TrackerSpec, overrides: dict[str, dict] | None = None, base_dir: str = ".") -> Plan:
    """The plan of :func:`spec_graph_text` with ``overrides`` ({stage: {param: value}})."""
    return parse_graph(spec_graph_text(spec), f"<graph of tracker {spec.name} ({spec.origin or 'registered'})>",
                       base_dir, overrides)
