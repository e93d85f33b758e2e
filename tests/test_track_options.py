"""``gflow track``'s options as a user types them: a value no tracker can run with, an output in a
folder that does not exist, and the default seed. Each mistake is one line naming the option,
found before anything runs; the CLI runs as a subprocess on tiny image folders in tmp_path.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from test_cli_errors import assert_one_line_error, frames, gflow  # noqa: F401  (frames: a fixture)


def one_line_error(r) -> str:
    return assert_one_line_error(r)


@pytest.mark.parametrize("tracker, extra", [("appearance", []), ("chamfer", []), ("m2", ["--model", "m.npz"])])
@pytest.mark.parametrize("value", ["0", "-5"])
def test_particles_below_one_is_one_line_for_every_tracker(tmp_path: Path, frames: Path, tracker: str,
                                                           extra: list[str], value: str) -> None:
    """--particles 0: one line naming the option and the value, not the graph file's path nor the
    stage's parameter names; chamfer and m2 do not run with their default instead."""
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--tracker", tracker,
              "--particles", value, *extra, "--inline", cwd=tmp_path)
    line = one_line_error(r)
    assert "--particles" in line and value in line, line
    assert ".yaml" not in line and "known parameters" not in line and "lam" not in line, line
    assert not (tmp_path / "b.csv").exists() and not list(tmp_path.rglob("*.mcap"))


@pytest.mark.parametrize("argv, said", [
    (["demo", "--particles", "0", "--frames", "3", "--inline"], "--particles 0"),
    (["track", "FRAMES", "--init", "10,10,20,20", "--out", "b.csv", "--tracker", "chamfer", "--set", "tracker.particles=0",
      "--inline"], "--set tracker.particles=0"),
])
def test_particles_below_one_from_demo_or_set_is_the_same_line(tmp_path: Path, frames: Path, argv: list[str],
                                                               said: str) -> None:
    """``gflow demo --particles 0`` and ``--set tracker.particles=0`` say what ``gflow track --particles 0``
    says, naming the option as given, not the graph file's path nor the stage kind."""
    r = gflow(*[str(frames) if a == "FRAMES" else a for a in argv], cwd=tmp_path)
    line = one_line_error(r)
    assert f"{said}: particles must be >= 1, got 0" in line, line
    assert ".yaml" not in line and "stage kind" not in line, line
    assert not (tmp_path / "b.csv").exists() and not list(tmp_path.rglob("*.mcap"))


@pytest.mark.parametrize("item, said", [
    ("tracker.nope=1", "DCFParams has no parameter 'nope'"),
    ("tracker.particle=10", "DCFParams has no parameter 'particle' (did you mean 'particles'?"),
    ("filter.particles=300", "particles is a parameter of tracker dcf, set once for all its stages: "
                             "--set tracker.particles=VALUE"),
    ("proposal.std_xy_rel=0.1", "--set tracker.std_xy_rel=VALUE"),
])
def test_a_tracker_parameter_is_set_once_as_tracker_param(tmp_path: Path, frames: Path, item: str, said: str) -> None:
    """A mistyped ``--set tracker.NAME`` and a tracker parameter given to one stage are one line naming
    what was given (the stages can never disagree), before anything runs."""
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--set", item, "--inline", cwd=tmp_path)
    line = one_line_error(r)
    assert f"--set {item}: " in line and said in line, line
    assert not (tmp_path / "b.csv").exists() and not list(tmp_path.rglob("*.mcap"))


@pytest.mark.parametrize("items, named, said", [
    (["online_mix=2"], "--gflow-set online_mix=2", "online_mix must be in [0, 1]"),
    (["online_mix=abc"], "--gflow-set online_mix=abc", "online_mix must be a number"),
    (["online_mix=0.3", "background=true"], "--gflow-set online_mix=0.3 --gflow-set background=true",
     "online_mix needs background off"),
])
def test_a_bad_gflow_set_is_named_as_typed(tmp_path: Path, frames: Path, items: list[str], named: str,
                                           said: str) -> None:
    """A G-flow value out of range, of the wrong kind or at odds with another is refused naming the
    ``--gflow-set`` options as typed, not the graph file (``gflow.yaml:26: tracker gflow``) it lands in."""
    sets = [a for it in items for a in ("--gflow-set", it)]
    r = gflow("track", str(frames), "--tracker", "gflow", "--init", "10,10,20,20", "--out", "b.csv", *sets, "--inline",
              cwd=tmp_path)
    line = one_line_error(r)
    assert line.startswith(f"gflow track: error: {named}: ") and said in line and ".yaml" not in line, line
    assert not (tmp_path / "b.csv").exists() and not list(tmp_path.rglob("*.mcap"))


@pytest.mark.parametrize("opt, name", [("--out", "x.csv"), ("--record", "r.mcap"), ("--points-out", "p.csv")])
def test_output_in_a_missing_folder_is_refused(tmp_path: Path, frames: Path, opt: str, name: str) -> None:
    """A mistyped folder is one line naming the option and the folder; no folder is created."""
    missing = tmp_path / "nonexistent_dir"
    args = {"--out": ["--out", str(missing / name)], "--record": ["--out", "b.csv", "--record", str(missing / name)],
            "--points-out": ["--out", "b.csv", "--tracker", "gflow", "--points-out", str(missing / name)]}[opt]
    r = gflow("track", str(frames), "--init", "10,10,20,20", *args, cwd=tmp_path)
    line = one_line_error(r)
    assert opt in line and str(missing) in line and "does not exist" in line, line
    assert not missing.exists()
    assert not (tmp_path / "b.csv").exists()


def test_default_recording_folder_is_still_made(tmp_path: Path, frames: Path) -> None:
    """The default recordings/ folder is the program's own: it is made when missing."""
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--inline", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "recordings").glob("*.mcap"))) == 1


def test_track_defaults_to_seed_one(tmp_path: Path, caviar1: Path) -> None:
    """gflow track without --seed gives the boxes of --seed 1, the seed of the README, gflow benchmark
    and the docs' figures (and the Python API's default)."""
    rows = {}
    for name, extra in (("default", []), ("one", ["--seed", "1"]), ("zero", ["--seed", "0"])):
        r = gflow("track", str(caviar1), "--init", "129,71,30,79", "--stop", "10", "--out", f"{name}.csv", "--inline",
                  "--no-record", "-q", *extra, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        rows[name] = (tmp_path / f"{name}.csv").read_text()
    assert rows["zero"] != rows["one"], "the seed must matter for this test to tell them apart"
    assert rows["default"] == rows["one"]
    from gflow import Tracker
    from gflow.track import track
    import inspect

    assert Tracker().seed == 1
    assert inspect.signature(track).parameters["seed"].default == 1
