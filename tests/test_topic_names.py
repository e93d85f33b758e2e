"""Topic names as a user types them: every command that takes topics accepts the name in the
stream, the full name with or without the run id, and wildcards; a name that matches nothing is
an error listing the topics there are (pipeline/recording/topics.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.cli.main import main
from pipeline.io.mcap_io import iter_records
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.inline import run_inline
from pipeline.runtime.runid import choose_stream

HELD = ["gflow/demo-43159e/estimate", "gflow/demo-43159e/frames", "gflow/demo-43159e/_status/filter",
        "gflow/demo-43159e/_snapshot/filter"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path]:
    """A demo recording whose topics carry a run id, and its graph re-run with another filter seed."""
    tmp = tmp_path_factory.mktemp("topics")
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 10}, "filter": {"particles": 100}}))
    choose_stream(plan, None, placed=False)  # gflow/demo-xxxxxx/...
    md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
          "gflow.config": plan.config_metadata()}
    run_inline(plan, recording=str(tmp / "run.mcap"), metadata=md)
    assert main(["rerun", str(tmp / "run.mcap"), "--graph", "--set", "filter.seed=3", "--out",
                 str(tmp / "seed3.mcap")]) == 0
    return tmp / "run.mcap", tmp / "seed3.mcap"


@pytest.mark.parametrize("pattern, want", [
    ("estimate", ["gflow/demo-43159e/estimate"]),
    ("gflow/demo/estimate", ["gflow/demo-43159e/estimate"]),
    ("gflow/demo-43159e/estimate", ["gflow/demo-43159e/estimate"]),
    ("demo/frames", ["gflow/demo-43159e/frames"]),
    ("_status/*", ["gflow/demo-43159e/_status/filter"]),
    ("gflow/*/est*", ["gflow/demo-43159e/estimate"]),
    ("estimate,frames", ["gflow/demo-43159e/estimate", "gflow/demo-43159e/frames"]),
    ("*", sorted(HELD)),
])
def test_the_forms_a_user_types(pattern: str, want: list[str]) -> None:
    from pipeline.recording.topics import select_topics

    assert select_topics([pattern], HELD) == want


def test_a_name_that_matches_nothing_lists_the_topics() -> None:
    from pipeline.recording.topics import TopicError, select_topics, topic_matches

    assert not topic_matches("gflow/cam0/estimate", "gflow/demo-43159e/estimate")
    assert not topic_matches("gflow/demo-4/estimate", "gflow/demo-43159e/estimate")  # a run id is whole
    with pytest.raises(TopicError) as e:
        select_topics(["gflow/cam0/frames"], HELD, where="run.mcap")
    assert "gflow/cam0/frames" in str(e.value) and "estimate" in str(e.value) and "run.mcap" in str(e.value)


def test_diff_with_a_topic_named_without_the_run_id_finds_the_differences(runs, capsys) -> None:
    a, b = runs
    assert main(["diff", str(a), str(b), "--topics", "gflow/demo/estimate", "--frames"]) == 1
    out = capsys.readouterr().out
    assert "the recordings differ" in out and "/estimate" in out
    assert main(["diff", str(a), str(b), "--topics", "estimate"]) == 1
    capsys.readouterr()
    assert main(["diff", str(a), str(b), "--topics", "gflow/cam0/estimate"]) == 2
    err = capsys.readouterr().err
    assert "no topic" in err and "estimate" in err and "frames" in err and len(err.strip().splitlines()) == 1


def test_replay_takes_the_names_of_its_help(runs, capsys) -> None:
    a, _ = runs
    frames = sum(1 for r in iter_records(a) if r.topic.endswith("/frames"))
    assert main(["replay", str(a), "--topics", "gflow/demo/frames", "--max"]) == 0
    assert f"replayed {frames} messages" in capsys.readouterr().err
    assert main(["replay", str(a), "--topics", "gflow/cam0/frames", "--max"]) == 2
    err = capsys.readouterr().err
    assert "no topic" in err and "frames" in err and "replaying" not in err  # refused before joining


def test_rerun_step_and_foxglove_take_topics(runs, tmp_path: Path, capsys, monkeypatch) -> None:
    import io

    a, _ = runs
    assert main(["rerun", str(a), "--stage", "filter", "--check", "--topics", "estimate"]) == 0
    out = capsys.readouterr().out
    n_est = sum(1 for r in iter_records(a) if r.topic.endswith("/estimate"))
    assert f"{n_est} outputs compared, all identical" in out
    assert main(["rerun", str(a), "--stage", "filter", "--check", "--topics", "estimat"]) == 2
    assert "no topic" in capsys.readouterr().err
    monkeypatch.setattr("sys.stdin", io.StringIO("n\nq\n"))
    assert main(["step", str(a), "--stage", "filter", "--topics", "gflow/demo/estimate"]) == 0
    out = capsys.readouterr().out
    assert "  estimate   Estimate" in out and "  particles  Particles" not in out
    assert main(["foxglove", str(a), str(tmp_path / "f.mcap"), "--topics", "frames", "estimate"]) == 0
    out = capsys.readouterr().out
    assert "frames 10" in out and "estimate 10" in out and "features" not in out


def _demo_with_a_run_id(path: Path, seed: int) -> Path:
    """A short demo recorded as a multi-process run records it: its stream carries a new run id."""
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 12}, "filter": {"particles": 50, "seed": seed},
                                                        "proposal": {"seed": seed}}))
    choose_stream(plan, None, placed=False)
    md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
          "gflow.config": plan.config_metadata()}
    run_inline(plan, recording=str(path), metadata=md)
    return path


def test_diff_pairs_two_runs_of_one_graph_across_their_run_ids(tmp_path: Path, capsys) -> None:
    a, b, c = (_demo_with_a_run_id(tmp_path / f"{n}.mcap", s) for n, s in (("a", 1), ("b", 2), ("c", 1)))
    assert {r.topic.split("/")[1] for r in iter_records(a)} != {r.topic.split("/")[1] for r in iter_records(c)}
    assert main(["diff", str(a), str(b), "--frames"]) == 1
    out = capsys.readouterr().out
    assert out.count("paired across run ids") == 1 and "gflow/demo/estimate" in out, out
    row = next(line.split() for line in out.splitlines() if line.startswith("gflow/demo/estimate "))
    same, differ, only_a, only_b = map(int, row[2:6])
    assert differ > 0 and only_a == 0 and only_b == 0 and same + differ == 13, row
    table = out[out.index("pose max|diff|"):].splitlines()[1:13]
    assert [int(line.split()[0]) for line in table] == list(range(12)), out  # one row per frame
    assert main(["diff", str(a), str(c)]) == 0
    out = capsys.readouterr().out
    assert "paired across run ids" in out and out.rstrip().endswith("identical"), out
