"""A sweep of every ``gflow`` command with the bad input a user would plausibly give, the faults it found: each
case is one line on stderr naming what was wrong, a non-zero exit, no traceback, before any work.

Every case runs the CLI in a process of its own (``tests/cli_fork.py``), or a new interpreter where a case needs
its own hash seed; the sources are tiny files written into tmp_path.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from test_cli_errors import assert_one_line_error, frames, gflow  # noqa: F401  (frames: a fixture)

ROOT = Path(__file__).resolve().parent.parent


def test_an_option_of_other_trackers_names_them_in_one_order(tmp_path: Path, frames: Path) -> None:
    """The trackers an option belongs to came from a set: their order changed with the hash seed of the run."""
    said = set()
    for seed in ("0", "1", "2"):
        env = dict(os.environ, PYTHONHASHSEED=seed, PYTHONPATH=str(ROOT))
        r = subprocess.run([sys.executable, "-m", "pipeline.cli.main", "track", str(frames), "--init", "1,1,5,5",
                            "--out", "b.csv", "--no-record", "--tracker", "gflow", "--particles", "9"], cwd=tmp_path,
                           env=env, capture_output=True, text=True, timeout=60)
        said.add(assert_one_line_error(r, "--particles is an option of --tracker appearance / chamfer / dcf / m2, "
                                          "not of --tracker gflow"))
    assert len(said) == 1, said


def _wait_for_the_zygote(p: subprocess.Popen, timeout: float = 60.0) -> None:
    """Wait until ``gflow track`` (pid ``p``) has forked its stages' zygote, the first thing its module does:
    before that, Python itself is starting (a SIGINT in its ``site`` import is a fatal error of Python's, whatever
    the program), and a busy machine can take longer than any fixed delay to get there."""
    import time

    children = Path(f"/proc/{p.pid}/task/{p.pid}/children")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and p.poll() is None:
        try:
            if children.read_text().split():
                return
        except OSError:
            return
        time.sleep(0.002)
    assert p.poll() is None, f"gflow ended before forking its zygote: {p.returncode}"


@pytest.mark.parametrize("delay", [0.0, 0.1, 0.3, 0.5, 0.8])
def test_ctrl_c_while_gflow_starts_is_one_line_not_a_traceback(tmp_path: Path, frames: Path, delay: float) -> None:
    """SIGINT to the terminal's process group while ``gflow track`` imports its modules (numpy, the trackers:
    the first few tenths of a second) printed a KeyboardInterrupt traceback from inside an import. Later, it
    is the run's own interruption: exit status 130 and it says so; a stage that the Ctrl-C stopped before its node
    started was also said as 'stage filter exited with status 130: ' (no reason), a line per stage."""
    script = Path(sys.executable).parent / "gflow"
    if not script.is_file():
        pytest.skip("no gflow console script beside this Python")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([str(script), "track", str(frames), "--init", "1,1,20,20", "--out", "b.csv", "--no-record",
                          "--realtime", "--fps", "1", "-q"], cwd=tmp_path, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        import time

        # the delay counts from gflow's first own step, not from the exec
        _wait_for_the_zygote(p)
        time.sleep(delay)
        os.killpg(p.pid, signal.SIGINT)
        out, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, (p.returncode, err)
    assert "Traceback" not in err, err
    assert "interrupted" in err and "exited with status 130" not in err, err


@pytest.fixture(scope="module")
def demo_mcap(tmp_path_factory) -> Path:
    """A closed recording of 20 frames of the synthetic scene (``gflow demo --inline``)."""
    where = tmp_path_factory.mktemp("demo")
    r = gflow("demo", "--frames", "20", "--inline", "--record", "demo.mcap", cwd=where)
    assert r.returncode == 0, r.stderr
    return where / "demo.mcap"


@pytest.mark.parametrize("extra", [["--check"], ["--out", "new.mcap"]])
def test_rerun_graph_interrupted_is_no_verdict(tmp_path: Path, demo_mcap: Path, monkeypatch, capsys,
                                               extra: list[str]) -> None:
    """A whole-graph re-run stopped by Ctrl-C (its inline run ends as at its source's end) was compared as if
    whole: every later output 'recorded, but the re-run did not produce it', exit 1 with --check and 0
    without. It is an interruption: exit 130, one line, nothing compared."""
    import pipeline.recording.rerun as rerun
    from pipeline.cli.main import main

    real = rerun.rerun_graph

    def stopped_midway(*a, **kw):
        plan, res = real(*a, **kw)
        res.interrupted = True  # as run_inline says a Ctrl-C
        return plan, res

    monkeypatch.setattr(rerun, "rerun_graph", stopped_midway)
    monkeypatch.chdir(tmp_path)
    assert main(["rerun", str(demo_mcap), "--graph", *extra]) == 130
    out, err = capsys.readouterr()
    assert "compared" not in out and "did not produce" not in out, out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gflow rerun: interrupted after ") and "nothing compared" in lines[0]


@pytest.mark.parametrize("stage", ["filter", "proposal"])
def test_rerun_and_step_name_the_frames_a_recording_holds_not_one_more(tmp_path: Path, demo_mcap: Path,
                                                                      stage: str) -> None:
    """20 frames recorded (0..19): the proposals of frame t + 1, sent once frame t was tracked, carry 20, so
    rerun and step said the recording 'holds frames 0..20' and rerun took --from 20 (re-ran, compared, exit 0).
    Both name frames 0..19 and refuse frame 20 in one line; frame 19 is still there to start from."""
    r = gflow("rerun", str(demo_mcap), "--stage", stage, "--from", "20", "--check", cwd=tmp_path)
    assert_one_line_error(r, f"gflow rerun: error: --from 20: {demo_mcap} holds frames 0..19 for stage {stage}")
    assert r.returncode == 2 and not r.stdout, r.stdout
    r = gflow("rerun", str(demo_mcap), "--stage", stage, "--from", "19", "--check", cwd=tmp_path)
    assert r.returncode == 0 and "identical bit for bit" in r.stdout, (r.stdout, r.stderr)
    r = gflow("step", str(demo_mcap), "--stage", stage, "--start", "20", cwd=tmp_path)
    assert_one_line_error(r, f"gflow step: error: --start: no frame 20 to jump to: {demo_mcap} holds frames 0..19 "
                             f"for stage {stage}")
    r = gflow("step", str(demo_mcap), "--stage", stage, cwd=tmp_path, input="j 20\nn\n")
    assert_one_line_error(r, "standard input line 1: no frame 20 to jump to", "holds frames 0..19")
    r = gflow("step", str(demo_mcap), "--stage", stage, "--start", "19", cwd=tmp_path, input="n\n")
    assert r.returncode == 0 and "jumped to frame 19" in r.stdout and "--- frame 19 " in r.stdout, r.stdout


def test_plot_of_a_recording_without_stage_inputs_prints_no_matplotlib_warning(tmp_path: Path) -> None:
    """A recording kept with --record-topics holds no stage's inputs and outputs both, so no latency line: the
    plot was written, with matplotlib's 'No artists with labels found to put in legend' warning (its file
    and line) on stderr."""
    r = gflow("demo", "--frames", "5", "--inline", "--record", "est.mcap", "--record-topics", "estimate", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = gflow("plot", "est.mcap", "p.png", cwd=tmp_path)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert (tmp_path / "p.png").stat().st_size > 0


@pytest.mark.parametrize("box", ["1,1,1e308,5", "1,1,641,5", "1,1,5,481"])
def test_an_init_box_many_times_the_image_is_refused_first(tmp_path: Path, frames: Path, box: str) -> None:
    """A box ten times the 64x48 image or more is a typing mistake: 1e308 ran, every frame an error report,
    'tracked 0 frames' and exit 0; 1e6 grew the dcf stage's arrays until it was killed and the run stalled."""
    r = gflow("track", str(frames), "--init", box, "--out", "b.csv", "--no-record", cwd=tmp_path)
    assert_one_line_error(r, "--init box", "more than 10 times the size of the 64x48 image",
                          "W at most 640, H at most 480")
    assert not (tmp_path / "b.csv").exists()



