"""A tracker's parameters live in one dataclass; the stages' structs, the graph files, the command
line's options and help, ``gflow info`` and the Python API all derive from it and cannot drift."""

from __future__ import annotations

import dataclasses
import io
import json
import sys
import typing
from contextlib import redirect_stdout

import msgspec
import pytest

from gflow_core.appearance.params import AppearanceParams
from gflow_core.appearance.tracker import AppearanceTracker
from gflow_core.gflow import GFlowParams, GFlowTracker
from gflow_core.params import describe, format_value
from gflow_core.tracker import TrackingFilter
from pipeline.cli.trackers import TRACKERS
from pipeline.runtime.graph import load_graph
from stages.registry import get_stage_class
import cli_fork

#: tracker name -> its parameter dataclass (the trackers whose parameters live in one)
WITH_PARAMS = {name: mod.PARAMS for name, mod in TRACKERS.items() if getattr(mod, "PARAMS", None) is not None}


def test_the_trackers_on_the_protocol_have_their_parameters_in_one_dataclass() -> None:
    assert WITH_PARAMS["gflow"] is GFlowParams and WITH_PARAMS["appearance"] is AppearanceParams


@pytest.mark.parametrize("name", sorted(WITH_PARAMS))
def test_every_stage_of_the_tracker_takes_every_parameter_with_the_dataclass_default(name) -> None:
    cls = WITH_PARAMS[name]
    hints = typing.get_type_hints(cls)
    plan = load_graph(TRACKERS[name].GRAPH)
    derived = [s for s in plan.stages.values() if s.kind not in ("source", "recorder", "preprocess")]
    assert derived
    for sp in derived:
        fields = {f.name: f for f in msgspec.structs.fields(get_stage_class(sp.kind).Params)}
        for f in dataclasses.fields(cls):
            assert f.name in fields, f"{sp.kind} has no parameter {f.name}"
            assert fields[f.name].default == f.default, f"{sp.kind}.{f.name}"
            assert fields[f.name].type == hints[f.name], f"{sp.kind}.{f.name}"
            # the stage's entry holds its own fields only: the tracker's come from the graph's block
            assert f.name not in sp.params, f"{name}.yaml sets {sp.name}.{f.name} per stage"
            # and the built-in graph runs the default: it names only what differs from the dataclass
            assert plan.stage_params(sp.name)[f.name] == msgspec.to_builtins(f.default), f"{name}.yaml sets {f.name}"
    assert plan.tracker is not None and plan.tracker.name == name


@pytest.mark.parametrize("cls, graph, bad", [(GFlowParams, "gflow", {"pyramid_levels": 9}),
                                             (AppearanceParams, "appearance", {"n_scales": 2})])
def test_a_stage_refuses_what_the_dataclass_refuses_with_its_message(cls, graph, bad) -> None:
    from pipeline.runtime.graph import GraphError

    with pytest.raises(ValueError) as core:
        cls(**bad)
    with pytest.raises(GraphError) as refused:
        load_graph(graph, overrides={"tracker": bad})
    assert str(core.value) in str(refused.value)
    for stage in ("proposal", "filter"):  # named for one stage: refused, naming the block's parameter
        with pytest.raises(GraphError, match=f"set tracker.{next(iter(bad))}"):
            load_graph(graph, overrides={stage: bad})


def test_the_command_lines_options_show_the_dataclass_help_and_default() -> None:
    help_text = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "track", "--help"], capture_output=True,
                                     text=True, env={"COLUMNS": "400", "PATH": ""}).stdout
    flat = " ".join(help_text.split())
    n = 0
    for cls in WITH_PARAMS.values():
        for info in describe(cls):
            if info.option:
                assert f"{info.option} " in flat
                assert f"{info.help} (default {format_value(info.default)}" in flat, info.name
                n += 1
    assert n >= 4


@pytest.mark.parametrize("name", sorted(WITH_PARAMS))
def test_gflow_info_lists_every_parameter_with_its_default(name) -> None:
    from pipeline.cli.main import main

    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["info", name, "--json"]) == 0
    d = json.loads(out.getvalue())
    assert [(r["name"], r["default"], r["help"]) for r in d["parameters"]] == \
        [(i.name, format_value(i.default), i.help) for i in describe(WITH_PARAMS[name])]
    assert {s["stage"] for s in d["stages"]} >= {"proposal", "filter"}


