"""`gflow plot --gt` leaves a gap in the centre-error line where the target is absent in the truth (a row of no
size, which `gflow eval` leaves out) and where the estimate is missing or of no size (a miss): the line was drawn
straight across those frames, as if the error between its ends had been measured there."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.evaluation.scored_boxes import ScoredBoxes
import cli_fork

ROOT = Path(__file__).resolve().parents[1]

B = (10.0, 10.0, 20.0, 20.0)


def test_error_series_is_nan_where_the_target_is_absent_or_the_estimate_a_miss() -> None:
    from pipeline.cli.commands.plot import error_series

    truth = ScoredBoxes({0: B, 1: B, 3: B, 4: B, 5: B, 9: B}, frozenset({2, 6}))
    est = {0: (12.0, 10.0, 20.0, 20.0), 1: B, 2: B, 3: (math.nan,) * 4, 5: (1.0, 1.0, 0.0, 0.0), 6: B, 7: B}
    frames, err, miss = error_series(sorted(est), truth, est)
    # frames 0..7 of the estimates with a row of truth (7 has none: not in the series; 9 is past the last estimate)
    assert frames.tolist() == [0, 1, 2, 3, 4, 5, 6]
    np.testing.assert_array_equal(err, [2.0, 0.0, np.nan, np.nan, np.nan, np.nan, np.nan])
    # 3: NaN box, 4: no estimate, 5: a box of no size are misses; 2 and 6 the target absent, not misses
    assert miss.tolist() == [False, False, False, True, True, True, False]


def test_error_series_of_no_estimate_or_no_truth_is_empty() -> None:
    from pipeline.cli.commands.plot import error_series

    frames, err, miss = error_series([], ScoredBoxes({0: B}, frozenset()), {})
    assert frames.size == err.size == miss.size == 0
    frames, err, miss = error_series([0, 1], ScoredBoxes({}, frozenset({0, 1})), {0: B, 1: B})
    assert frames.tolist() == [0, 1] and np.isnan(err).all() and not miss.any()


def gflow(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args], cwd=cwd, env=env, capture_output=True,
                                text=True, timeout=120, stdin=subprocess.DEVNULL)


@pytest.fixture
def demo(demo8: Path) -> Path:
    return demo8


def test_the_plotted_line_breaks_on_the_frames_with_the_target_absent(demo: Path, tmp_path: Path) -> None:
    """The figure's own line data: frames 3 and 4 absent in the truth are NaN in it, not left out of its x."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.cli.main import main

    gt = tmp_path / "gt.csv"
    gt.write_text("".join(f"{f},150,115,{0 if f in (3, 4) else 30},30\n" for f in range(8)))
    out = tmp_path / "p.png"
    assert main(["plot", str(demo), str(out), "--gt", str(gt)]) == 0 and out.is_file()
    try:
        line = plt.gcf().axes[0].get_lines()[0]
        x, y = np.asarray(line.get_xdata()), np.asarray(line.get_ydata(), dtype=float)
        assert x.tolist() == list(range(8)), x
        assert np.isnan(y[[3, 4]]).all() and np.isfinite(y[[0, 1, 2, 5, 6, 7]]).all(), y
        assert "target absent on 2, left out" in plt.gcf().axes[0].get_title()
    finally:
        plt.close("all")


def test_matplotlib_caches_its_fonts_in_this_test_process_own_folder(tmp_path: Path) -> None:
    """Test processes side by side (`pytest -n 2`), and the gflow commands they start, wrote one font cache in the
    user's matplotlib folder at once; each test process has its own (tests/conftest.py), which what it starts
    inherits."""
    import matplotlib

    own = Path(os.environ["MPLCONFIGDIR"])
    assert own.is_dir() and f"gflow-mpl-{os.getpid()}-" in own.name
    assert Path(matplotlib.get_cachedir()) == own
    r = cli_fork.run_command([sys.executable, "-c", "import matplotlib; print(matplotlib.get_cachedir())"],
                             capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and Path(r.stdout.strip()) == own, (r.stdout, r.stderr)
    assert [p for p in own.parent.glob(f"gflow-mpl-{os.getpid()}-*")] == [own]


def test_a_script_importing_conftest_leaves_no_matplotlib_folder_behind(tmp_path: Path) -> None:
    """A script that imported tests/conftest.py for a helper (synthetic_sequence, damaged_copy) left its folder in
    the temporary folder: it was removed only by pytest_unconfigure, which such a script never runs."""
    env = dict(os.environ, TMPDIR=str(tmp_path))
    env.pop("MPLCONFIGDIR")
    r = cli_fork.run_command([sys.executable, "-c", "import os, sys; sys.path.insert(0, sys.argv[1]); import conftest; "
                              "print(os.environ['MPLCONFIGDIR'])", str(ROOT / "tests")], capture_output=True, text=True,
                             timeout=60, env=env)
    assert r.returncode == 0 and Path(r.stdout.strip()).parent == tmp_path, (r.stdout, r.stderr)
    assert not list(tmp_path.iterdir())