@pytest.mark.parametrize("record", [["--record", "r.mcap"], ["--no-record"]])
def test_a_track_run_with_no_estimate_at_all_is_incomplete(tmp_path: Path, frames: Path, monkeypatch, capsys,
                                                           record: list[str]) -> None:
    """Every frame sent and recorded, the filter failing on each (here a box too large for it, let past the
    check of --init), no estimate at all: the frames expected were counted only if some estimate came, so the
    run was 'tracked 0 frames', complete, exit 0. It is incomplete (exit 3), every frame named; with --no-record
    (no recording of the frames sent) the frames the stages reported are those expected."""
    import pipeline.runtime.preflight as preflight
    from pipeline.cli.main import main

    monkeypatch.setattr(preflight, "MAX_BOX_TIMES_IMAGE", float("inf"))
    monkeypatch.chdir(tmp_path)
    rc = main(["track", str(frames), "--init", "1,1,1e308,5", "--out", "b.csv", *record, "--inline", "-q"])
    out, err = capsys.readouterr()
    assert rc == 3, (out, err)
    assert "5 frame(s) have no estimate: 0-4" in out, (out, err)
    assert err.splitlines()[-1].startswith("every one of the 5 frames failed in stage "), err


#: appearance's search margin of 1e300 box sizes: finite, past its checks, and every frame's step fails (OpenCV
#: cannot size the window), the pipeline carrying on
EVERY_FRAME_FAILS = ["--set", "tracker.search=1e300"]