def test_every_parameter_has_help() -> None:
    for cls in WITH_PARAMS.values():
        for info in describe(cls):
            assert len(info.help) > 10, f"{cls.__name__}.{info.name} has no help"


def test_the_api_takes_the_dataclass_parameters() -> None:
    from gflow import Tracker

    t = Tracker("gflow", n_experts=7, psi_v=2e-3)
    assert t.params == dataclasses.replace(GFlowParams(), n_experts=7, psi_v=2e-3)
    assert Tracker("gflow").params == GFlowParams()
    assert Tracker("appearance", lam=20.0).params == dataclasses.replace(AppearanceParams(), lam=20.0)
    assert Tracker("appearance").params == AppearanceParams()


@pytest.mark.parametrize("impl", [GFlowTracker, AppearanceTracker])
def test_the_trackers_implement_the_tracker_protocol(impl) -> None:
    names = [n for n in dir(TrackingFilter) if not n.startswith("_")]
    assert set(names) >= {"observe", "init", "propose", "update", "coast"}
    for n in names:
        assert hasattr(impl, n), n


def test_the_command_line_reads_the_parameters_without_importing_the_mathematics() -> None:
    """Every gflow command builds gflow track's options from the parameter dataclasses: that must not
    import the trackers' mathematics (scipy, the G-flow filter), which would slow every start (about 0.3 s)."""
    code = ("import sys; from pipeline.cli.commands.track import add_track_args; import argparse; "
            "add_track_args(argparse.ArgumentParser()); "
            "print(sorted(m for m in ('gflow_core.gflow.filter', 'gflow_core.appearance.filter', 'scipy') if m in sys.modules))")
    out = cli_fork.run_command([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


@pytest.mark.parametrize("name", ["dcf", "appearance"])
def test_set_tracker_param_changes_what_every_stage_of_the_tracker_uses(name) -> None:
    """``--set tracker.particles=N`` is one value in the graph's tracker block; every stage of the
    tracker is built with it (the proposal's and the filter's parameter dataclass alike), and the
    recording's plan holds the block once and rebuilds the same stages from it."""
    from pipeline.runtime.build import make_stage
    from pipeline.runtime.graph import Plan

    box = {"init": [10.0, 10.0, 20.0, 20.0]}
    plan = load_graph(name, overrides={"tracker": {"particles": 77}, "proposal": box, "filter": box})
    cores = {s: make_stage(plan, s).core for s in ("proposal", "filter")}
    assert {s: c.particles for s, c in cores.items()} == {"proposal": 77, "filter": 77}
    assert cores["proposal"] == cores["filter"] == dataclasses.replace(WITH_PARAMS[name](), particles=77)
    meta = plan.config_metadata()
    assert json.loads(meta["tracker"])["params"]["particles"] == 77
    assert all("particles" not in json.loads(v)["params"] for k, v in meta.items() if k.startswith("stage."))
    again = Plan.from_metadata({}, meta)
    assert make_stage(again, "proposal").core == cores["proposal"]


def test_a_parameter_added_later_is_read_from_an_older_plan_as_the_code_before_it_behaved() -> None:
    """A recorded plan that lacks a parameter added since (``param(before=...)``: dcf's
    ``colour_outlier``, 0.01 by default, 0 before it existed) is read at the value the code had before
    it, in the tracker block and in a plan recorded before the block, so the recording re-runs bit
    for bit; a plan that names it keeps its value, and a new graph takes today's default."""
    from gflow_core.dcf.params import DCFParams
    from gflow_core.params import added_later
    from pipeline.runtime.build import make_stage
    from pipeline.runtime.graph import Plan

    assert added_later(DCFParams) == {"colour_outlier": 0.0, "search_min": 3, "search_colour_outlier": 0.0,
                                      "redetect_speed": False, "confirm": 0, "confirm_flow": False,
                                      "roll_step": 0.0, "roll_explain": 0.0, "roll_relax": 0.0,
                                      "search_size_volume": False, "search_track": 0.0,
                                      "search_track_wald": False, "scale_upsample": False, "roll_detect": False,
                                      "colour_names": False}
    assert (DCFParams().colour_outlier, DCFParams().search_min) == (0.01, 10)
    box = {"init": [10.0, 10.0, 20.0, 20.0]}
    plan = load_graph("dcf", overrides={"proposal": box, "filter": box})
    assert plan.tracker is not None and plan.tracker.params["colour_outlier"] == 0.01
    meta = plan.config_metadata()
    assert Plan.from_metadata({}, meta).tracker.params["colour_outlier"] == 0.01  # named: kept
    block = json.loads(meta["tracker"])
    del block["params"]["colour_outlier"]
    old = Plan.from_metadata({}, {**meta, "tracker": json.dumps(block)})
    assert old.tracker.params["colour_outlier"] == 0.0
    assert make_stage(old, "filter").core.colour_outlier == 0.0
    # before the block: each stage of the tracker held every value
    per_stage = {k: v for k, v in meta.items() if k != "tracker"}
    for k, v in meta.items():
        if k.startswith("stage.") and json.loads(v)["kind"].startswith("dcf."):
            d = json.loads(v)
            d["params"] = {**{n: x for n, x in block["params"].items()}, **d["params"]}
            per_stage[k] = json.dumps(d)
    old = Plan.from_metadata({}, per_stage)
    assert old.tracker is None
    assert {n: s.params["colour_outlier"] for n, s in old.stages.items() if s.kind.startswith("dcf.")} == \
        {"proposal": 0.0, "filter": 0.0}


def test_a_graph_without_a_tracker_block_keeps_its_per_stage_values() -> None:
    """Graph files (and recordings' plans) written before the block name the parameters per stage:
    they are read as they are, and ``tracker`` overrides set every stage of the tracker."""
    from pipeline.runtime.build import make_stage
    from pipeline.runtime.graph import GRAPHS_DIR, parse_graph

    text = (GRAPHS_DIR / "dcf.yaml").read_text().replace("\ntracker: dcf", "\n#")
    text = text.replace("params: {seed: 0}", "params: {seed: 0, particles: 55}")
    box = {"init": [10.0, 10.0, 20.0, 20.0]}
    plan = parse_graph(text, "old.yaml", overrides={"proposal": box, "filter": dict(box, particles=44)})
    assert plan.tracker is None
    assert make_stage(plan, "proposal").core.particles == 55 and make_stage(plan, "filter").core.particles == 44
    plan = parse_graph(text, "old.yaml", overrides={"tracker": {"particles": 33}, "proposal": box, "filter": box})
    assert make_stage(plan, "proposal").core.particles == make_stage(plan, "filter").core.particles == 33


@pytest.mark.parametrize("name,value,says", [
    ("particles", "nan", "particles must be a whole number, got 'nan'"),
    ("particles", 1.5, "particles must be a whole number, got 1.5"),
    ("refine_position", "maybe", "refine_position must be true or false, got 'maybe'"),
])
def test_a_tracker_value_of_the_wrong_type_is_named_in_plain_words(name, value, says) -> None:
    from pipeline.runtime.tracker_block import block_values

    with pytest.raises(ValueError) as e:
        block_values(AppearanceParams, {name: value})
    assert str(e.value) == says


def test_the_generic_proposal_takes_the_random_walk_of_chamfer_params_alone() -> None:
    """particle.proposal (the demo's, graphs of your own) declares no standard deviation of its own: its
    random walk's fields, defaults and checks are ChamferParams', and it takes no other ChamferParams field."""
    from gflow_core.contour.params import ChamferParams
    from gflow_core.params import defaults
    from stages.particle_proposal import ProposalFields, ProposalParams
    from gflow_msgs.params import stage_params, tracker_of

    walk = ("std_xy", "std_theta", "std_log_s")
    p = ProposalParams()
    assert {k: getattr(p, k) for k in walk} == {k: defaults(ChamferParams)[k] for k in walk}
    assert tracker_of(ProposalParams) is None  # no stage of a tracker: a graph's tracker block does not feed it
    with pytest.raises(ValueError, match="std_xy, std_theta and std_log_s must be finite and >= 0"):
        msgspec.convert({"std_theta": -0.1}, ProposalParams)
    with pytest.raises(msgspec.ValidationError, match="unknown field `lam`"):
        msgspec.convert({"lam": 0.3}, ProposalParams)
    with pytest.raises(TypeError, match="has no field"):
        stage_params("Bad", ChamferParams, ProposalFields, __name__, only=("std_xy", "std_z"))


def test_gflow_settings_made_default_later_are_read_from_an_older_plan_as_they_were() -> None:
    """G-flow's local background and its size walk, on by default since they were measured, were off in
    every recording made before they existed: a recorded gflow plan that lacks them is read with both
    off, so it re-runs bit for bit, while a new graph takes today's defaults."""
    from gflow_core.gflow.params import GFlowParams
    from gflow_core.params import added_later
    from pipeline.runtime.graph import Plan

    assert {"local_background": 0.0, "scale_walk": 0.0}.items() <= added_later(GFlowParams).items()
    plan = load_graph("gflow", overrides={"proposal": {"init": [10.0, 10.0, 20.0, 20.0]},
                                          "filter": {"init": [10.0, 10.0, 20.0, 20.0]}})
    assert plan.tracker is not None
    assert (plan.tracker.params["local_background"], plan.tracker.params["scale_walk"]) == (5.0, 0.01)
    meta = plan.config_metadata()
    block = json.loads(meta["tracker"])
    for name in ("local_background", "scale_walk"):
        del block["params"][name]
    old = Plan.from_metadata({}, {**meta, "tracker": json.dumps(block)})
    assert (old.tracker.params["local_background"], old.tracker.params["scale_walk"]) == (0.0, 0.0)


def test_a_value_is_refused_past_the_memory_it_declares() -> None:
    """A parameter that sizes the run's arrays declares their memory (gflow_core.params.Memory); a value needing
    more than the memory at hand is refused naming the largest value that fits, which itself passes. The memory
    is given here, so nothing depends on this machine's."""
    import math

    from gflow_core.dcf.params import DCFParams
    from gflow_core.params import Memory, check_memory

    assert Memory(100.0, "particle").most(1e6) == 10000 and Memory(400.0, "pixel", power=2).most(1.6e9) == 2000
    assert Memory(100.0, "particle").most(123456789.0) == 1200000  # two figures, rounded down
    assert Memory(360.0, "template pixel", power=2).need(10**400) == math.inf
    check_memory(DCFParams())  # the defaults fit this machine
    have = 150 ** 2 * 360 - 1.0  # one byte short of the default template's
    with pytest.raises(ValueError) as e:
        check_memory(DCFParams(), have)
    assert str(e.value) == ("template must be at most 140 on this machine (about 360 bytes a template pixel, "
                            "template^2 of them; it has 8.1 MB of memory), got 150")
    check_memory(DCFParams(template=140), have)
    check_memory(DCFParams(particles=2_200_000), 1e9)
    with pytest.raises(ValueError, match=r"^particles must be at most 2200000 on this machine .* got 3000000$"):
        check_memory(DCFParams(particles=3_000_000), 1e9)


def test_a_product_of_two_parameters_is_said_of_the_one_made_large() -> None:
    """G-flow's memory is a pose sample's times n_experts x n_samples: a value too large is said of the parameter
    furthest above its default, with the bound holding the other at its value."""
    from gflow_core.params import check_memory

    have = 20 * 10 * 22_000 * 100.0  # a hundred times the defaults' pose samples
    check_memory(GFlowParams(), have)
    with pytest.raises(ValueError, match=r"^n_experts must be at most 2000 on this machine \(about 22000 bytes a pose "
                                         r"sample, n_experts x n_samples of them; .* got 5000$"):
        check_memory(GFlowParams(n_experts=5000), have)
    with pytest.raises(ValueError, match=r"^n_samples must be at most 1000 .* got 5000$"):
        check_memory(GFlowParams(n_samples=5000), have)
    with pytest.raises(ValueError, match=r"^n_experts must be at most 1000 .* got 5000$"):
        check_memory(GFlowParams(n_experts=5000, n_samples=20), have)


@pytest.mark.parametrize("name", sorted(WITH_PARAMS) + ["m2 patch"])
def test_what_sizes_every_trackers_arrays_declares_its_memory(name) -> None:
    """What sizes a run's arrays is bounded by the machine's memory for every tracker: its particles (or G-flow's
    experts and their pose samples)."""
    from gflow_core.m2.patch_params import PatchParams

    cls = PatchParams if name == "m2 patch" else WITH_PARAMS[name]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    sized = [n for n in ("particles", "n_experts", "n_samples") if n in fields]
    assert sized and all(fields[n].metadata.get("memory") is not None for n in sized), name
