"""Shared fixtures: the real data folder, free loopback ports, small recordings."""

from __future__ import annotations

import atexit
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from pipeline.runtime.instruction_sets import hold

# before numpy, OpenCV or OpenBLAS loads in a test or a process a test starts: the kernels every gflow
# command uses (pipeline/runtime/instruction_sets.py), so the tests' own tracking equals the commands'
hold()

ROOT = Path(__file__).resolve().parent.parent

# The tests press Ctrl-C (SIGINT) on the processes they start, as a user at a terminal does. A suite
# started as a background job of a non-interactive shell (`nohup ... &`, some CI runners) inherits
# SIGINT ignored, and every process it starts would inherit that too and never see the Ctrl-C; so the
# suite takes SIGINT back as an interactive Python process has it (its children then start with it).
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
DATA = Path(os.environ.get("GFLOW_DATA", ROOT.parent / "shared" / "data"))



def _own_mpl_config() -> Path:
    """matplotlib (gflow plot, gflow benchmark --plot) keeps a font cache in its config folder, one for the whole
    user by default; test processes run side by side (`pytest -n 2`), and the commands they start, would write it at
    once and could read each other's half-written file. Each test process, and what it starts, has a folder of its
    own, removed when the process ends (at exit: a script that imports this module for a helper, outside pytest,
    leaves none behind either); one per process, however often the module is run in it."""
    mine = Path(os.environ.get("MPLCONFIGDIR", ""))
    if mine.name.startswith(f"gflow-mpl-{os.getpid()}-") and mine.is_dir():
        return mine
    made = Path(tempfile.mkdtemp(prefix=f"gflow-mpl-{os.getpid()}-"))
    atexit.register(shutil.rmtree, made, True)
    os.environ["MPLCONFIGDIR"] = str(made)
    return made


MPL_CONFIG = _own_mpl_config()
JS = ROOT / "tests" / "js"


def data_dir(name: str) -> Path:
    """A sequence folder of ../shared/data, or skip the test saying why."""
    p = DATA / name
    if not p.is_dir():
        pytest.skip(f"real data not available: {p} is missing (tests look for ../shared/data beside the repo, "
                    f"or set GFLOW_DATA)")
    return p


# The test files that take longest (seconds of wall time on 2 busy cores, --durations), longest first: every
# file of 40 s or more in a run of the whole suite at load 12 (--durations=0, the times of a file's tests summed).
# `-n 2 --dist loadfile` hands whole files to the two workers; by default xdist hands out the files
# with the most tests first, which leaves the long files with few tests (test_doc_figures: 3 tests,
# over a minute) to the end, where one worker runs them while the other has nothing left to do. Handed
# out first, they run while the other worker works through the many short files, and both end
# together. A name that is no longer a test file is simply not found; files not named keep xdist's order.
LONGEST_FIRST = ("test_cli_errors", "test_doc_figures", "core/test_appearance", "test_live_streams", "test_types",
                 "test_cli_audit", "test_real_tracking", "test_docs", "test_stress_benchmark", "test_faults_restart",
                 "test_recording_tools", "test_dcf_rotation", "test_benchmark_seeds", "test_live_input",
                 "test_m2_pipeline", "test_run_equals_track", "test_python_api", "test_gflow_rerun", "test_benchmark",
                 "test_m2_transfer", "test_dcf_pipeline", "core/test_dcf_track_score", "test_gflow_guard_online",
                 "test_deployment", "test_trust", "test_stress_skip", "test_gflow_lost_witness", "test_gflow_face",
                 "test_own_tracker", "test_track_options", "test_live_tools", "test_trax", "test_gflow_pipeline",
                 "test_faults_recording", "test_dcf_lookalike", "test_cli_trust", "core/test_dcf_tracker",
                 "test_eval_empty_boxes", "test_live", "test_placement", "test_recordings_kept", "test_dcf_start",
                 "test_cli_small", "core/test_dcf_scale_anchor", "test_truthful_reports", "core/test_dcf_scale_prior")


def pytest_collection_modifyitems(config, items):
    """Under xdist, the files of :data:`LONGEST_FIRST` first, in its order; then the others by their
    number of tests, most first (xdist's own order, which it is told not to apply on top)."""
    if not hasattr(config, "workerinput"):
        return  # not an xdist worker: the collection order is left alone
    rank = {f"tests/{name}.py": i for i, name in enumerate(LONGEST_FIRST)}
    count: dict[str, int] = {}
    for item in items:
        count[item.nodeid.split("::")[0]] = count.get(item.nodeid.split("::")[0], 0) + 1
    items.sort(key=lambda item: (rank.get(f := item.nodeid.split("::")[0], len(rank)), -count[f], f))


