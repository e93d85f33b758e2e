"""gflow track / gflow info / the run report with m2 and a patch model (AVLetters mouths, M2 sec. 5.2):
the options of :class:`gflow_core.m2.patch_params.PatchParams`, the model-kind check, and the blank
frames said by the patch tracker's own rule (``blank_std``), not the contour trackers' (``min_edges``)."""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from gflow_core.m2.patch_params import PatchParams
from gflow_core.params import describe
from pipeline.cli.commands.common import CliError
from pipeline.cli.main import main
from pipeline.io.mcap_io import iter_records
from gflow_msgs.messages import Estimate, decode


@pytest.fixture(scope="module")
def mouths(tmp_path_factory) -> tuple[Path, Path]:
    """(a whole-frame shuffle model learned from anya's reps 1-2 of A-C, rep 3's frames as a folder)."""
    from conftest import data_dir
    from pipeline.io.datasets import read_avletters, write_frames

    src = data_dir("avletters") / "anya.npz"
    if not src.is_file():
        pytest.skip(f"real data not available: {src} is missing")
    tmp = tmp_path_factory.mktemp("mouths")
    model = tmp / "mouth.npz"
    assert main(["learn", "m2", str(src), "--reps", "1,2", "--letters", "A-C", "--metric", "shuffle", "-K", "6",
                 "--patch-size", "20x15", "--out", str(model), "-q"]) == 0
    test, _ = read_avletters(src, [3], "A-C")
    return model, write_frames(tmp / "rep3", test.frames)


def _coasted(recording: Path) -> set[int]:
    return {r.seq for r in iter_records(recording) if r.type == "Estimate"
            and isinstance(m := decode(r.data), Estimate) and m.state == "coast"}


@pytest.mark.data
def test_a_patch_models_blank_frames_are_said_by_its_grey_level_rule(mouths, tmp_path, capsys) -> None:
    """Blanked frames (every tenth frame twice) coast with a patch model because their grey levels'
    spread is below blank_std (set with --blank-std); gflow track's report and gflow boxes of its
    recording say so, with the value, and name no edge count."""
    model, frames = mouths
    rec = tmp_path / "run.mcap"
    assert main(["track", str(frames), "--tracker", "m2", "--model", str(model), "--init", "0,0,80,60",
                 "--particles", "100", "--blank-std", "2.5", "--set", "source.blank_every=10", "--set",
                 "source.blank_count=2", "--stop", "40", "--inline", "--out", str(tmp_path / "b.csv"), "--record",
                 str(rec)]) == 0
    blank = {8, 9, 18, 19, 28, 29, 38, 39}
    assert _coasted(rec) == blank
    assert main(["boxes", str(rec), "--out", str(tmp_path / "again.csv")]) == 0
    out = capsys.readouterr().out
    said = [ln.strip() for ln in out.splitlines() if "held no evidence" in ln]
    assert len(said) == 2, out  # the run's report, and gflow boxes'
    for ln in said:
        assert ln == ("8 frame(s) coasted on the dynamics: the frame was read but held no evidence (a grey-level "
                      "standard deviation below the tracker's blank_std 2.5: a blank frame): 8-9, 18-19, 28-29, 38-39")
    assert "min_edges" not in out and "edge pixels" not in out


@pytest.mark.data
def test_set_tracker_reaches_the_patch_filter(mouths, tmp_path, capsys) -> None:
    """`--set tracker.blank_std=3` (the graph's tracker block, PatchParams) reaches the patch filter: the
    recorded plan's filter is built with it, and a naming of it for the filter alone is refused."""
    from pipeline.recording.rerun import recorded_plan

    model, frames = mouths
    rec = tmp_path / "run.mcap"
    common = ["track", str(frames), "--tracker", "m2", "--model", str(model), "--init", "0,0,80,60", "--particles",
              "50", "--stop", "5", "--inline"]
    assert main([*common, "--out", str(tmp_path / "b.csv"), "--set", "tracker.blank_std=3", "--record", str(rec)]) == 0
    plan = recorded_plan(rec)
    assert plan.tracker is not None and plan.tracker.name == "m2"
    assert plan.tracker.params == {"crop": "frame", "particles": 50, "blank_std": 3.0}
    assert plan.stage_params("filter")["blank_std"] == 3.0 and "blank_std" not in plan.stages["filter"].params
    capsys.readouterr()
    assert main([*common, "--out", str(tmp_path / "b2.csv"), "--set", "filter.blank_std=3", "--no-record"]) == 2
    assert capsys.readouterr().err.strip() == ("gflow track: error: --set filter.blank_std=3: blank_std is a parameter "
                                               "of tracker m2, set once for all its stages: --set tracker.blank_std=VALUE")


