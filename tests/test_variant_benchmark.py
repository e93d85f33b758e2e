"""``gflow benchmark --variant``: the frame transforms, and the real CLI on grey frames of ../shared/data/crossing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from gflow_core.evaluation.variants import VARIANTS, grey, select_variant
from pipeline.io.frame_readers import folder_frames
from pipeline.io.mcap_io import iter_records
from gflow_msgs.messages import Frame, decode

from conftest import data_dir

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


def test_grey_is_the_luma_of_every_pixel():
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    g = grey(bgr)
    assert g.shape == (12, 16) and g.dtype == np.uint8
    # Y = 0.299 R + 0.587 G + 0.114 B, to within rounding
    y = 0.299 * bgr[..., 2] + 0.587 * bgr[..., 1] + 0.114 * bgr[..., 0]
    assert np.abs(g.astype(float) - y).max() <= 1.0
    assert grey(g) is g
    with pytest.raises(ValueError, match="not"):
        grey(np.zeros((4, 4, 4), np.uint8))
    assert select_variant("grey") is VARIANTS["grey"]
    with pytest.raises(ValueError, match=r"unknown variant 'gray' .*known: grey"):
        select_variant("gray")


def test_bad_variant_is_a_one_line_error():
    r = subprocess.run([*GFLOW, "benchmark", "no/such/folder", "--variant", "gray"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["gflow benchmark: error: unknown variant 'gray' in --variant (known: grey)"]


def test_grey_variant_tracks_grey_frames_and_prints_the_table(tmp_path):
    crossing = data_dir("crossing")
    original = cv2.imread(str(dict(folder_frames(crossing / "frames"))[0]), cv2.IMREAD_COLOR)
    assert original[..., 0].tolist() != original[..., 1].tolist()  # a colour sequence: the check below can fail
    out = tmp_path / "out"
    r = subprocess.run([*GFLOW, "benchmark", str(crossing), "--variant", "grey", "--trackers", "dcf", "--opencv",
                        "none", "--frames", "0:6", "--inline", "--seed", "1", "--markdown", "--no-fps", "-q",
                        "--out-dir", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "| crossing | 6 |" in r.stdout and "**static box**" in r.stdout
    assert "inline, seed 1, the grey variant of every sequence" in r.stdout
    # the frames the tracker was given, from its recording: three equal channels, the grey levels of the originals
    frames = [m for m in (decode(rec.data) for rec in iter_records(out / "crossing" / "dcf.mcap") if rec.type == "Frame")
              if isinstance(m, Frame)]
    assert len(frames) == 6
    first = frames[0].image.array()
    assert first.shape == original.shape
    assert (first[..., 0] == first[..., 1]).all() and (first[..., 1] == first[..., 2]).all()
    assert np.array_equal(first[..., 0], grey(original))
    # the derived frames lived in a temporary folder: only the runs' boxes and recordings are kept
    assert sorted(p.name for p in (out / "crossing").iterdir()) == ["dcf.csv", "dcf.mcap", "static_box.csv"]
