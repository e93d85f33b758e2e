"""``gflow benchmark --variant``: the frame transforms, and the real CLI on grey frames of ../shared/data/crossing."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from gflow_core.evaluation.variants import (BLUR_LENGTH, JPEG_QUALITY, NOISE_READ, NOISE_SHOT, VARIANTS, blur, grey, half,
                                           noise, select_variant)
from pipeline.io.frame_readers import folder_frames
from pipeline.recording.results import read_boxes
from pipeline.io.mcap_io import iter_records
from gflow_msgs.messages import Frame, decode

from conftest import data_dir
import cli_fork

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
    with pytest.raises(ValueError, match=r"unknown variant 'gray' .*known: grey, blur, fast, small"):
        select_variant("gray")
    with pytest.raises(ValueError, match=r"unknown variant 'slow'"):
        select_variant("fast+slow")
    with pytest.raises(ValueError, match="twice"):
        select_variant("blur+blur")


def test_bad_variant_is_a_one_line_error():
    r = cli_fork.run_command([*GFLOW, "benchmark", "no/such/folder", "--variant", "gray"], capture_output=True, text=True,
                             timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["gflow benchmark: error: unknown variant 'gray' in --variant (known: grey, "
                                             "blur, fast, small, noise, or several joined by '+'); 'none' is the "
                                             "sequences as they are, 'all' every kind (none, grey, blur, fast, small, "
                                             "noise, fast+blur)"]


def test_grey_variant_tracks_grey_frames_and_prints_the_table(tmp_path):
    crossing = data_dir("crossing")
    original = cv2.imread(str(dict(folder_frames(crossing / "frames"))[0]), cv2.IMREAD_COLOR)
    assert original[..., 0].tolist() != original[..., 1].tolist()  # a colour sequence: the check below can fail
    out = tmp_path / "out"
    r = cli_fork.run_command([*GFLOW, "benchmark", str(crossing), "--variant", "grey", "--trackers", "dcf", "--opencv",
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


def test_blur_smears_each_frame_its_own_way_and_the_same_way_every_run():
    rng = np.random.default_rng(3)
    bgr = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    a, b = blur(bgr, 7), blur(bgr, 8)
    assert a.shape == bgr.shape and a.dtype == np.uint8
    assert np.array_equal(a, blur(bgr.copy(), 7))  # drawn from the frame's index: the same on every run
    assert not np.array_equal(a, b)  # another frame, another kernel
    # a line kernel of at least BLUR_LENGTH[0] px averages noise down; the mean level stays
    assert a.astype(float).std() < 0.8 * bgr.astype(float).std()
    assert abs(a.astype(float).mean() - bgr.astype(float).mean()) < 2.0
    assert BLUR_LENGTH[0] >= 2.0
    with pytest.raises(ValueError, match="index"):
        blur(bgr, -1)


def test_small_halves_frames_and_boxes_and_fast_keeps_every_third_frame_numbered_on():
    bgr = np.zeros((12, 20, 3), np.uint8)
    bgr[2:6, 4:12] = 200
    h = half(bgr)
    assert h.shape == (6, 10, 3)
    assert h[1:3, 2:6].min() == 200 and h[3:, :].max() == 0 and h[:, 6:].max() == 0  # the block at half its place, size
    assert half(bgr[:11]).shape == (6, 10, 3)  # an odd side rounds
    small, fast = VARIANTS["small"], VARIANTS["fast"]
    assert small.truth({4: (10.0, 20.0, 30.0, 40.0)}, 4) == {4: (5.0, 10.0, 15.0, 20.0)}
    assert not small.keeps_truth and not fast.keeps_truth and VARIANTS["grey"].keeps_truth
    # fast from frame 10: 10, 13, 16 kept as 10, 11, 12; 11, 12 and anything before 10 dropped
    assert [fast.index(f, 10) for f in (9, 10, 11, 12, 13, 16)] == [None, 10, None, None, 11, 12]
    truth = {f: (float(f), 0.0, 5.0, 5.0) for f in range(0, 20, 5)}  # labelled every 5th frame
    assert fast.truth(truth, 0) == {0: (0.0, 0.0, 5.0, 5.0), 5: (15.0, 0.0, 5.0, 5.0)}
    assert np.array_equal(fast.transform(bgr, 3), bgr)


def _benchmark(seq: Path, variant: str, frames: str, out: Path) -> subprocess.CompletedProcess:
    return cli_fork.run_command([*GFLOW, "benchmark", str(seq), "--variant", variant, "--trackers", "dcf", "--opencv",
                                 "none", "--frames", frames, "--inline", "--seed", "1", "--json", "--no-fps", "-q",
                                 "--out-dir", str(out)], capture_output=True, text=True, timeout=120)


def _frames_given(recording: Path) -> list[np.ndarray]:
    return [m.image.array() for m in (decode(rec.data) for rec in iter_records(recording) if rec.type == "Frame")
            if isinstance(m, Frame)]


def test_fast_and_small_variants_give_the_tracker_the_kept_frames_and_score_the_carried_truth(tmp_path):
    crossing = data_dir("crossing")
    originals = dict(folder_frames(crossing / "frames"))
    # fast: frames 2..10 of the original are 2, 5, 8 kept, numbered 2, 3, 4
    r = _benchmark(crossing, "fast", "2:11", tmp_path / "fast")
    assert r.returncode == 0, r.stderr
    frames = _frames_given(tmp_path / "fast" / "crossing" / "dcf.mcap")
    assert len(frames) == 3
    for got, f in zip(frames, (2, 5, 8)):
        assert np.array_equal(got, cv2.imread(str(originals[f]), cv2.IMREAD_COLOR))
    boxes = (tmp_path / "fast" / "crossing" / "dcf.csv").read_text().splitlines()[1:]
    assert [int(line.split(",")[0]) for line in boxes] == [2, 3, 4]
    rows = {row["tracker"]: row for row in json.loads(r.stdout)["rows"] if row["sequence"] == "crossing"}
    assert rows["dcf"]["frames"] == 3
    # small: the frames at half size, the truth's box halved (the first frame's box starts the tracker)
    r = _benchmark(crossing, "small", "0:4", tmp_path / "small")
    assert r.returncode == 0, r.stderr
    frames = _frames_given(tmp_path / "small" / "crossing" / "dcf.mcap")
    first = cv2.imread(str(originals[0]), cv2.IMREAD_COLOR)
    assert len(frames) == 4 and frames[0].shape == half(first).shape
    truth = read_boxes(crossing / "groundtruth.csv")[0]
    got = [float(v) for v in (tmp_path / "small" / "crossing" / "dcf.csv").read_text().splitlines()[1].split(",")[1:5]]
    assert np.allclose(got, [v / 2 for v in truth], atol=0.01)


def test_a_combination_applies_each_in_turn_and_keeps_and_scales_as_both():
    """fast+blur: every 3rd frame, each blurred as blur blurs its original index; small+fast: half size too."""
    rng = np.random.default_rng(5)
    bgr = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    fb = select_variant(" fast + blur ")
    assert (fb.name, fb.step, fb.scale) == ("fast+blur", 3, 1.0) and not fb.keeps_truth
    assert np.array_equal(fb.transform(bgr, 9), blur(bgr, 9))  # the kept frame, blurred by its own index
    assert [fb.index(f, 2) for f in (2, 3, 5, 8)] == [2, None, 3, 4]
    sf = select_variant("small+fast+grey")
    assert (sf.step, sf.scale) == (3, 0.5)
    assert np.array_equal(sf.transform(bgr, 0), grey(half(bgr)))
    assert sf.truth({0: (10.0, 20.0, 8.0, 6.0), 1: (0.0, 0.0, 1.0, 1.0), 3: (4.0, 4.0, 2.0, 2.0)}, 0) == {
        0: (5.0, 10.0, 4.0, 3.0), 1: (2.0, 2.0, 1.0, 1.0)}


def test_noise_is_a_sensors_noise_then_jpeg_the_same_bits_every_run():
    """A flat frame gets noise whose spread grows with the level (as a sensor's), the same draw for the same
    frame index and another for another index; the frame is then JPEG-compressed (8 x 8 blocks, so a flat
    frame stays near its level); an equal-channel frame stays grey, a colour one gets noise of its own per
    channel."""
    dark, bright = np.full((64, 64, 3), 30, np.uint8), np.full((64, 64, 3), 220, np.uint8)
    a, b = noise(dark, 7), noise(bright, 7)
    assert a.shape == dark.shape and a.dtype == np.uint8
    assert np.array_equal(a, noise(dark, 7)) and not np.array_equal(a, noise(dark, 8))
    for img, out in ((dark, a), (bright, b)):
        assert (out[..., 0] == out[..., 1]).all() and (out[..., 0] == out[..., 2]).all()
        assert abs(float(out.mean()) - float(img[0, 0, 0])) < 1.5
    # the spread before the codec is sqrt(a I + b); the codec smooths it, but keeps the order
    s_dark, s_bright = float(a[..., 0].std()), float(b[..., 0].std())
    assert 1.0 < s_dark < np.sqrt(NOISE_SHOT * 30 + NOISE_READ ** 2)
    assert s_bright > 1.3 * s_dark
    colour = np.dstack([dark[..., 0], np.full((64, 64), 120, np.uint8), bright[..., 0]])
    c = noise(colour, 3)
    assert not np.array_equal(c[..., 0].astype(int) - 30, c[..., 2].astype(int) - 220)
    # a grey (H, W) frame stays (H, W)
    g = noise(dark[..., 0], 1)
    assert g.shape == (64, 64) and g.dtype == np.uint8
    with pytest.raises(ValueError, match="index"):
        noise(dark, -1)
    with pytest.raises(ValueError, match="not"):
        noise(np.zeros((4, 4, 4), np.uint8), 0)
    assert VARIANTS["noise"].keeps_truth and str(JPEG_QUALITY) in VARIANTS["noise"].describe
