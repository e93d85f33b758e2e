"""Graph files are validated before launch, with errors that name the line."""

import textwrap

import pytest

from pipeline.runtime.graph import GraphError, load_graph, parse_graph

GOOD = textwrap.dedent("""\
    name: t
    stream: cam0
    stages:
      source:
        kind: source
        params: {kind: synthetic, frames: 5}
      preprocess:
        kind: preprocess
        inputs: {frames: frames}
      proposal:
        kind: particle.proposal
        inputs: {particles: particles}
      filter:
        kind: particle.filter
        inputs: {features: features, proposals: proposals}
        params: {init: [1, 2, 3, 4]}
      recorder:
        kind: recorder
    """)


def test_good_graph_resolves_topics():
    plan = parse_graph(GOOD, "g.yaml")
    assert plan.stages["filter"].inputs == {"features": "gflow/cam0/features", "proposals": "gflow/cam0/proposals"}
    assert plan.stages["filter"].outputs["estimate"] == "gflow/cam0/estimate"
    assert plan.stages["filter"].params["seed"] == 0  # defaults are filled in


@pytest.mark.parametrize("old,new,line,words", [
    ("kind: preprocess", "kind: preprocesss", 8, "unknown stage kind 'preprocesss'"),
    ("params: {init: [1, 2, 3, 4]}", "params: {init: [1, 2, 3, 4], particels: 5}", 16, "particels"),
    ("inputs: {frames: frames}", "inputs: {frames: framez}", 9, "no stage publishes gflow/cam0/framez"),
    ("inputs: {particles: particles}", "inputs: {particles: estimate}", 12, "type mismatch"),
    ("params: {kind: synthetic, frames: 5}", "params: {kind: synthetic, frames: five}", 6, "frames"),
])
def test_typos_name_the_line(old, new, line, words):
    text = GOOD.replace(old, new)
    with pytest.raises(GraphError) as e:
        parse_graph(text, "g.yaml")
    msg = str(e.value)
    assert f"g.yaml:{line}:" in msg and words in msg, msg


def test_missing_input_is_unconnected():
    text = GOOD.replace("    inputs: {frames: frames}\n", "")
    with pytest.raises(GraphError, match="input port 'frames' is not connected"):
        parse_graph(text, "g.yaml")


def test_builtin_graphs_are_valid():
    for name in ("demo", "chamfer"):
        plan = load_graph(name, overrides={"filter": {"init": [1, 2, 3, 4]}})
        assert {"source", "preprocess", "proposal", "filter", "recorder"} <= set(plan.stages)