@pytest.mark.parametrize("argv", [
    ["track", "{frames}", "--tracker", "appearance", "--init", "10,10,20,20", "--out", "b.csv", "-q", "--inline"],
    ["track", "{frames}", "--tracker", "appearance", "--init", "10,10,20,20", "--out", "b.csv", "-q",
     "--listen", "tcp/127.0.0.1:0"],
    ["run", "appearance", "--inline", "--set", "source.path={frames}", "--set", "filter.init=[10,10,20,20]",
     "--set", "proposal.init=[10,10,20,20]"],
])
def test_a_run_whose_every_frame_failed_says_why_and_exits_non_zero(tmp_path: Path, frames: Path,
                                                                    argv: list[str]) -> None:
    """Every frame's step failing (the stage reporting each, the pipeline carrying on), `gflow run` ended 'appearance:
    5 frames in 0.07 s', exit 0, and `gflow track` 'the run is incomplete: 5 frame(s) have no estimate', saying
    nothing of why. Each ends on one line naming the stage and its first reason, exit status 3."""
    r = gflow(*(a.format(frames=frames) for a in argv), "--no-record", *EVERY_FRAME_FAILS, cwd=tmp_path, timeout=120)
    assert r.returncode == 3, (r.stdout, r.stderr)
    last = r.stderr.splitlines()[-1]
    assert last.startswith("every one of the 5 frames failed in stage filter: frame 0: ") and "warpAffine" in last, \
        r.stderr