@pytest.mark.data
def test_a_plan_without_the_tracker_block_still_runs_and_reruns(mouths, tmp_path) -> None:
    """The m2_patch graph as it was before its tracker block (PatchParams' values in the filter stage): it
    loads, gflow track's values (and --set tracker.NAME) reach the filter, and its recording, whose plan
    names them per stage as recordings made before do, re-runs bit for bit."""
    from pipeline.recording.results import blank_rule
    from pipeline.recording.rerun import recorded_plan

    text = (Path(__file__).resolve().parent.parent / "pipeline" / "graphs" / "m2_patch.yaml").read_text()
    old = tmp_path / "old.yaml"
    head, filt = text.replace("\ntracker: m2", "\n#").split("kind: patch.filter")
    old.write_text(head + "kind: patch.filter" + filt.replace('params: {seed: 0, model: "model.npz"}',
                                                              'params: {particles: 500, seed: 0, model: "model.npz", '
                                                              'crop: frame}'))
    model, frames = mouths
    rec = tmp_path / "old.mcap"
    assert main(["track", str(frames), "--tracker", "m2", "--model", str(model), "--init", "0,0,80,60", "--graph",
                 str(old), "--particles", "50", "--set", "tracker.blank_std=2.5", "--stop", "12", "--inline", "--out",
                 str(tmp_path / "b.csv"), "--record", str(rec), "-q"]) == 0
    plan = recorded_plan(rec)
    assert plan.tracker is None and {k: plan.stages["filter"].params[k] for k in ("particles", "blank_std")} == \
        {"particles": 50, "blank_std": 2.5}
    assert "blank_std 2.5" in blank_rule(plan)
    assert main(["rerun", str(rec), "--graph", "--check"]) == 0


def test_the_blank_rule_is_the_trackers_own() -> None:
    from pipeline.recording.results import blank_rule
    from pipeline.runtime.graph import load_graph

    assert "fewer edge pixels than the tracker's min_edges 1" in blank_rule(load_graph("m2"))
    assert "fewer edge pixels than the tracker's min_edges 3" in blank_rule(
        load_graph("chamfer", overrides={"tracker": {"min_edges": 3}}))
    patch = blank_rule(load_graph("m2_patch", overrides={"tracker": {"blank_std": 0.5}}))
    assert "blank_std 0.5" in patch and "edge" not in patch
    assert blank_rule(None) == "a blank frame"


def _track_args(*argv: str) -> argparse.Namespace:
    from pipeline.cli.commands.track import track_args

    return track_args(["src", "--init", "0,0,80,60", "--out", "b.csv", "--tracker", "m2", *argv])


@pytest.mark.data
def test_patch_params_options_reach_the_filter(mouths) -> None:
    """--crop, --blank-std and --particles become the patch filter's parameters (the crop the model's own
    unless given); the options are derived from PatchParams with its help and default."""
    from pipeline.cli.trackers.m2 import overrides

    model, _ = mouths
    from pipeline.runtime.graph import load_graph

    graph, over = overrides(_track_args("--model", str(model)))
    assert graph == "m2_patch" and over["tracker"] == dataclasses.asdict(PatchParams())
    graph, over = overrides(_track_args("--model", str(model), "--crop", "box", "--blank-std", "4", "--particles", "9"))
    assert over["tracker"] == {"crop": "box", "particles": 9, "blank_std": 4.0}
    # the graph's tracker block holds them, and the filter is built with them (naming none itself)
    plan = load_graph(graph, overrides=over)
    assert plan.tracker is not None and plan.tracker.params == over["tracker"]
    assert {k: plan.stage_params("filter")[k] for k in over["tracker"]} == over["tracker"]
    assert not set(plan.stages["filter"].params) & set(over["tracker"])
    from gflow_core.params import format_value

    p = argparse.ArgumentParser()
    from pipeline.cli.commands.track import add_track_args

    add_track_args(p)
    flat = " ".join(p.format_help().split())
    declared = [i for i in describe(PatchParams) if i.option]
    assert [i.option for i in declared] == ["--crop", "--blank-std"]
    for i in declared:
        assert f"{i.option} " in flat and f"{i.help} (default {format_value(i.default)}" in flat


