"""M2 models on targets of another size: the kernel floor of learning (``gflow learn m2 --kernel-floor``,
:func:`gflow_core.m2.kernel.fit_kernels`'s ``min_rho``) and edges read at the model's resolution
(``preprocess.match_resolution``, :func:`gflow_core.features.resampled_edges`)."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from gflow_core import features
from gflow_core.contour.params import EdgeParams
from gflow_core.m2.chamfer import chamfer_distance
from gflow_core.m2.curves import Curves
from gflow_core.m2.dynamics import random_walk
from gflow_core.m2.kernel import fit_kernels
from gflow_core.m2.model import M2Model
import cli_fork


def _outline(scale: int) -> np.ndarray:
    """A (60 scale, 40 scale) uint8 frame with a bright 'walker' (an ellipse over a rectangle) drawn at
    ``scale`` times the size of scale 1, from an 8x finer canvas averaged down."""
    U = 8 * scale
    img = np.full((60 * U, 40 * U), 40, np.uint8)
    cv2.ellipse(img, (20 * U, 22 * U), (6 * U, 14 * U), 0, 0, 360, 200, -1)
    cv2.rectangle(img, (16 * U, 24 * U), (24 * U, 45 * U), 200, -1)
    return cv2.resize(img, (40 * scale, 60 * scale), interpolation=cv2.INTER_AREA)


def test_upsample_to_its_own_grid_is_the_image_itself() -> None:
    """Read back on the grid it came from, an image is unchanged, bilinear or nearest (the mapping back
    is exact)."""
    img = np.random.default_rng(3).uniform(0, 50, (17, 23)).astype(np.float32)
    assert np.array_equal(features.upsample_to(img, img.shape), img)
    e = (img > 25).astype(np.uint8) * 255
    assert np.array_equal(features.upsample_to(e, e.shape, nearest=True), e)


def test_resampled_edges_measure_a_twice_larger_target_as_the_model_did() -> None:
    """An exemplar taken from a target's edges, on the same target drawn twice as large: read at half
    resolution (``resampled_edges``, f = 0.5), the exemplar scaled onto it and moved by 2 full px is as
    far from the edges as the exemplar moved by 1 px on the small target, in the small target's px^2 (to
    the map back's interpolation, measured 0.23-0.30 px^2); read at full resolution it is 4-5 times as far
    (the quantity the model's d_k were not learned on)."""
    small, large = _outline(1), _outline(2)
    e1 = features.edge_map(small, 50, 150, 1.0)
    r, c = np.nonzero(e1)
    pts = np.stack([c, r], 1).astype(np.float64)  # (P, 2) the exemplar, (x, y) px of the small frame
    cham1 = features.chamfer_image(e1, "quadratic")
    # a point x of the small frame is at 2 x + 1/2 on the large one (pixel centres, an area-averaged 2x)
    on_large = 2.0 * pts + 0.5
    _, cham_res = features.resampled_edges(large, 0.5, (50.0, 150.0), 1.0, 80.0, "quadratic", 100.0)
    _, cham_full = features.edges_and_chamfer(large, (50.0, 150.0), 1.0, 80.0, "quadratic", 100.0)
    for shift in ((1.0, 0.0), (0.0, 1.0), (1.0, 1.0)):
        d = np.array(shift)
        rho1 = chamfer_distance(cham1, (pts + d)[None])[0]
        rho_res = chamfer_distance(cham_res, (on_large + 2 * d)[None])[0]
        rho_full = chamfer_distance(cham_full, (on_large + 2 * d)[None])[0]
        # the map back interpolates the resampled chamfer image once more: about a quarter px^2 more
        assert abs(rho_res - rho1) < 0.35, (shift, rho1, rho_res)
        assert rho_full > 3 * rho1 and rho_full > 2.5 * rho_res, (shift, rho1, rho_res, rho_full)


def test_resample_1_is_the_frame_itself() -> None:
    """``resample`` 1 reads the frame's own edges (no resampling: bit for bit the default path)."""
    g = _outline(1)
    a = features.edges_and_chamfer(g, (50.0, 150.0), 1.0, 80.0, "quadratic", 100.0)
    b = features.edges_and_chamfer(g, (50.0, 150.0), 1.0, 80.0, "quadratic", 100.0, resample=1.0)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


def _model(train_scale: float) -> M2Model:
    return M2Model(metric="chamfer", kernel="moments", exemplars=Curves.from_list([np.zeros((3, 2)), np.ones((3, 2))]),
                   d=np.array([2.0, 2.0]), sigma=np.array([1.0, 1.0]), pi=np.array([0.5, 0.5]),
                   markov=np.full((2, 2), 0.5), dynamics=random_walk(1.0, 0.01, 0.01),
                   ref_size=np.array([16.0, 42.0]), train_scale=train_scale)


def test_match_scale_is_one_within_the_training_sizes_and_1_over_s0_beyond() -> None:
    m = _model(1.25)
    assert m.match_scale((0, 0, 16, 42)) == 1.0
    assert m.match_scale((0, 0, 20, 52.5)) == 1.0  # s0 = 1.25, the largest training target's
    assert m.match_scale((0, 0, 32, 84)) == pytest.approx(0.5)
    assert _model(float("inf")).match_scale((0, 0, 32, 84)) == 1.0  # files of format 2 and older: not known
    assert EdgeParams(model_scale=0.5).resample == 1.0  # off unless match_resolution
    assert EdgeParams(model_scale=0.5, match_resolution=True).resample == 0.5
    with pytest.raises(ValueError, match="model_scale"):
        EdgeParams(model_scale=0.0)


def test_a_cluster_at_the_pixel_floor_gets_the_pooled_kernel() -> None:
    """Distances of the pixel grid (mean 0.3 px^2, little spread: d in the tens) get the pooled fit with
    min_rho 0.5, their own without; a cluster above the floor keeps its own either way."""
    rng = np.random.default_rng(0)
    tight = 0.01 * rng.chisquare(30, 40)       # sigma^2 chi^2_30, mean 0.3
    wide = 0.5 * rng.chisquare(3, 40)          # mean 1.5
    rho = np.concatenate([tight, wide])
    labels = np.repeat([0, 1], 40)
    own = fit_kernels(rho, labels, 2)
    floored = fit_kernels(rho, labels, 2, min_rho=0.5)
    pooled = fit_kernels(rho, np.zeros(80, np.int64), 1)
    assert own.d[0] > 15 and not own.pooled.any()
    assert floored.pooled.tolist() == [True, False]
    assert (floored.d[0], floored.sigma[0]) == (pooled.d[0], pooled.sigma[0])
    assert (floored.d[1], floored.sigma[1]) == (own.d[1], own.sigma[1])
    with pytest.raises(ValueError, match="min_rho"):
        fit_kernels(rho, labels, 2, min_rho=-1.0)


def _learn(seq: Path, out: Path, *more: str) -> M2Model:
    from pipeline.io.modelfile import load_model

    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "learn", "m2", str(seq), "--boxes",
                              str(seq / "groundtruth.csv"), "-K", "20", "--out", str(out), "-q", *more],
                             capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    m = load_model(out)
    assert isinstance(m, M2Model)
    return m


