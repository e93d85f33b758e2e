"""What a stage process pays for at start-up: only its own stage's imports."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _fresh(code: str) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_a_source_or_recorder_process_does_not_import_scipy():
    out = _fresh("import sys, pipeline.runtime.node\n"
                 "from stages.registry import get_stage_class\n"
                 "get_stage_class('source'); get_stage_class('particle.proposal')\n"
                 "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))")
    assert out == "[]", f"scipy imported at start-up: {out[:300]}"


def test_a_filter_stage_imports_scipy_when_a_runner_takes_it_not_on_a_frame():
    """SciPy's gamma functions are imported where visibility is judged, so a process that only reads
    gflow_core.visibility does not import them; a filter stage that judges it imports them when a runner
    takes it (``check_prepare``), not on the frame of its first judgement. m2's patch filter judges none, and
    the default tracker's stage leaves SciPy out of its start-up (it judges with them only in a search)."""
    out = _fresh("import sys, pipeline.runtime.node\n"
                 "from stages.base import StageContext\n"
                 "from stages.registry import get_stage_class\n"
                 "dcf = get_stage_class('dcf.filter')\n"
                 "d = dcf(dcf.Params(init=(10, 10, 20, 20), seed=1), StageContext('filter', 't'))\n"
                 "d.check_prepare()\n"
                 "after_dcf = 'scipy.special' in sys.modules\n"
                 "cls = get_stage_class('chamfer.filter')\n"
                 "st = cls(cls.Params(init=(10, 10, 20, 20), seed=1), StageContext('filter', 't'))\n"
                 "before = 'scipy.special' in sys.modules\n"
                 "st.check_prepare()\n"
                 "from stages.patch_filter import PatchFilterStage\n"
                 "print(after_dcf, before, 'scipy.special' in sys.modules, PatchFilterStage.preload_gamma)")
    assert out == "False False True False"


def test_the_appearance_tracker_imports_scipy_when_taken_not_on_a_frame():
    """The appearance filter judges visibility first on a frame deep in a run (caviar1's frame 111): its stage
    and the Python API import SciPy's gamma functions when they take the tracker, before the first frame."""
    out = _fresh("import sys, pipeline.runtime.node\n"
                 "from stages.base import StageContext\n"
                 "from stages.registry import get_stage_class\n"
                 "cls = get_stage_class('appearance.filter')\n"
                 "st = cls(cls.Params(init=(10, 10, 20, 20), seed=1), StageContext('filter', 't'))\n"
                 "before = 'scipy.special' in sys.modules\n"
                 "st.check_prepare()\n"
                 "print(before, 'scipy.special' in sys.modules)")
    assert out == "False True"
    out = _fresh("import sys, gflow\n"
                 "gflow.Tracker('appearance', seed=1)\n"
                 "print('scipy.special' in sys.modules)")
    assert out == "True"


def test_the_zygote_can_preload_every_stage_kind_and_still_fork():
    """The zygote forks a stage only while it has one thread, and it imports each kind its run will start
    (``_preload``) first: a kind whose import starts a thread (OpenCV's workers, which a colour conversion at
    import starts) leaves every stage of its runs to a new interpreter, about 0.9 s of CPU each (G-flow's,
    until dcf's colour-name table was made on first use rather than at import). Each kind and the recorder
    are preloaded in one fresh process, held to one BLAS thread as the zygote is, the threads counted after each."""
    out = _fresh("import os\n"
                 "for var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):\n"
                 "    os.environ[var] = '1'\n"
                 "import pipeline.runtime.node\n"
                 "from pipeline.runtime.zygote import _preload\n"
                 "from stages.registry import STAGES\n"
                 "threads = lambda: len(os.listdir('/proc/self/task'))\n"
                 "started = []\n"
                 "for kind in [*STAGES, 'recorder']:\n"
                 "    _preload([kind])\n"
                 "    if threads() > 1 and not started:\n"
                 "        started.append(kind)\n"
                 "print(len(list(STAGES)), started)")
    n, started = out.split(" ", 1)
    assert int(n) >= 10 and started == "[]", f"importing a stage kind started a thread: {started}"


def test_every_kind_resolves_lazily_to_its_stage_class():
    from stages.base import Stage
    from stages.registry import STAGES, get_stage_class

    kinds = list(STAGES)
    assert {"source", "preprocess", "particle.filter", "particle.proposal", "appearance.filter", "appearance.proposal",
            "gflow.filter", "gflow.proposal"} <= set(kinds)
    for kind in kinds:
        cls = get_stage_class(kind)
        assert issubclass(cls, Stage) and cls.kind == kind
    with pytest.raises(KeyError, match="known kinds: .*particle.filter"):
        get_stage_class("no.such.kind")


def test_malloc_is_tuned_for_frame_sized_buffers():
    from pipeline.runtime.memory import keep_freed_memory

    if not sys.platform.startswith("linux"):
        pytest.skip("glibc malloc tuning is Linux-only")
    assert keep_freed_memory() is True
    assert keep_freed_memory() is True  # idempotent


def _cold_run(tmp_path: Path, tag: str, **env: str) -> tuple[float, list[str]]:
    """``gflow run demo`` (5 frames) in a new process: CPU seconds of every process of it, and its start-up trace."""
    import resource

    trace = tmp_path / f"trace-{tag}.txt"
    e = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
             GFLOW_STARTUP_TRACE=str(trace), **env)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "demo", "--set", "source.frames=5",
                        "--set", "filter.particles=50", "--record", str(tmp_path / f"{tag}.mcap"),
                        "--listen", "tcp/127.0.0.1:0"], capture_output=True, text=True, env=e, timeout=180, cwd=tmp_path)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert r.returncode == 0, r.stderr
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return cpu, trace.read_text().splitlines()


def test_stage_processes_fork_from_the_zygote_and_cost_less_cpu(tmp_path):
    """Every stage process of a gflow command is forked from its zygote (pipeline/runtime/zygote.py),
    not started as a new interpreter: the whole run takes clearly less CPU than with GFLOW_ZYGOTE=0."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the zygote is Linux-only (PR_SET_CHILD_SUBREAPER)")
    cpu_fork, lines = _cold_run(tmp_path, "fork")
    spawned = {ln.split()[-1] for ln in lines if " launcher spawned " in ln}
    forked = {ln.split()[1] for ln in lines if ln.endswith(" node forked")}
    assert len(spawned) == 6 and spawned <= forked, lines  # source, preprocess, proposal, filter, render, recorder
    cpu_exec, lines = _cold_run(tmp_path, "exec", GFLOW_ZYGOTE="0")
    assert not any(ln.endswith(" node forked") for ln in lines)
    assert cpu_fork < 0.8 * cpu_exec, (cpu_fork, cpu_exec)


def test_a_stage_stopped_while_it_is_being_born_exits_quietly():
    """A stop that reaches a stage forked by the zygote before its handlers are set (the launcher
    stopping a run whose source could not open) ends it with 130 and no traceback on stderr."""
    code = ("import os, signal, socket\n"
            "from pipeline.runtime import zygote\n"
            "mask = signal.pthread_sigmask(signal.SIG_BLOCK, zygote._STOPS)  # as the zygote forks it\n"
            "os.kill(os.getpid(), signal.SIGINT)  # the launcher's stop, pending until the stage takes it\n"
            "a, b = socket.socketpair()\n"
            "zygote._stage({'plan': 'none.json', 'name': 'x', 'env': {}}, os.dup(2), os.getppid(), a, mask)\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT)
    assert r.returncode == 130 and "Traceback" not in r.stderr, (r.returncode, r.stderr)