@pytest.mark.data
def test_an_option_of_the_other_kind_of_model_is_one_line_before_anything_starts(mouths, caviar1_m2_model,
                                                                                 tmp_path, capsys) -> None:
    """--crop with a contour model, and a bad value of a patch option, are refused in one line naming the
    option and the model, with no recording and no boxes written."""
    model, frames = mouths
    cases = [(["--model", str(caviar1_m2_model), "--crop", "box"],
              f"--crop is an option of --tracker m2 with a patch model; {caviar1_m2_model} holds a contour model"),
             (["--model", str(model), "--crop", "middle"], "--crop middle: crop must be frame or box, got 'middle'"),
             (["--model", str(model), "--blank-std", "-1"], "--blank-std -1.0: blank_std must be >= 0, got -1.0")]
    for argv, said in cases:
        out = tmp_path / "b.csv"
        code = main(["track", str(frames), "--tracker", "m2", "--init", "0,0,80,60", *argv, "--out", str(out),
                     "--inline", "--record", str(tmp_path / "r.mcap")])
        err = capsys.readouterr().err.strip()
        assert code == 2 and err == f"gflow track: error: {said}", err
        assert not out.exists() and not (tmp_path / "r.mcap").exists()
    code = main(["track", str(frames), "--tracker", "dcf", "--init", "0,0,80,60", "--blank-std", "2", "--out",
                 str(tmp_path / "b.csv"), "--inline", "--no-record"])
    assert code == 2 and "--blank-std is an option of --tracker m2, not of --tracker dcf" in capsys.readouterr().err


def test_a_contour_option_with_a_patch_model_is_refused_too(monkeypatch) -> None:
    """The check runs both ways: an option of the contour kind's dataclass given with a patch model."""
    from pipeline.cli.trackers import m2

    @dataclasses.dataclass(frozen=True)
    class Contour:
        lam: float = dataclasses.field(default=0.5, metadata={"help": "lambda", "option": "--lam"})

    monkeypatch.setitem(m2.KINDS, "curve", m2.ModelKind("contour", Contour, "m2"))
    m2.check_kind(argparse.Namespace(lam=None, crop=None, blank_std=None, particles=None), "patch", Path("p.npz"))
    with pytest.raises(CliError, match=r"^--lam is an option of --tracker m2 with a contour model; p.npz holds a "
                                       r"patch model$"):
        m2.check_kind(argparse.Namespace(lam=0.3, crop=None, blank_std=None, particles=None), "patch", Path("p.npz"))


def test_gflow_info_m2_lists_the_parameters_of_both_kinds_of_model() -> None:
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["info", "m2", "--json"]) == 0
    d = json.loads(out.getvalue())
    assert d["model"] == "contour" and d["parameters_of"] == "gflow_core.contour.params.M2Params"
    (patch,) = d["models"]
    assert (patch["model"], patch["graph"], patch["set_by"]) == ("patch", "m2_patch", [])  # the tracker block's
    assert patch["parameters_of"] == "gflow_core.m2.patch_params.PatchParams"
    assert [(r["name"], r["option"]) for r in patch["parameters"]] == [(i.name, i.option or "")
                                                                       for i in describe(PatchParams)]
    filt = next(s for s in patch["stages"] if s["stage"] == "filter")
    assert {p["name"] for p in filt["params"]} == {"model", "init", "seed"}  # the rest are PatchParams'
    text = io.StringIO()
    with redirect_stdout(text):
        assert main(["info", "m2"]) == 0
    assert "graph:   with a patch model: m2_patch" in text.getvalue()
    assert "gflow_core.m2.patch_params.PatchParams; named once in the graph's tracker block" in text.getvalue()
    assert "--set filter.NAME=VALUE" not in text.getvalue() and "--set tracker.NAME=VALUE" in text.getvalue()


def test_the_m2_patch_block_takes_the_variant_its_filter_is_made_of() -> None:
    """`tracker: m2` in graph m2_patch is PatchParams (the m2 registration's variant the patch filter is
    made of), with no contour edge settings for its preprocess; the block of another tracker is refused."""
    from pipeline.runtime.graph import GraphError, load_graph, parse_graph
    from pipeline.runtime.tracker_block import block_class, is_main_class

    plan = load_graph("m2_patch")
    assert plan.tracker is not None and plan.tracker.params == dataclasses.asdict(PatchParams())
    assert block_class(plan.tracker) is PatchParams and not is_main_class(plan.tracker)
    assert is_main_class(load_graph("m2").tracker)
    text = (Path(__file__).resolve().parent.parent / "pipeline" / "graphs" / "m2_patch.yaml").read_text()
    with pytest.raises(GraphError, match=r"p.yaml:\d+: stage 'filter': a stage of the tracker of PatchParams, but "
                                         r"the graph's tracker block is chamfer's"):
        parse_graph(text.replace("\ntracker: m2", "\ntracker: chamfer"), "p.yaml")
    with pytest.raises(GraphError, match="tracker m2: PatchParams has no parameter 'lam'"):
        load_graph("m2_patch", overrides={"tracker": {"lam": 0.3}})
