"""Results come only from the run's own stages: a peer on the run's zenoh network (no run key)
that publishes Estimate messages on the run's estimate topic does not get its boxes into the
CSV or the recording's results; what it sent is recorded, counted and reported.

Real processes: ``gflow track`` as processes over zenoh on loopback, and an outsider process
(``tests/outsider_peer.py``) that finds the run as ``gflow topics`` does and publishes on its
estimate topic. Each run has its own runtime folder, so the outsider finds this run only.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path
import cli_fork

ROOT = Path(__file__).resolve().parent.parent
INIT = "129,71,30,79"
FRAMES = 60


def env_for(tmp_path: Path) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
                GFLOW_RUNTIME_DIR=str(tmp_path / "runtime"))


def rows(path: Path) -> dict[int, list[str]]:
    with open(path) as f:
        return {int(r[0]): r[1:] for r in list(csv.reader(f))[1:]}


def test_estimates_from_outside_the_run_are_left_out_and_reported(tmp_path: Path, caviar1: Path) -> None:
    env = env_for(tmp_path)
    ref = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "track", str(caviar1), "--init", INIT, "--stop",
                                str(FRAMES), "--out", "ref.csv", "--inline", "--no-record", "-q"], cwd=tmp_path, env=env,
                               capture_output=True, text=True, timeout=120)
    assert ref.returncode == 0, ref.stderr
    # the outsider is started first and the run only once it says it is ready: on a busy machine its own
    # start-up (python, numpy, zenoh) took longer than the run's 60 frames, and it published after the run ended
    peer = subprocess.Popen([sys.executable, str(ROOT / "tests" / "outsider_peer.py"), str(FRAMES + 40), "0.005"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert peer.stdout is not None and peer.stdout.readline().strip() == "ready", peer.communicate(timeout=60)
    track = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "track", str(caviar1), "--init", INIT,
                              "--stop", str(FRAMES), "--realtime", "--out", "run.csv", "--record", "run.mcap"],
                             cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peer_out, peer_err = peer.communicate(timeout=120)
    out, err = track.communicate(timeout=120)
    assert peer.returncode == 0 and "published" in peer_out, (peer_out, peer_err)
    assert track.returncode == 0, err[-2000:]
    got, want = rows(tmp_path / "run.csv"), rows(tmp_path / "ref.csv")
    assert sorted(got) == list(range(FRAMES)), f"{len(got)} rows for {FRAMES} frames"
    assert got == want  # the run's own boxes, bit for bit as --inline gives them
    said = [ln for ln in out.splitlines() if "outside the run" in ln]
    assert said and str(FRAMES + 40) in said[0] and "estimate" in said[0], out
    # the recording keeps what the outsider sent, and its results leave it out
    from pipeline.io.mcap_io import iter_records
    from pipeline.recording.results import estimates

    est = [r for r in iter_records(tmp_path / "run.mcap") if r.type == "Estimate"]
    assert len(est) == FRAMES + FRAMES + 40
    assert sorted(estimates(tmp_path / "run.mcap")) == list(range(FRAMES))
    boxes = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "boxes", "run.mcap", "--out", "b.csv"],
                                 cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert boxes.returncode == 0, boxes.stderr
    assert rows(tmp_path / "b.csv") == want
    info = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "info", "run.mcap"], cwd=tmp_path, env=env,
                                capture_output=True, text=True, timeout=60)
    assert info.returncode == 0, info.stderr
    line = [ln for ln in info.stdout.splitlines() if "outside the run" in ln]
    assert line and str(FRAMES + 40) in line[0], info.stdout
