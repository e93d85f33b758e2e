"""M2's edge settings are named once (gflow_core.m2.edge_settings): `gflow learn m2`'s defaults, a
model file without thresholds tracked by gflow track and by the Python API, and the m2 graph's
preprocess stage (filled in from the m2 tracker's registration by the graph loader)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import msgspec
import pytest
import yaml

from gflow_core.contour.params import EdgeParams
from gflow_core.contour.protocol import m2_edge_params
from gflow_core.m2.curves import Curves
from gflow_core.m2.dynamics import random_walk
from gflow_core.m2.edge_settings import LEARN_EDGES
from gflow_core.m2.model import M2Model

import numpy as np

GRAPHS = Path(__file__).resolve().parent.parent / "pipeline" / "graphs"
EDGE_FIELDS = tuple(f.name for f in dataclasses.fields(EdgeParams))


def test_the_m2_graph_preprocesses_with_the_learn_defaults() -> None:
    """The graph file names no edge setting; the loaded graph's preprocess stage has the learn defaults,
    under the graph's own values and the command line's."""
    from pipeline.runtime.graph import GraphError, load_graph, parse_graph

    text = (GRAPHS / "m2.yaml").read_text()
    assert not set(yaml.safe_load(text)["stages"]["preprocess"]["params"]) & set(EDGE_FIELDS)
    pre = load_graph("m2").stages["preprocess"].params
    assert {k: pre[k] for k in EDGE_FIELDS} == dataclasses.asdict(LEARN_EDGES) and pre["colour"] is True
    over = load_graph("m2", overrides={"preprocess": {"canny_low": 20}}).stages["preprocess"].params
    assert (over["canny_low"], over["canny_high"]) == (20.0, LEARN_EDGES.canny_high)
    own = parse_graph(text.replace("params: {colour: true}", "params: {colour: true, profile: linear}"),
                      "own.yaml").stages["preprocess"].params
    assert (own["profile"], own["canny_low"]) == ("linear", LEARN_EDGES.canny_low)
    with pytest.raises(GraphError, match="own.yaml:.*'preprocess'.*profile"):  # checked with the tracker's values
        parse_graph(text.replace("params: {colour: true}", "params: {colour: true, profile: curved}"), "own.yaml")
    # a graph of another tracker, and a patch model's graph (it reads the grey image alone), get none
    assert load_graph("chamfer").stages["preprocess"].params["canny_low"] is None
    patch = yaml.safe_load((GRAPHS / "m2_patch.yaml").read_text())["stages"]["preprocess"]["params"]
    assert patch == {"edges": False} and load_graph("m2_patch").stages["preprocess"].params["canny_low"] is None


def test_gflow_learn_m2_defaults_are_the_edge_settings() -> None:
    from pipeline.cli.commands.learn import register

    p = argparse.ArgumentParser()
    register(p.add_subparsers())
    a = p.parse_args(["learn", "m2", "src", "--out", "m.npz"])
    assert (a.canny, a.blur, a.profile, a.g0) == (f"{LEARN_EDGES.canny_low:g},{LEARN_EDGES.canny_high:g}",
                                                  LEARN_EDGES.blur, LEARN_EDGES.profile, LEARN_EDGES.g0)


def test_a_model_file_without_thresholds_is_tracked_with_the_learn_defaults() -> None:
    rng, K = np.random.default_rng(0), 2
    model = M2Model(metric="chamfer", kernel="moments", exemplars=Curves.from_list([rng.normal(0, 10, (20, 2))] * K),
                    d=np.full(K, 3.0), sigma=np.full(K, 1.0), pi=np.full(K, 1 / K), markov=np.full((K, K), 1 / K),
                    dynamics=random_walk(2.0, 0.01, 0.01), ref_size=np.array([25.0, 66.0]), profile="truncated",
                    g0=64.0)
    e = m2_edge_params(model, {})
    assert e == dataclasses.replace(LEARN_EDGES, profile="truncated", g0=64.0)
    own = m2_edge_params(model, {"canny_low": 20, "canny_high": 60, "blur": 0.5})
    assert (own.canny_low, own.canny_high, own.blur) == (20.0, 60.0, 0.5)


def test_the_preprocess_stage_has_every_edge_setting_with_its_default() -> None:
    """stages.preprocess.PreprocessParams is derived from EdgeParams (every field, its type and default),
    without being a stage of a tracker: a graph's tracker block does not feed it."""
    from stages.preprocess import PreprocessParams
    from gflow_msgs.params import tracker_of
    from pipeline.runtime.graph import GraphError, parse_graph

    fields = {f.name: f.default for f in msgspec.structs.fields(PreprocessParams)}
    assert {f.name: fields.get(f.name, "(missing)") for f in dataclasses.fields(EdgeParams)} == \
        {f.name: f.default for f in dataclasses.fields(EdgeParams)}
    assert tracker_of(PreprocessParams) is None
    with pytest.raises(msgspec.ValidationError, match="profile"):  # EdgeParams' type, as the stage checks it
        msgspec.convert({"profile": "curved"}, PreprocessParams)
    text = (GRAPHS / "chamfer.yaml").read_text()
    pre = parse_graph(text, "c.yaml").stages["preprocess"].params  # the graph's own values, none of the block's
    assert (pre["profile"], pre["g0"], pre["colour"]) == ("truncated", 100.0, True) and "min_edges" not in pre
    with pytest.raises(GraphError, match="'preprocess'.*min_edges"):  # a tracker parameter is not the stage's
        parse_graph(text.replace("colour: true}", "colour: true, min_edges: 2}"), "c.yaml")
