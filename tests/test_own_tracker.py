"""A tracker of another package, registered by its entry point alone (docs/own_tracker.md).

The example package ``tests/plugins/gflow_ncc`` is put on a temporary ``sys.path`` entry beside a
``.dist-info`` holding the entry points its ``pyproject.toml`` declares, as ``pip install`` would
leave it: ``importlib.metadata`` finds it there, in this process and in the ``gflow`` processes the
tests start (``PYTHONPATH``). No file of gflow names it.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from conftest import DATA, data_dir

ROOT = Path(__file__).resolve().parent.parent
PLUGIN = ROOT / "tests" / "plugins" / "gflow_ncc"
PAGE = ROOT / "docs" / "own_tracker.md"
GFLOW = [sys.executable, "-m", "pipeline.cli"]


def install(where: Path, name: str, entry_points: dict[str, str], package: Path | None = None) -> Path:
    """``where`` as a site folder holding ``package`` (linked) and a dist-info of ``name`` with the
    entry points ``{tracker: "module:attr"}`` of the group ``gflow.trackers``."""
    where.mkdir(parents=True, exist_ok=True)
    if package is not None:
        (where / package.name).symlink_to(package, target_is_directory=True)
    info = where / f"{name.replace('-', '_')}-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text("[gflow.trackers]\n" + "".join(f"{k} = {v}\n" for k, v in
                                                                          entry_points.items()))
    return where


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The example installed from its pyproject.toml's entry points."""
    meta = tomllib.loads((PLUGIN / "pyproject.toml").read_text())
    eps = meta["project"]["entry-points"]["gflow.trackers"]
    return install(tmp_path_factory.mktemp("site"), meta["project"]["name"], eps, PLUGIN / "gflow_ncc")


def env_with(*paths: Path) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([*map(str, paths), str(ROOT)]))