def test_a_run_some_of_whose_frames_failed_says_how_many_and_why(tmp_path: Path, frames: Path) -> None:
    """A filter that fails from its second frame on (a spread of 1e300 px): `gflow track` counted the error without
    its reason, and said '--stop 4 is past the end of frames: its last frame is 0', the last estimate taken for the
    last frame there is; `gflow run` said nothing of its errors at all."""
    r = gflow("track", str(frames), "--tracker", "appearance", "--init", "10,10,20,20", "--out", "b.csv", "--stop", "4",
              "--no-record", "--inline", "-q", "--set", "tracker.detect_std=1e300", cwd=tmp_path)
    assert r.returncode == 3, (r.stdout, r.stderr)
    assert "errors reported: 1 (filter 1); the first: frame 1: ValueError: log-weights contain NaN" in r.stdout, r.stdout
    assert "past the end" not in r.stdout, r.stdout
    r = gflow("run", "demo", "--inline", "--no-record", "--set", "source.frames=5", "--set",
              "proposal.std_log_s=1e300", cwd=tmp_path)
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "errors reported: 1 by stage proposal, 4 of the 5 frames without an estimate; the first: particles 0: " \
           "alpha contains NaN or inf" in r.stdout, r.stdout


@pytest.mark.parametrize("argv,words", [
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--set", "tracker.kappa=inf"],
     "--set tracker.kappa=inf: kappa must be a finite number, got inf"),
    (["run", "demo", "--set", "filter.lam=inf"], "--set filter.lam=inf: lam must be a finite number, got inf"),
])
def test_infinity_where_it_means_nothing_is_refused_before_the_run(tmp_path: Path, frames: Path, argv: list[str],
                                                                   words: str) -> None:
    """inf passes a check such as ``kappa > 0``: dcf failed every frame after the first as processes started
    ('Expected `float`, got `null`'), inline from frame 1 ('log-weights contain NaN or +inf'); the demo's filter
    reported every frame ('kernel widths sigma_k must be positive') and exited 0."""
    r = gflow(*(a.format(frames=frames) for a in argv), "--no-record", "--inline", cwd=tmp_path)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert_one_line_error(r, words)
    assert not (tmp_path / "b.csv").exists()


def test_infinity_where_a_parameter_says_what_it_means_runs_as_processes_too(tmp_path: Path, frames: Path) -> None:
    """G-flow's max_rotation_deg of inf is no wall: a run as processes failed at start-up, every stage's plan
    read with null for it."""
    r = gflow("track", str(frames), "--tracker", "gflow", "--model", "ellipsoid", "--init", "10,10,20,20", "--out",
              "b.csv", "--no-record", "-q", "--listen", "tcp/127.0.0.1:0", "--set", "tracker.max_rotation_deg=inf",
              cwd=tmp_path, timeout=120)
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "tracked 5 frames" in r.stdout, r.stdout


#: a tracker of its own package (the example ``tests/plugins/gflow_ncc``) whose filter fails on every frame from
#: frame 3 on: a stage failing midway, in a run inline or as processes alike
FAILING = """
from dataclasses import replace
from gflow_ncc import SPEC as NCC, NCCTracker

class Failing(NCCTracker):
    name = "failing"

    def update(self, p, st, prop, obs, rng):
        if rng.t >= 3:
            raise RuntimeError("fails from frame 3")
        return super().update(p, st, prop, obs, rng)

SPEC = replace(NCC, name="failing", tracker=Failing)
"""


@pytest.mark.parametrize("mode", [["--inline", "--record", "r.mcap"], ["--inline", "--no-record"],
                                  ["--listen", "tcp/127.0.0.1:0", "--no-record"]])
def test_frames_after_a_stage_failed_midway_have_no_estimate_without_a_recording(tmp_path: Path, frames: Path,
                                                                                 mode: list[str]) -> None:
    """The filter failing from frame 3 of 5: recorded, frames 3-4 were named as having no estimate (exit 3); with
    --no-record the frames expected ended at the last estimate, so the run was 'tracked 3 frames', complete, exit 0.
    Without a recording the frames expected run to the last frame the source sent, as with one."""
    from test_own_tracker import PLUGIN, install

    site = install(tmp_path / "site", "gflow-failing", {"failing": "gflow_failing:SPEC"}, PLUGIN / "gflow_ncc")
    (site / "gflow_failing.py").write_text(FAILING)
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "track", str(frames), "--init", "10,10,20,20",
                        "--tracker", "failing", "--out", "b.csv", "-q", *mode], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120, env=dict(os.environ, PYTHONPATH=f"{site}{os.pathsep}{ROOT}"))
    assert r.returncode == 3, (r.stdout, r.stderr)
    assert "tracked 3 frames" in r.stdout and "2 frame(s) have no estimate: 3-4" in r.stdout, r.stdout
    assert "the run is incomplete: 2 frame(s) have no estimate: 3-4" in r.stderr, r.stderr


