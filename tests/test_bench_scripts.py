"""Every script under ``bench/`` starts: ``python bench/X.py --help`` prints its usage and exits 0.

A script that imports a module that has moved fails at import, long before anyone runs it for its
figures (``bench_dcf.py`` imported ``stages.rng`` after it had gone). The scripts run here in one
interpreter, one after another, so the check costs the imports once."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted(p.name for p in (ROOT / "bench").glob("*.py") if not p.name.startswith("_"))

_RUN_ALL = r"""
import contextlib, io, runpy, sys
failed = []
for name in sys.argv[1:]:
    sys.argv = [f"bench/{name}", "--help"]
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            runpy.run_path(f"bench/{name}", run_name="__main__")
        failed.append(f"{name}: no usage printed for --help")
    except SystemExit as e:
        if e.code not in (0, None) or "usage" not in out.getvalue():
            failed.append(f"{name}: --help exited {e.code!r}")
    except BaseException as e:  # an import that fails, a module that moved
        failed.append(f"{name}: {type(e).__name__}: {e}")
print("\n".join(failed))
"""


def test_every_bench_script_starts_and_explains_itself() -> None:
    assert len(SCRIPTS) > 20, SCRIPTS
    r = subprocess.run([sys.executable, "-c", _RUN_ALL, *SCRIPTS], cwd=ROOT, capture_output=True, text=True,
                       timeout=600, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr[-2000:]
    assert not r.stdout.strip(), r.stdout


def test_the_pace_benchmark_refuses_a_bad_gflow_setting_in_one_line_before_any_work() -> None:
    """``bench_gflow_pace.py --gflow-set`` of an unknown name, a value of the wrong kind or one G-flow
    refuses: one line naming it, in the user's words (not msgspec's), and nothing run (no frame
    written or tracked is reported)."""
    for setting, says in (("nonexist=1", "no parameter 'nonexist'"),
                          ("online_cue=abc", "online_cue must be a number, got 'abc'"),
                          ("online_cue=-3", "online_cue must be finite")):
        r = subprocess.run([sys.executable, "bench/bench_gflow_pace.py", "--gflow-set", setting], cwd=ROOT,
                           capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
        assert r.returncode != 0 and says in r.stderr, (setting, r.stderr)
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not r.stdout.strip(), r.stdout


def test_a_compare_folder_that_is_no_checkout_is_refused_in_one_line_before_any_work(tmp_path: Path) -> None:
    """``--compare DIR`` of a folder that holds no gflow: a run there would import the installed gflow and
    compare this code with itself (it did, and printed ratios near 1), or end in a traceback."""
    for bench in ("bench_command_startup.py", "bench_startup.py", "bench_gflow_cycle.py",
                  "bench_gflow_stress_points.py"):
        r = subprocess.run([sys.executable, f"bench/{bench}", "--compare", str(tmp_path)], cwd=ROOT,
                           capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
        assert r.returncode == 2 and "not a gflow checkout" in r.stderr, (bench, r.stderr[-500:])
        assert "Traceback" not in r.stderr and not r.stdout.strip(), (bench, r.stdout[-300:], r.stderr[-300:])


def test_the_pace_benchmark_takes_a_number_in_e_notation_as_gflow_track_does() -> None:
    """``--gflow-set psi_v=3e-3`` (YAML reads ``3e-3`` as a string) is the number 0.003 to ``gflow track``; the
    pace benchmark's check before any work accepts it too (it refused it as "not a number")."""
    code = ("import sys; sys.path.insert(0, 'bench'); import _util as b; "
            "b.gflow_sets(['psi_v=3e-3', 'psi_b=1e-2']); print('accepted')")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                       stdin=subprocess.DEVNULL)
    assert r.returncode == 0 and r.stdout.strip() == "accepted", (r.stdout, r.stderr)


def test_the_gflow_benches_set_gflow_parameters_in_the_graphs_tracker_block(tmp_path: Path) -> None:
    """``bench_gflow_fig3.py``, ``bench_gflow_david.py`` and ``bench_gflow_pipeline.py`` build their plans
    with ``bench/_util.py``'s ``gflow_plan``; a G-flow parameter set on a stage rather than in the tracker
    block is refused by the graph, which ``--help`` does not reach (all three once failed so, at their
    first run)."""
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        from _util import gflow_plan
        from bench_gflow_david import OPTIC_FLOW
    finally:
        sys.path.remove(str(ROOT / "bench"))
    src = {"kind": "folder", "path": str(tmp_path)}
    optic = gflow_plan(src, dict(OPTIC_FLOW, init=[1.0, 2.0, 30.0, 40.0], seed=3))
    assert optic.tracker.params["n_experts"] == 1 and optic.tracker.params["alpha"] == 0.0
    sharded = gflow_plan(src, {"n_experts": 20, "background": False, "init": [1.0, 2.0, 30.0, 40.0], "seed": 0},
                         shards=2)
    assert sharded.tracker.params["n_experts"] == 20 and {"proposal0", "proposal1"} <= set(sharded.stages)
    assert all(sharded.stage_params(s)["seed"] == 0 for s in ("proposal0", "proposal1", "filter"))


def test_the_pipeline_benchmark_runs_the_ellipsoid_head_with_its_own_settings(tmp_path: Path) -> None:
    """``bench_gflow_pipeline.py --model ellipsoid --gflow-set lost_guard=false`` builds the graph's plan
    with the ellipsoid's preset and the setting over it, in the tracker block (how its speed was traced
    against the face model's)."""
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        from _util import gflow_sets
        from bench_gflow_pipeline import plan
    finally:
        sys.path.remove(str(ROOT / "bench"))
    from gflow_core.gflow.params import ELLIPSOID

    settings = {**ELLIPSOID, **gflow_sets(["lost_guard=false", "reset_rate=0"])}
    p = plan(tmp_path, [1.0, 2.0, 30.0, 40.0], 20, False, 1, settings)
    block = p.tracker.params
    assert block["model"] == "" and block["photometric"] is True and block["lost_guard"] is False
    assert block["reset_rate"] == 0 and block["n_experts"] == 20
    face = plan(tmp_path, [1.0, 2.0, 30.0, 40.0], 20, False, 1).tracker.params
    assert face["model"] == "face" and face["photometric"] is False and face["lost_guard"] is True


def test_the_pipeline_benchmark_runs_to_its_tables(tmp_path: Path) -> None:
    """A few frames of the rendered head through ``bench_gflow_pipeline.py`` inline, to its tables (a helper
    it needs once went missing in a change that ``--help`` and the plan's check did not reach); its scratch
    folder, given with ``--out``, holds the recording it measured."""
    r = subprocess.run([sys.executable, "bench/bench_gflow_pipeline.py", "--experts", "2", "--frames", "4",
                        "--modes", "inline", "--background", "off", "--model", "ellipsoid",
                        "--out", str(tmp_path / "out")], cwd=ROOT, capture_output=True, text=True, timeout=300,
                       stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr[-2000:]
    row = next(ln for ln in r.stdout.splitlines() if ln.startswith("2 ") and "inline" in ln)
    assert row.split()[3] == "4", row  # every frame tracked
    assert float(row.split()[4]) > 0, row
    assert (tmp_path / "out" / "E2-bg0-inline.mcap").is_file()