def _compile_the_project_once() -> None:
    """Byte-compile the project's packages before any test starts a process. With PYTHONDONTWRITEBYTECODE
    set (as on some CI machines) Python still reads a package's ``__pycache__`` but never writes it, so
    every `gflow` command and pipeline stage the tests start (hundreds) would compile the project from
    source again: about 0.3 s of each command's start-up. Written once here, by the one process that
    configures the run (the xdist controller, or plain pytest), before the workers exist."""
    import compileall

    for package in ("gflow", "gflow_core", "gflow_msgs", "stages", "pipeline"):
        compileall.compile_dir(ROOT / package, quiet=2, workers=1)


def pytest_configure(config):
    if not hasattr(config, "workerinput"):
        _compile_the_project_once()
    # pytest keeps each test module as it rewrote its asserts in tests/__pycache__ (ignored by git) and reads it
    # back while the module is unchanged, but with PYTHONDONTWRITEBYTECODE set it never writes it: every test process
    # (both xdist workers) would parse and rewrite all the test modules again, about 6 s of CPU each, at every run.
    # Written here, as _compile_the_project_once writes the project's; only this process's flag: the processes the
    # tests start keep the environment's setting.
    sys.dont_write_bytecode = False
    if getattr(config.option, "dist", "no") == "loadfile":
        config.option.loadscopereorder = False  # the order is pytest_collection_modifyitems'


@pytest.fixture(autouse=True, scope="session")
def _private_runtime_dir(tmp_path_factory):
    """Pipelines started by the tests announce themselves (pipeline.runtime.running) in a folder of the
    test session's own, so the live tools in a test never see a user's (or another session's)
    pipeline, and the tests never clutter the user's runtime folder."""
    old = os.environ.get("GFLOW_RUNTIME_DIR")
    os.environ["GFLOW_RUNTIME_DIR"] = str(tmp_path_factory.mktemp("gflow-runtime"))
    yield
    if old is None:
        os.environ.pop("GFLOW_RUNTIME_DIR", None)
    else:
        os.environ["GFLOW_RUNTIME_DIR"] = old


@pytest.fixture
def crossing() -> Path:
    return data_dir("crossing")


@pytest.fixture
def caviar1() -> Path:
    return data_dir("caviar1")


def made_once(tmp_path_factory, name: str, make) -> Path:
    """The folder ``name`` that ``make(folder)`` fills, made once for the whole test run: under xdist the
    workers' base temps (``.../popen-gwN``) share a parent that is the run's own, and the first worker to
    ask makes the folder there while the other waits on a lock, then both read it. ``make`` failing leaves
    no folder marked done, so the next to ask makes it again (and fails the same way)."""
    import fcntl

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = shared / f"made-once-{name}"
    with open(shared / f"made-once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (folder / ".done").exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            make(folder)
            (folder / ".done").touch()
    return folder


@pytest.fixture(scope="session")
def caviar1_m2_model(tmp_path_factory) -> Path:
    """A small contour model (K = 4) learned by `gflow learn m2` from caviar1 frames 0-59; learned once for
    the test run, both xdist workers reading the one file (:func:`made_once`): five test files use it."""
    caviar1 = data_dir("caviar1")

    def learn(folder: Path) -> None:
        import cli_fork  # forked from this test process's warm `gflow` (tests/cli_fork.py), not a new interpreter

        r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "learn", "m2", str(caviar1), "--boxes",
                                  str(caviar1 / "groundtruth.csv"), "--frames", "0:60", "-K", "4", "--max-points", "80",
                                  "--out", str(folder / "caviar1-k4.npz")], capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr

    return made_once(tmp_path_factory, "m2-model", learn) / "caviar1-k4.npz"


def synthetic_sequence(folder: Path, seed: int, frames: int, move=None) -> Path:
    """A sequence folder (frames/ and groundtruth.csv) of the synthetic scene with ``seed``, ``frames`` long;
    ``move(t, box)``, if given, changes the truth written for frame t (a target that leaves the image)."""
    from gflow_core.synthetic import SyntheticScene
    from pipeline.io.datasets import write_frames
    from pipeline.recording.results import write_boxes

    scene = SyntheticScene(n_frames=frames, seed=seed, period=90)
    write_frames(folder / "frames", [scene.render(t) for t in range(frames)])
    boxes = {t: scene.truth_box(t) for t in range(frames)}
    write_boxes(folder / "groundtruth.csv", boxes if move is None else {t: move(t, b) for t, b in boxes.items()})
    return folder