@pytest.mark.data
@pytest.mark.slow
def test_the_kernel_floor_lets_a_crossing_model_follow_caviar1(crossing, caviar1, tmp_path) -> None:
    """Learned on crossing's 16x42 px walker, two kernels are the pixel grid's (mean distance about 0.33
    px^2, d over 20) and their exemplar is the MAP one on nearly every frame of caviar1, where the box
    rides above the walker (--kernel-floor 0, as models learned before the floor); with the default floor,
    0.5, they get the pooled kernel and the box follows her (frames 0-79, seed 1)."""
    import gflow
    from pipeline.io.frame_readers import folder_frames
    from pipeline.recording.results import read_boxes

    plain = _learn(crossing, tmp_path / "plain.npz", "--kernel-floor", "0")
    floored = _learn(crossing, tmp_path / "floor.npz")
    assert (plain.d * plain.sigma ** 2).min() < 0.5 and plain.d.max() > 20
    assert (floored.d * floored.sigma ** 2).min() >= 0.5 and floored.d.max() < 5
    gt = read_boxes(caviar1 / "groundtruth.csv")
    files = folder_frames(caviar1 / "frames")[:80]

    def cle(model: Path) -> float:
        t = gflow.Tracker("m2", seed=1, model=str(model))
        boxes = [t.init(cv2.imread(str(files[0][1])), gt[0]).box] + [t.update(cv2.imread(str(f))).box
                                                                      for _, f in files[1:]]
        c = np.array([[b[0] + b[2] / 2, b[1] + b[3] / 2] for b in boxes])
        g = np.array([[gt[i][0] + gt[i][2] / 2, gt[i][1] + gt[i][3] / 2] for i in range(len(boxes))])
        return float(np.hypot(*(c - g).T).mean())

    before, after = cle(tmp_path / "plain.npz"), cle(tmp_path / "floor.npz")
    assert after < 4.0 < 6.0 < before, (before, after)


@pytest.mark.data
@pytest.mark.slow
def test_match_resolution_is_the_same_through_the_api_and_gflow_track(caviar1, caviar1_m2_model, tmp_path) -> None:
    """A first box 1.6 times caviar1's walker (beyond the model's training sizes, so model_scale < 1):
    gflow track --set preprocess.match_resolution=true and the Python API's match_resolution=True give the
    same boxes over 20 frames (to the boxes file's 2 decimals), and not those of the frame's own
    resolution."""
    import gflow
    from pipeline.io.frame_readers import folder_frames
    from pipeline.io.modelfile import load_model
    from pipeline.recording.results import read_boxes

    x, y, w, h = read_boxes(caviar1 / "groundtruth.csv")[0]
    box = (x - 0.3 * w, y - 0.3 * h, 1.6 * w, 1.6 * h)
    m = load_model(caviar1_m2_model)
    assert isinstance(m, M2Model) and m.match_scale(box) < 0.7
    files = folder_frames(caviar1 / "frames")[:20]

    def api(match: bool) -> list:
        t = gflow.Tracker("m2", seed=1, model=str(caviar1_m2_model), match_resolution=match)
        return [t.init(cv2.imread(str(files[0][1])), box).box] + [t.update(cv2.imread(str(f))).box for _, f in files[1:]]

    out = tmp_path / "boxes.csv"
    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "track", str(caviar1), "--tracker", "m2", "--model",
                              str(caviar1_m2_model), "--init", ",".join(f"{v:g}" for v in box), "--seed", "1", "--inline",
                              "--stop", "20", "--out", str(out), "-q", "--set", "preprocess.match_resolution=true"],
                             capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    cli = read_boxes(out)
    on = api(True)
    # the boxes file keeps 2 decimals
    assert np.allclose([cli[i] for i in range(20)], on, rtol=0, atol=0.0051)
    assert on != api(False)
