"""The default tracker (dcf) on video that holds nothing like its target: frames of fresh random noise.
The box it was given on the first frame holds noise that never comes back, so from the next frame on
the tracker's own model must say the box holds clutter: low confidence at once, and the target
judged hidden once its doubt has lasted ``hidden_after`` frames. And on real video the first frames
are still tracked with confidence (the same model, with a target there)."""

from __future__ import annotations

import csv
import os
import sys
from pathlib import Path

import cv2
import numpy as np

from gflow_core.dcf.params import DCFParams
import cli_fork

ROOT = Path(__file__).resolve().parent.parent


def track(tmp_path: Path, source: Path, init: str, stop: int) -> list[list[str]]:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "track", str(source), "--tracker", "dcf", "--init", init, "--out",
                              "b.csv", "--stop", str(stop), "--inline", "--no-record", "-q"], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    with open(tmp_path / "b.csv") as f:
        return list(csv.reader(f))[1:]


def test_random_noise_is_not_reported_tracked(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    (tmp_path / "noise").mkdir()
    for i in range(30):
        cv2.imwrite(str(tmp_path / "noise" / f"{i:04d}.png"), rng.integers(0, 256, (240, 320, 3), dtype=np.uint8))
    rows = track(tmp_path, tmp_path / "noise", "100,80,40,60", 30)
    assert len(rows) == 30 and rows[0][6] == "tracked"
    assert all(float(r[5]) < 0.5 for r in rows[1:]), [r[5] for r in rows[:10]]
    after = DCFParams().hidden_after
    assert all(r[6] in ("occluded", "lost") for r in rows[after:]), [r[6] for r in rows[:10]]


def test_real_video_starts_tracked_with_confidence(tmp_path: Path, caviar1: Path) -> None:
    rows = track(tmp_path, caviar1, "129,71,30,79", 20)
    assert [r[6] for r in rows] == ["tracked"] * 20
    assert min(float(r[5]) for r in rows) > 0.5, [r[5] for r in rows]