def gflow(args: list[str], env: dict[str, str], cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(GFLOW + args, env=env, cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def runs(site, tmp_path_factory) -> dict[str, Path]:
    """``gflow track --tracker ncc`` on crossing frames 0-29, as processes and inline."""
    crossing = data_dir("crossing")
    out = tmp_path_factory.mktemp("ncc-runs")
    csvs = {}
    for mode in ("processes", "inline"):
        csvs[mode] = out / f"{mode}.csv"
        r = gflow(["track", str(crossing), "--init", "204,150,17,50", "--tracker", "ncc", "--seed", "1", "--stop", "30",
                   "-q", "--out", str(csvs[mode])] + (["--record", str(out / "ncc.mcap")] if mode == "processes"
                                                     else ["--inline", "--no-record"]),
                  env_with(site), cwd=out)
        assert r.returncode == 0, r.stderr
    return csvs


def test_processes_and_inline_give_the_same_bytes(runs):
    rows = list(csv.reader(runs["processes"].open()))
    assert len(rows) == 31 and rows[0][:5] == ["frame", "x", "y", "w", "h"]
    assert runs["processes"].read_bytes() == runs["inline"].read_bytes()
    # it tracks: the box follows the walker (ground truth of frame 29) within a few pixels
    truth = {int(r[0]): [float(v) for v in r[1:5]] for r in list(csv.reader((DATA / "crossing" / "groundtruth.csv")
                                                                            .open()))[1:]}
    x, y = float(rows[30][1]), float(rows[30][2])
    assert abs(x - truth[29][0]) < 8 and abs(y - truth[29][1]) < 8


def test_a_recording_reruns_from_its_snapshot(runs, site):
    """The filter's snapshots (the spec's to_arrays / from_arrays) restore its state bit for bit."""
    r = gflow(["rerun", str(runs["processes"].parent / "ncc.mcap"), "--stage", "filter", "--from", "28", "--check"],
              env_with(site))
    assert r.returncode == 0 and "from the snapshot at frame" in r.stdout and "identical bit for bit" in r.stdout, \
        r.stdout + r.stderr


def test_python_api_gives_the_cli_boxes(site, runs, monkeypatch):
    import cv2

    import gflow

    monkeypatch.syspath_prepend(str(site))
    assert "ncc" in gflow.tracker.trackers()
    frames = sorted((DATA / "crossing" / "frames").glob("*.jpg"))[:30]
    t = gflow.Tracker("ncc", seed=1)
    ests = [t.init(cv2.imread(str(frames[0])), (204, 150, 17, 50))] + [t.update(cv2.imread(str(f))) for f in frames[1:]]
    rows = list(csv.reader(runs["inline"].open()))[1:]
    assert [[f"{v:.2f}" for v in e.box] + [f"{e.confidence:.3f}", e.target_state] for e in ests] == \
        [r[1:] for r in rows]
    with pytest.raises(gflow.UnknownParameter, match="sharpnes"):
        gflow.Tracker("ncc", sharpnes=3.0)


def test_benchmark_scores_it(site, tmp_path):
    data_dir("crossing")
    r = gflow(["benchmark", str(DATA), "--sequences", "crossing", "--trackers", "ncc", "--frames", "0:30", "--inline",
               "--json", "-q"], env_with(site), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    rows = [row for row in doc["rows"] if row["tracker"] == "ncc"]
    assert len(rows) == 1 and rows[0]["sequence"] == "crossing" and rows[0]["frames"] == 30
    static = [row for row in doc["rows"] if row["tracker"] == "static box"]
    assert rows[0]["auc"] > static[0]["auc"]


def test_info_and_options_come_from_its_dataclass(site, runs, tmp_path):
    env = env_with(site)
    # its option reaches its stages: a flatter likelihood gives other boxes than the default's
    flat = tmp_path / "flat.csv"
    r = gflow(["track", str(DATA / "crossing"), "--init", "204,150,17,50", "--tracker", "ncc", "--seed", "1", "--stop",
               "30", "--inline", "--no-record", "-q", "--ncc-sharpness", "2", "--out", str(flat)], env)
    assert r.returncode == 0, r.stderr
    rows, default = list(csv.reader(flat.open())), list(csv.reader(runs["inline"].open()))
    assert len(rows) == len(default) == 31 and rows[1] == default[1] and rows[30] != default[30]
    r = gflow(["info", "ncc"], env)
    assert r.returncode == 0, r.stderr
    assert re.search(r"sharpness\s+20\.0\s+--ncc-sharpness", r.stdout) and "entry point ncc = gflow_ncc:SPEC" in r.stdout
    r = gflow(["track", "--help"], env)
    assert "--ncc-sharpness" in r.stdout and "ncc" in r.stdout
    # its option with another tracker, and a value its dataclass refuses: one line each, before any work
    r = gflow(["track", "in", "--init", "1,1,5,5", "--out", "x.csv", "--tracker", "dcf", "--ncc-sharpness", "3"], env)
    assert r.returncode == 2 and r.stderr.strip().endswith("--ncc-sharpness is an option of --tracker ncc, not of "
                                                           "--tracker dcf")


def test_mistyped_and_broken_registrations_are_one_line(site, tmp_path, monkeypatch):
    broken = install(tmp_path / "broken", "gflow-broken", {"bad": "gflow_no_such_module:SPEC", "odd": "json:dumps"})
    env = env_with(site, broken)
    for name, says in (("nccc", "unknown tracker 'nccc' (known: appearance, chamfer, dcf, gflow, m2, ncc)"),
                       ("bad", "entry point bad = gflow_no_such_module:SPEC (group gflow.trackers) cannot be "
                               "loaded: ModuleNotFoundError"),
                       ("odd", "entry point odd = json:dumps (group gflow.trackers) is a function, not a "
                               "gflow_core.spec.TrackerSpec")):
        r = gflow(["track", "in", "--init", "1,1,5,5", "--out", "x.csv", "--tracker", name], env, cwd=tmp_path)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and says in r.stderr, r.stderr
    r = gflow(["info", "dcf"], env)  # the others still run
    assert r.returncode == 0 and "tracker dcf" in r.stdout

    import gflow as api

    monkeypatch.syspath_prepend(str(broken))
    monkeypatch.syspath_prepend(str(site))
    with pytest.raises(api.GflowError, match="entry point bad = gflow_no_such_module:SPEC"):
        api.Tracker("bad")
    assert "bad" not in api.tracker.trackers() and "ncc" in api.tracker.trackers()


def page_blocks() -> list[tuple[str, str]]:
    """(language, text) of the fenced blocks of docs/own_tracker.md."""
    return re.findall(r"^```(\w+)\n(.*?)^```", PAGE.read_text(), flags=re.S | re.M)


def test_the_page_shows_the_example_and_runs_as_written(site, tmp_path):
    """The page's code is the package's and its entry point; its commands run as written."""
    blocks = page_blocks()
    python = [t for lang, t in blocks if lang == "python"]
    assert python[0] == (PLUGIN / "gflow_ncc" / "__init__.py").read_text()
    assert [t for lang, t in blocks if lang == "toml"] == [(PLUGIN / "pyproject.toml").read_text()]
    data_dir("crossing")
    work = tmp_path / "work"  # ../shared/data resolves from here as from the repository
    work.mkdir()
    (tmp_path / "shared").symlink_to(DATA.parent, target_is_directory=True)
    env = env_with(site)
    shell = [ln for lang, t in blocks if lang == "bash" for ln in t.splitlines() if ln.strip()]
    assert any("--inline" in ln for ln in shell) and any(ln.startswith("cmp ") for ln in shell)
    for line in shell:
        if line.startswith("pip "):
            continue
        words = shlex.split(line)
        if words[0] == "gflow":  # the repository's gflow, with a shorter run for the benchmark
            line = shlex.join(GFLOW + words[1:]).replace(" -q > ", " --frames 0:30 -q > ").replace("'>'", ">")
        r = subprocess.run(["bash", "-o", "pipefail", "-c", line], env=env, cwd=work, capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, f"{line}\n{r.stderr[-1500:]}"
    assert json.loads((work / "ncc.json").read_text())["rows"][0]["tracker"] == "ncc"
    r = subprocess.run([sys.executable, "-c", python[1]], env=env, cwd=work, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and "tracked" in r.stdout, r.stderr


def test_a_spec_is_checked_when_it_is_made():
    """A spec that could not run is refused where it is written, naming what is wrong."""
    from dataclasses import dataclass

    from gflow_core.spec import BoxStages, SpecError, TrackerSpec

    @dataclass(frozen=True)
    class NoParticles:
        sharpness: float = 1.0

    box = BoxStages(walk=lambda *a: a[1], purpose=1, proposal=lambda x, dt: x, particles=lambda s: s,
                    alpha_of=lambda x: x, particles_of=lambda a: a, to_arrays=lambda s: ({}, {}),
                    from_arrays=lambda a, v, p: None)
    with pytest.raises(SpecError, match="lower-case Python identifier"):
        TrackerSpec("My-Tracker", NoParticles, lambda: None, box=box)  # type: ignore[arg-type,return-value]
    with pytest.raises(SpecError, match="params must be a dataclass"):
        TrackerSpec("mine", dict, lambda: None, box=box)  # type: ignore[arg-type,return-value]
    with pytest.raises(SpecError, match="either the graph it runs in or its box stages"):
        TrackerSpec("mine", NoParticles, lambda: None)  # type: ignore[arg-type,return-value]
    with pytest.raises(SpecError, match="need a parameter 'particles' in NoParticles"):
        TrackerSpec("mine", NoParticles, lambda: None, box=box)  # type: ignore[arg-type,return-value]


#: trackers of another package built from the example's spec: one needing a model, one declaring
#: appearance's option (shared) and gflow track's --start (a clash); written beside the example
#: in a site folder of their own
VARIANTS = '''
import dataclasses

from gflow_core.params import param
from gflow_ncc import SPEC, NCCParams

@dataclasses.dataclass(frozen=True)
class ModelParams(NCCParams):
    sharpness: float = param(20.0, "likelihood exp(sharpness * ncc)")  # no option: ncc has --ncc-sharpness


MODEL = dataclasses.replace(SPEC, name="nccm", params=ModelParams, model_option="--model", model_required=True)


@dataclasses.dataclass(frozen=True)
class ClashParams(ModelParams):
    particles: int = param(300, "number of particles", option="--particles")  # appearance's, by its name: shared
    first: int = param(0, "the first frame it tracks", option="--start")  # gflow track's own: a clash


CLASH = dataclasses.replace(SPEC, name="clash", params=ClashParams)
'''


@pytest.fixture(scope="module")
def variants(tmp_path_factory) -> Path:
    where = install(tmp_path_factory.mktemp("variants"), "gflow-variants",
                    {"nccm": "gflow_variants:MODEL", "clash": "gflow_variants:CLASH"})
    (where / "gflow_variants.py").write_text(VARIANTS)
    return where


def test_it_is_in_every_list_of_trackers(site, variants, monkeypatch):
    """gflow.TRACKERS, the options it shares (its field ``particles`` reads ``--particles``), the
    benchmark's model options and the VOT workspace's trackers all come from the registry."""
    import argparse

    import gflow
    from pipeline.cli.commands.benchmark import model_options
    from pipeline.cli.commands.export import served_trackers
    from pipeline.cli.commands.track import option_users, tracker_options

    monkeypatch.syspath_prepend(str(variants))
    monkeypatch.syspath_prepend(str(site))
    assert {"ncc", "nccm", "dcf"} <= set(gflow.TRACKERS) and "ncc" in gflow.tracker.TRACKERS
    assert option_users("particles", "appearance") == {"appearance", "chamfer", "clash", "dcf", "m2", "ncc", "nccm"}
    assert set(tracker_options("ncc")) == {"particles", "ncc_sharpness"}
    assert model_options() == {"gflow": "--gflow-model", "m2": "--m2-model", "nccm": "--nccm-model"}
    none = argparse.Namespace(gflow_model=None, m2_model=None, nccm_model=None)
    served = served_trackers(none)
    assert list(served)[0] == "dcf" and "ncc" in served and "clash" in served
    assert "nccm" not in served and "m2" not in served  # each needs a model nobody gave
    given = served_trackers(argparse.Namespace(gflow_model="ellipsoid", m2_model=None, nccm_model="m.npz"))
    assert given["nccm"] == ["--tracker", "nccm", "--model", "m.npz"]
    assert given["gflow"] == ["--tracker", "gflow", "--model", "ellipsoid"]


def test_its_shared_and_model_options_reach_its_plan(site, variants, tmp_path):
    """``--particles`` (appearance's option) reaches ncc's stages; a tracker needing a model is
    refused without one and skipped by the benchmark, naming its option."""
    crossing = data_dir("crossing")
    env = env_with(site, variants)
    probe = ("import sys; from pipeline.cli.commands.track import track_args, track_plan; "
             "tp = track_plan(track_args(sys.argv[1:])); print(tp.plan.stage_params('filter')['particles'])")
    r = subprocess.run([sys.executable, "-c", probe, str(crossing), "--init", "204,150,17,50", "--tracker", "ncc",
                        "--particles", "57", "--out", str(tmp_path / "x.csv"), "--inline"], env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "57", r.stderr
    r = gflow(["track", str(crossing), "--init", "204,150,17,50", "--tracker", "nccm", "--out", "x.csv", "--inline"], env,
              cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().endswith("--tracker nccm needs --model MODEL"), r.stderr
    r = gflow(["benchmark", str(DATA), "--sequences", "crossing", "--trackers", "nccm", "--frames", "0:5", "--inline",
               "--opencv", "none", "--json", "-q"], env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    row = next(row for row in json.loads(r.stdout)["rows"] if row["tracker"] == "nccm")
    assert row["note"] == "skipped: needs --nccm-model MODEL.npz"


def test_an_option_another_tracker_has_is_one_line(variants, tmp_path):
    """A tracker declaring ``--start`` (gflow track's) cannot run from the command line, said in one
    line naming it, the option and its owner; ``--particles`` on its field ``particles`` is shared,
    not a clash; every other tracker still runs."""
    env = env_with(variants, PLUGIN)
    r = gflow(["track", "in", "--init", "1,1,5,5", "--out", "x.csv", "--tracker", "clash"], env, cwd=tmp_path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "tracker clash: its option --start (ClashParams.first) is already an option of gflow track" in r.stderr
    r = gflow(["track", str(DATA / "crossing"), "--init", "204,150,17,50", "--tracker", "dcf", "--particles", "50",
               "--stop", "3", "--inline", "--no-record", "-q", "--out", str(tmp_path / "dcf.csv")], env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
