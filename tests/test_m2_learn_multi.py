"""`gflow learn m2 SEQ1 SEQ2 ... --boxes`: one model from several training sequences, with
appearance exemplars; bad combinations of sources and box files get a one-line error."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gflow_core.synthetic import SyntheticScene
from pipeline.io.modelfile import load_meta, load_model
from pipeline.recording.results import write_boxes
import cli_fork

N = 12


def _dataset(root: Path, seed: int) -> Path:
    scene = SyntheticScene(width=160, height=120, n_frames=N, seed=seed, noise=4.0)
    (root / "frames").mkdir(parents=True)
    for t in range(N):
        cv2.imwrite(str(root / "frames" / f"{t:04d}.png"), scene.render(t))
    write_boxes(root / "groundtruth.csv", {t: scene.truth_box(t) for t in range(N)})
    return root


def test_learn_from_two_sequences_with_each_folders_boxes(tmp_path, gflow_cmd) -> None:
    a, b = _dataset(tmp_path / "a", 3), _dataset(tmp_path / "b", 5)
    out = tmp_path / "m.npz"
    r = cli_fork.run_command([*gflow_cmd, "learn", "m2", str(a), str(b), "--boxes", "-K", "4", "--max-points", "60",
                              "--out", str(out), "-q"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "appearance d'_k median" in r.stdout
    m = load_model(out)
    meta = load_meta(out)
    assert m.K == 4 and m.appearance is not None and m.appearance.patches.shape[0] == 4
    assert meta["sequences"] == 2 and meta["source"].count(";") == 1
    assert meta["boxes"] == f"{a / 'groundtruth.csv'};{b / 'groundtruth.csv'}"
    # one box file per source works the same; a count that matches neither is a one-line error
    r = cli_fork.run_command([*gflow_cmd, "learn", "m2", str(a), str(b), "--boxes", str(a / "groundtruth.csv"),
                              "--out", str(tmp_path / "x.npz")], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "--boxes lists 1 file(s) for 2 source(s)" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "x.npz").exists()
    (tmp_path / "c" / "frames").mkdir(parents=True)
    r = cli_fork.run_command([*gflow_cmd, "learn", "m2", str(a), str(tmp_path / "c"), "--boxes", "--out",
                              str(tmp_path / "x.npz")], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "groundtruth.csv" in r.stderr and "Traceback" not in r.stderr