@pytest.fixture(scope="session")
def demo8(tmp_path_factory) -> Path:
    """The recording of `gflow demo --frames 8 --inline` (the synthetic scene): a small real run to read (made
    once for the test run, :func:`made_once`; the tests only read it)."""

    def demo(d: Path) -> None:
        import cli_fork  # forked from this test process's warm `gflow` (tests/cli_fork.py), not a new interpreter

        r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "demo", "--frames", "8", "--inline",
                                  "--record", "demo.mcap"], cwd=d, capture_output=True, text=True, timeout=120,
                                 stdin=subprocess.DEVNULL)
        assert r.returncode == 0, r.stderr

    return made_once(tmp_path_factory, "demo8", demo) / "demo.mcap"


@pytest.fixture
def gflow_cmd() -> list[str]:
    """The gflow command as the user runs it (the console script), falling back to python -m."""
    return [sys.executable, "-m", "pipeline.cli.main"]


def _node_reader() -> list[str]:
    """The command that runs the TypeScript reader, installing @mcap/core on first use."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node/npm not found: the independent @mcap/core reader cannot run here")
    if not (JS / "node_modules" / "@mcap" / "core").is_dir():
        r = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=JS, capture_output=True, text=True, timeout=300)
        if r.returncode != 0:
            pytest.skip(f"npm could not install @mcap/core (no registry?): {r.stderr.strip()[-300:]}")
    return [node, str(JS / "read_mcap.mjs")]


def read_mcap_js(path: Path, stream: bool = False) -> dict:
    """Summary of an MCAP file read by @mcap/core (TypeScript), an independent implementation."""
    out = subprocess.run([*_node_reader(), str(path), *(["--stream"] if stream else [])],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def damaged_copy(src: Path, bad: Path) -> Path:
    """``src`` rewritten into ``bad`` in many small chunks, 64 bytes in the middle flipped: a chunk that
    fails its CRC inside the file, its end intact (so not 'torn')."""
    from pipeline.io.mcap_io import iter_records, read_metadata
    from pipeline.io.recorder import McapRecorder

    with McapRecorder(bad, chunk_size=64 * 1024, metadata=read_metadata(src)) as w:  # many chunks
        for r in iter_records(src):
            w.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, log_ns=r.log_ns, type_name=r.type)
    data = bytearray(bad.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(b ^ 0xFF for b in data[mid:mid + 64])
    bad.write_bytes(bytes(data))
    return bad


def cli(args: list[str], capsys) -> tuple[int, str]:
    """Run ``gflow ARGS`` in this process: its exit status and what it wrote on stderr."""
    from pipeline.cli.main import main

    capsys.readouterr()
    try:
        rc = main(args)
    except SystemExit as e:  # argparse's refusals exit
        rc = int(e.code or 0)
    return rc, capsys.readouterr().err


class StderrLines:
    """The lines a running process (``subprocess.Popen``, text mode) writes on stderr, read on a thread as
    they come, so a test can wait for one (:meth:`until`) and then read them all (:meth:`rest`)."""

    def __init__(self, p: subprocess.Popen) -> None:
        import queue
        import threading

        self.p, self.seen, self._q = p, [], queue.Queue()
        self._reader = threading.Thread(target=lambda: [self._q.put(ln) for ln in p.stderr], daemon=True)
        self._reader.start()

    def until(self, done, timeout: float) -> None:
        """Wait until ``done(lines so far)``; fail (with the lines) after ``timeout`` s or if the process ends."""
        import queue
        import time

        deadline = time.monotonic() + timeout
        while not done(self.seen):
            assert time.monotonic() < deadline and self.p.poll() is None, "".join(self.seen)
            try:
                self.seen.append(self._q.get(timeout=1.0))
            except queue.Empty:
                pass

    def rest(self) -> list[str]:
        """Every line, once the process has closed its stderr."""
        self._reader.join(timeout=30)
        while not self._q.empty():
            self.seen.append(self._q.get())
        return self.seen



def interrupt_after(cmd: list[str], marker: str, timeout: float = 120) -> tuple[int, str, list[str]]:
    """Run ``cmd`` (text mode), wait until a stderr line holds ``marker`` and, after it, a source's progress line
    with frames sent (so a run is going), send SIGINT; (exit status, stdout, every stderr line)."""
    import signal

    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err = StderrLines(p)

    def going(seen: list[str]) -> bool:
        at = next((i for i, ln in enumerate(seen) if marker in ln), None)
        return at is not None and any(ln.startswith("source: ") and not ln.startswith("source: 0") for ln in seen[at:])

    err.until(going, timeout)
    p.send_signal(signal.SIGINT)
    p.wait(timeout=60)
    out = p.stdout.read()  # type: ignore[union-attr]
    return p.returncode, out, err.rest()

def pytest_sessionfinish(session, exitstatus):
    """Stop the ``gflow`` fork server this test process started, if it started one (tests/cli_fork.py)."""
    import cli_fork

    cli_fork.close()