@pytest.mark.parametrize("argv,words", [
    (["track", "{frames}", "--init", "1,1,20,20", "--out", "b.csv", "--no-record", "--inline", "--fps", "1e-300"],
     ["gflow track: error: argument --fps: must be a number >= 0.001, got 1e-300"]),
    (["run", "{graph}", "--inline", "--no-record", "--set", "source.fps=1e-300"],
     ["--set source.fps=1e-300", "at least 0.001 frames/s"]),
    (["render", "{rec}", "v.mp4", "--fps", "1e-300"], ["argument --fps: must be a number >= 0.01, got 1e-300"]),
    (["render", "{rec}", "v.avi", "--fps", "2000"], ["argument --fps: a video's frame rate is 0.01-1000, got 2000"]),
])
def test_a_frame_rate_past_what_can_be_used_is_refused_as_the_option(tmp_path: Path, frames: Path, demo_mcap: Path,
                                                                      argv: list[str], words: list[str]) -> None:
    """A source's rate of 1e-300 stamped its frames past any integer: 'internal error: OverflowError'. A video's
    rate OpenCV cannot write printed OpenCV's own error lines and blamed the file's kind (.mp4), or asked
    about a full disk (.avi past 1000 frames/s)."""
    graph = tmp_path / "g.yaml"
    graph.write_text("name: g\nstream: g\ntracker: dcf\nstages:\n  source:\n    kind: source\n"
                     f"    params: {{kind: folder, path: {frames}, fps: 25}}\n"
                     "  proposal:\n    kind: dcf.proposal\n    inputs: {particles: particles}\n"
                     "    params: {seed: 0, init: [1, 1, 20, 20]}\n"
                     "  filter:\n    kind: dcf.filter\n    inputs: {frames: frames, proposals: proposals}\n"
                     "    params: {seed: 0, init: [1, 1, 20, 20]}\n")
    args = [a.format(frames=frames, graph=graph, rec=demo_mcap) for a in argv]
    r = gflow(*args, cwd=tmp_path)
    assert_one_line_error(r, *words)
    assert not list(tmp_path.glob("v.*")) and not (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("argv,words", [
    (["track", "{frames}", "--init", "1,1,20,20", "--out", "b.csv", "--particles", "abc"],
     "argument --particles: expected a whole number, got 'abc'"),
    (["track", "{frames}", "--init", "1,1,20,20", "--out", "b.csv", "--tracker", "gflow", "--shards", "1.5"],
     "argument --shards: expected a whole number, got '1.5'"),
    (["track", "{frames}", "--init", "1,1,20,20", "--out", "b.csv", "--blank-std", "abc"],
     "argument --blank-std: expected a number, got 'abc'"),
    (["demo", "--seed", "abc"], "argument --seed: expected a whole number, got 'abc'"),
    (["frame", "{frames}", "abc", "f.png"], "argument index: expected a whole number, got 'abc'"),
    (["rerun", "{rec}", "--from", "abc"], "argument --from: expected a whole number, got 'abc'"),
    (["hz", "demo/frames", "--window", "abc"], "argument --window: expected a whole number, got 'abc'"),
    (["learn", "m2", "{frames}", "-K", "abc", "--out", "m.npz"], "argument -K: expected a whole number, got 'abc'"),
])
def test_a_number_that_is_not_one_is_said_as_every_command_says_it(tmp_path: Path, frames: Path, demo_mcap: Path,
                                                                    argv: list[str], words: str) -> None:
    """argparse's own 'invalid int value: 'abc'' (or 'invalid float value') for the options read with int or
    float, where every other option says 'expected a whole number' (or 'expected a number')."""
    r = gflow(*[a.format(frames=frames, rec=demo_mcap) for a in argv], cwd=tmp_path)
    line = assert_one_line_error(r, words)
    assert r.returncode == 2 and "invalid" not in line, line


def test_every_option_of_every_command_reads_its_numbers_as_the_others_do() -> None:
    """Every option (and argument) of every command and tracker that reads a value through a type refuses a
    value it cannot read with its own words (an ``argparse.ArgumentTypeError``), never with argparse's
    'invalid int value' (a ValueError of ``int`` or ``float``)."""
    import argparse

    from pipeline.cli.main import build_parser

    def typed(parser: argparse.ArgumentParser, words: str):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from typed(sub, f"{words} {name}")
            elif a.type is not None:
                yield f"{words} {max(a.option_strings, key=len) if a.option_strings else a.dest}", a.type

    bad = []
    for where, kind in typed(build_parser(), "gflow"):
        for text in ("abc", "1.5", "nan", "1e999"):
            try:
                kind(text)
            except argparse.ArgumentTypeError:
                pass
            except (ValueError, TypeError) as e:
                bad.append(f"{where} {text}: {type(e).__name__}: {e}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("tracker", ["dcf", "appearance"])
def test_particles_past_opencvs_row_limit_are_tracked(tmp_path: Path, frames: Path, tracker: str) -> None:
    """40000 particles (OpenCV's remap writes fewer than 32767 rows): the filter failed on the first frame after
    the first (a 'stage_exception' with OpenCV's assertion), one frame of five tracked, exit 0."""
    r = gflow("track", str(frames), "--init", "1,1,20,20", "--out", "b.csv", "--no-record", "--inline", "-q",
              "--tracker", tracker, "--set", "tracker.particles=40000", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "errors reported" not in r.stdout and "WARNING" not in r.stderr, (r.stdout, r.stderr)
    assert len((tmp_path / "b.csv").read_text().splitlines()) == 6


def test_remap_points_in_blocks_is_the_one_call_below_the_limit() -> None:
    """Past :data:`gflow_core.remap.MAX_ROWS` points, the blocks give each point the value a call of its own would."""
    from gflow_core.remap import MAX_ROWS, remap_points

    rng = np.random.default_rng(1)
    src = rng.random((40, 50)).astype(np.float32)
    u = rng.uniform(-5, 55, MAX_ROWS * 2 + 7).astype(np.float32)
    v = rng.uniform(-5, 45, u.size).astype(np.float32)
    got = remap_points(src, u, v, cv2.INTER_LINEAR, cv2.BORDER_CONSTANT, -1.0)
    want = np.concatenate([cv2.remap(src, u[a:a + 1000].reshape(-1, 1), v[a:a + 1000].reshape(-1, 1), cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0).ravel()
                           for a in range(0, u.size, 1000)])
    assert got.shape == (u.size,) and np.array_equal(got, want)


@pytest.mark.parametrize("endpoint,why", [("tcp/999.1.1.1:7447", "cannot listen on tcp/999.1.1.1:7447"),
                                          ("tcp/10.255.255.1:7447", "Cannot assign requested address")])
def test_listen_where_this_machine_cannot_is_refused_before_saying_it_listens(tmp_path: Path, frames: Path,
                                                                             endpoint: str, why: str) -> None:
    """A --listen host that does not resolve, or an address not this machine's: 'dcf: listening on ENDPOINT' was
    printed, then zenoh's error (two lines, the first untrue)."""
    r = gflow("track", str(frames), "--init", "1,1,20,20", "--out", "b.csv", "--no-record", "--listen", endpoint,
              cwd=tmp_path)
    assert_one_line_error(r, "gflow track: error: cannot listen on", why)
    assert "listening on" not in r.stderr


@pytest.mark.parametrize("vis,words", [("nosuch.csv", ["visibility file not found: nosuch.csv"]),
                                       ("afolder", ["afolder is a folder, not a visibility file"])])
def test_eval_names_a_missing_visibility_file_as_itself(tmp_path: Path, vis: str, words: list[str]) -> None:
    """With predictions of no state column, a missing --visibility file was said as 'PRED has no state column'."""
    (tmp_path / "afolder").mkdir()
    (tmp_path / "b.csv").write_text("frame,x,y,w,h\n0,1,1,5,5\n1,1,1,5,5\n")
    r = gflow("eval", "--gt", "b.csv", "--pred", "b.csv", "--visibility", vis, cwd=tmp_path)
    assert_one_line_error(r, *words)


@pytest.mark.parametrize("box", ["0.1,0.2,0.05,0.1", "10,10,0.5,5"])
def test_an_init_box_smaller_than_a_pixel_is_refused_first(tmp_path: Path, frames: Path, box: str) -> None:
    """A box given in fractions of the image: every frame an error report of the trackers' stages (chamfer's
    preprocess, appearance's filter...), 'tracked 0 frames', exit 0."""
    r = gflow("track", str(frames), "--init", box, "--out", "b.csv", "--no-record", "--tracker", "chamfer", cwd=tmp_path)
    assert_one_line_error(r, f"--init box {box}", "is smaller than a pixel", "64x48 image")
    assert not (tmp_path / "b.csv").exists()


#: a value past any machine's memory (the bound itself is the machine's: no figure of it is written here)
HUGE = "10000000000000"


@pytest.mark.parametrize("argv, said", [
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--set", "tracker.template=1e9"],
     ["--set tracker.template=1e9: template must be at most", "template pixel", "got 1000000000"]),
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--particles", HUGE],
     [f"--particles {HUGE}: particles must be at most", "bytes a particle", f"got {HUGE}"]),
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--tracker", "chamfer",
      "--set", f"tracker.particles={HUGE}"], [f"--set tracker.particles={HUGE}: particles must be at most"]),
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--tracker", "appearance",
      "--particles", HUGE], [f"--particles {HUGE}: particles must be at most"]),
    (["benchmark", "{seq}", "--trackers", "dcf", "--set", "tracker.template=1e9"],
     ["--set tracker.template=1e9: template must be at most"]),
    (["trax", "--set", "template=1e9"], ["--set template=1e9: template must be at most"]),
    # the scale filter's samples: scales x scale_area pixels (scales=1000000001 stalled the run, exit 3)
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--set",
      "tracker.scales=1000000000001"], ["--set tracker.scales=1000000000001: scales must be at most",
                                        "scales x scale_area of them"]),
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--set",
      f"tracker.scale_area={HUGE}"], [f"--set tracker.scale_area={HUGE}: scale_area must be at most"]),
    (["track", "{frames}", "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--tracker", "gflow",
      "--experts", HUGE], [f"--experts {HUGE}: n_experts must be at most", "n_experts x n_samples of them"]),
])
def test_a_value_needing_more_memory_than_the_machine_has_is_refused_first(tmp_path: Path, frames: Path,
                                                                          argv: list[str], said: list[str]) -> None:
    """--set tracker.template=1e9 or --particles 1e8 passed every check, then the stages grew their arrays for
    about 40 s until one died or the run stalled: exit 3. A value whose arrays need more memory than the machine
    has is refused before any work, as a bad value (exit 2), naming the largest that fits."""
    seq = tmp_path / "seq"
    (seq / "frames").mkdir(parents=True)
    for f in sorted(frames.iterdir()):
        (seq / "frames" / f.name).write_bytes(f.read_bytes())
    (seq / "groundtruth.csv").write_text("frame,x,y,w,h\n" + "".join(f"{i},10,10,20,20\n" for i in range(5)))
    r = gflow(*(a.format(frames=frames, seq=seq) for a in argv), cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, *said, "on this machine", "GB of memory")
    assert not (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("box, covers", [("10,10,1,20", "1x20"), ("10,10,20,1", "20x1"), ("10.5,10,1.4,20", "2x20")])
def test_a_box_narrower_than_chamfers_calibration_is_refused_first(tmp_path: Path, frames: Path, box: str,
                                                                  covers: str) -> None:
    """A 1-pixel-wide box passed the check of a box smaller than a pixel, then chamfer's preprocess refused every
    frame ('calibration box ... does not overlap the image', a box that does), 'tracked 0 frames', exit 3: its
    edges' thresholds are calibrated on at least 2x2 of the box's pixels. The tracker's minimum is said before
    any work. A box reaching into two pixels a side is enough, however narrow."""
    r = gflow("track", str(frames), "--init", box, "--out", "b.csv", "--no-record", "--tracker", "chamfer", "--inline",
              "-q", cwd=tmp_path)
    if covers == "2x20":
        assert r.returncode == 0, r.stderr
        return
    assert_one_line_error(r, f"--init box {box} covers {covers} pixels of the 64x48 image: chamfer needs at least 2x2",
                          "calibrated on the box's pixels")
    assert r.returncode == 2 and not (tmp_path / "b.csv").exists()


def test_a_tracker_that_needs_no_more_than_a_pixel_takes_a_one_pixel_wide_box(tmp_path: Path, frames: Path) -> None:
    """The minimum is the tracker's: dcf, whose window is padded about the box, tracks from a 1-pixel-wide box; so
    does chamfer with fixed thresholds (nothing calibrated on the box)."""
    r = gflow("track", str(frames), "--init", "10,10,1,20", "--out", "b.csv", "--no-record", "--inline", "-q",
              cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = gflow("track", str(frames), "--init", "10,10,1,20", "--out", "c.csv", "--no-record", "--inline", "-q",
              "--tracker", "chamfer", "--set", "preprocess.canny_low=10", "--set", "preprocess.canny_high=30",
              cwd=tmp_path)
    assert r.returncode == 0, r.stderr


def test_two_options_that_fit_alone_but_not_together_are_named_together(tmp_path: Path, frames: Path) -> None:
    """G-flow's pose samples are n_experts x n_samples: --experts and --samples that each fit the machine's memory
    but not together were said as the graph file's line (gflow.yaml:26: tracker gflow: ...), not as the options.
    The values are this machine's: each a little over the square root of what its memory holds (n_samples, the
    further above its default, is the one named)."""
    from gflow_core.gflow import GFlowParams
    from gflow_core.params import machine_memory

    m = next(f.metadata["memory"] for f in dataclasses.fields(GFlowParams) if f.name == "n_samples")
    n = int((machine_memory() / m.per) ** 0.5) + 1
    r = gflow("track", str(frames), "--init", "10,10,20,20", "--out", "b.csv", "--no-record", "--tracker", "gflow",
              "--experts", str(n), "--samples", str(n), cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, f"--experts {n} --samples {n}: n_samples must be at most", "on this machine")


def test_a_graph_run_checks_the_box_against_what_its_stages_need(tmp_path: Path, frames: Path) -> None:
    """gflow run of the chamfer graph with a 1-pixel-wide box calibrated on: every frame refused by its preprocess,
    as gflow track's was. Its stages' needs are checked with their initial boxes before any process starts."""
    box = "[10, 10, 1, 20]"
    r = gflow("run", "chamfer", "--inline", "--no-record", "--set", f"source.path={frames}",
              "--set", f"proposal.init={box}", "--set", f"filter.init={box}", "--set", f"preprocess.calibrate_box={box}",
              cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert_one_line_error(r, "init: box 10,10,1,20 covers 1x20 pixels of the 64x48 image: chamfer needs at least 2x2")
