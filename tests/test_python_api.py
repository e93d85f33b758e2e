"""The Python API (``from gflow import Tracker, track``): the boxes of ``gflow track --inline``
bit for bit, errors as exceptions with the command line's messages."""

from __future__ import annotations

import sys

import cv2
import numpy as np
import pytest

from gflow import Estimate, GflowError, Tracker, UnknownParameter, UnusableFrameError, track
from pipeline.io.frame_readers import folder_frames
from pipeline.io.mcap_io import iter_records
from pipeline.recording.results import read_boxes
from gflow_msgs.messages import decode
import cli_fork


def cli_estimates(cmd: list[str], tmp_path, name: str = "run") -> dict[int, object]:
    """Run a gflow command that records, and return its estimate messages by frame."""
    rec = tmp_path / f"{name}.mcap"
    out = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *cmd, "--record", str(rec)],
                               capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    return {r.seq: decode(r.data) for r in iter_records(rec) if r.type in ("Estimate", "PoseEstimate")}


def assert_same(api: list[Estimate], cli: dict[int, object]) -> None:
    assert [e.frame for e in api] == sorted(cli)
    for e in api:
        m = cli[e.frame]
        assert (e.box, e.confidence, e.target_state, e.phase) == (tuple(m.box), m.confidence, m.target_state,
                                                                   m.state), f"frame {e.frame}"


#: the first frame of each tracker's run: a few dozen frames before the man in black passes in front of the target
#: (frames ~95-120), so every run has him in it; the appearance model needs longer to be sure of her to call him an
#: occluder
START = {"appearance": 40, "gflow": 80, "chamfer": 80, "m2": 80}


@pytest.mark.data
@pytest.mark.slow
@pytest.mark.parametrize("tracker", ["appearance", "gflow", "chamfer", "m2"])
def test_the_api_over_caviar1_gives_gflow_tracks_boxes(caviar1, tmp_path, tracker, request) -> None:
    """Frames read with cv2.imread, the ground-truth box of frame START (Tracker.init's frame_index), seed 1:
    every estimate of caviar1's frames START-129 equals gflow track --inline --seed 1 --start START --stop 130's
    (box, confidence, target state, phase), bit for bit (m2: a model learned from caviar1 frames 0-59). The
    frames are those where a man in black walks in front of the target: each tracker's run leaves the plain
    'track' phase there (occluded, lost or redetect), so its coasting and re-detection are compared too."""
    gt = read_boxes(caviar1 / "groundtruth.csv")
    start, stop = START[tracker], 130
    box = gt[start]
    model = {"model": str(request.getfixturevalue("caviar1_m2_model"))} if tracker == "m2" else {}
    cli = cli_estimates(["track", str(caviar1), "--tracker", tracker, "--init", ",".join(map(str, box)), "--seed",
                         "1", "--inline", "--start", str(start), "--stop", str(stop), "--out",
                         str(tmp_path / "boxes.csv"), "-q", *[a for k, v in model.items() for a in (f"--{k}", v)]],
                        tmp_path)
    t = Tracker(tracker, seed=1, **model)
    files = folder_frames(caviar1 / "frames")
    api = [t.init(cv2.imread(str(files[start][1])), box, frame_index=start)]
    api += [t.update(cv2.imread(str(f))) for _, f in files[start + 1:stop]]
    assert len(api) == stop - start and api[0].frame == start
    assert_same(api, cli)
    assert {e.phase for e in api} - {"init", "track"}, "no frame left the track phase: the run compares too little"


def _learn(cmd: list[str]) -> None:
    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "learn", "m2", *cmd, "-q"], capture_output=True,
                             text=True, timeout=300)
    assert r.returncode == 0, r.stderr


def assert_same_patch(api: list[Estimate], cli: dict[int, object]) -> None:
    """Every field of an m2 patch model's estimates, bit for bit."""
    assert_same(api, cli)
    for e in api:
        m = cli[e.frame]
        assert (e.extras["k"], e.extras["ess"], e.extras["log_evidence"], e.extras["n"]) == (m.k, m.ess,
                                                                                            m.log_evidence, m.n)
        assert e.extras["alpha"] == tuple(m.alpha)


@pytest.mark.data
def test_an_m2_patch_model_gives_gflow_tracks_estimates(tmp_path) -> None:
    """M2 with a whole-frame patch model (AVLetters mouths, sec. 5.2) runs on the protocol like every
    tracker: track() of a folder with two frames missing and every tenth frame blanked twice equals
    gflow track --inline's estimates, every field, bit for bit: the exemplar k, the ESS, the evidence,
    and the coasted frames (the lost ones and the blank ones)."""
    from conftest import data_dir
    from gflow_core.m2.patch_protocol import PatchParams
    from pipeline.io.datasets import read_avletters, write_frames
    from stages.source import SourceParams

    src = data_dir("avletters") / "anya.npz"
    if not src.is_file():
        pytest.skip(f"real data not available: {src} is missing")
    model = tmp_path / "mouth.npz"
    _learn([str(src), "--reps", "1,2", "--letters", "A-C", "--metric", "shuffle", "-K", "6", "--patch-size", "20x15",
            "--out", str(model)])
    test, _ = read_avletters(src, [3], "A-C")
    folder = write_frames(tmp_path / "rep3", test.frames)
    for lost in (7, 30):
        (folder / f"{lost:06d}.png").unlink()
    cli = cli_estimates(["track", str(folder), "--tracker", "m2", "--model", str(model), "--init", "0,0,80,60",
                         "--seed", "5", "--particles", "150", "--set", "source.blank_every=10", "--set",
                         "source.blank_count=2", "--inline", "--out", str(tmp_path / "m.csv"), "-q"], tmp_path)
    source = SourceParams(kind="folder", path=str(folder), blank_every=10, blank_count=2)
    api = list(track(source, init=(0, 0, 80, 60), tracker="m2", seed=5, model=str(model), particles=150))
    assert len(api) == len(test) and sorted(cli) == list(range(len(test)))
    assert_same_patch(api, cli)
    assert {e.frame for e in api if e.phase == "coast"} == {7, 30} | {f for f in range(len(test)) if f % 10 >= 8}
    assert len({e.extras["k"] for e in api}) >= 3  # the exemplar follows the mouth: a run that compares something
    t = Tracker("m2", seed=5, model=str(model), crop="box")
    assert t.params == PatchParams(crop="box") and t.state is None
    with pytest.raises(UnknownParameter, match="unknown parameter lam of PatchParams"):
        Tracker("m2", model=str(model), lam=0.3)
    with pytest.raises(GflowError, match="particles must be an integer >= 1, got 0"):
        Tracker("m2", model=str(model), particles=0)


@pytest.mark.data
def test_an_m2_patch_model_cut_from_the_box_gives_gflow_tracks_estimates(caviar1, tmp_path) -> None:
    """A patch model learned from boxes (the patch is cut from the initial box, ``crop: box``, read
    from the model file): Tracker fed cv2.imread frames, with one frame lost (coast()), equals gflow
    track --inline over the folder without that frame, every field, bit for bit."""
    model = tmp_path / "patch.npz"
    _learn([str(caviar1), "--boxes", str(caviar1 / "groundtruth.csv"), "--frames", "0:60", "-K", "4", "--metric",
            "shuffle", "--patch-size", "16x32", "--out", str(model)])
    files = [f for _, f in folder_frames(caviar1 / "frames")[:12]]
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, f in enumerate(files):
        if k != 4:
            (folder / f.name).symlink_to(f)
    box = (129.0, 71.0, 30.0, 79.0)
    cli = cli_estimates(["track", str(folder), "--tracker", "m2", "--model", str(model), "--particles", "150",
                         "--init", ",".join(map(str, box)), "--seed", "3", "--inline", "--out",
                         str(tmp_path / "b.csv"), "-q"], tmp_path)
    t = Tracker("m2", seed=3, model=str(model), particles=150)
    assert t.params.crop == "box"
    api = [t.init(cv2.imread(str(files[0])), box)]
    api += [t.coast() if k == 4 else t.update(cv2.imread(str(f))) for k, f in enumerate(files) if k > 0]
    assert [e.frame for e in api] == sorted(cli) == list(range(12)) and api[4].phase == "coast"
    assert len({e.extras["k"] for e in api}) > 1  # the exemplar changes: a run that compares something
    assert_same_patch(api, cli)
    assert all(e.box == box for e in api)


def test_track_equals_tracker_and_gflow_track_on_the_synthetic_scene(tmp_path) -> None:
    """track() of a source reads the frames the source stage sends; on the built-in scene it starts
    from the scene's true box and equals Tracker fed the same frames, and gflow track."""
    from gflow_core.synthetic import SyntheticScene

    ests = list(track("synthetic", tracker="gflow", seed=2, stop=12, n_experts=6, n_samples=4))
    scene = SyntheticScene()
    t = Tracker("gflow", seed=2, n_experts=6, n_samples=4)
    by_hand = [t.init(scene.render(0), scene.truth_box(0))] + [t.update(scene.render(k)) for k in range(1, 12)]
    assert [(e.frame, e.box) for e in ests] == [(e.frame, e.box) for e in by_hand]
    assert [e.phase for e in ests] == ["init"] + ["track"] * 11
    assert ests[-1].extras["expert_points"].shape[0] == 6 and ests[0].target_state == "tracked"


@pytest.mark.parametrize("tracker", ["gflow", "appearance", "chamfer", "dcf"])
def test_lost_frames_are_coasted_as_the_pipeline_does(tmp_path, tracker) -> None:
    """A folder with frame 5 missing: the pipeline coasts over it and so does track()."""
    from gflow_core.synthetic import SyntheticScene

    scene = SyntheticScene(width=160, height=120, seed=3)
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(10):
        if k != 5:
            cv2.imwrite(str(folder / f"{k:06d}.png"), scene.render(k))
    box = scene.truth_box(0)
    extra = {"gflow": ["--experts", "5", "--samples", "3"], "appearance": [], "chamfer": [], "dcf": []}[tracker]
    cli = cli_estimates(["track", str(folder), "--tracker", tracker, "--init", ",".join(map(str, box)), "--seed",
                         "3", "--inline", "--out", str(tmp_path / "b.csv"), "-q", *extra], tmp_path)
    params = {"gflow": {"n_experts": 5, "n_samples": 3}, "appearance": {}, "chamfer": {}, "dcf": {}}[tracker]
    api = list(track(folder, init=box, tracker=tracker, seed=3, **params))
    assert_same(api, cli)
    assert api[5].frame == 5 and api[5].phase == "coast"


def test_a_uniform_frame_cannot_start_a_track_and_is_coasted_over_later() -> None:
    from gflow_core.synthetic import SyntheticScene

    scene = SyntheticScene()
    t = Tracker("gflow", seed=0, n_experts=4, n_samples=2)
    with pytest.raises(UnusableFrameError, match="every pixel is 0"):
        t.init(np.zeros((240, 320, 3), np.uint8), scene.truth_box(0))
    t.init(scene.render(0), scene.truth_box(0))
    est = t.update(np.full((240, 320, 3), 255, np.uint8))
    assert est.phase == "coast" and est.frame == 1
    assert t.problems == [(1, "frame 1: every pixel is 255 (a blank or saturated frame carries no information "
                              "about the pose, and would overwrite the textures); coasting")]
    assert t.coast().frame == 2 and t.update(scene.render(3)).phase == "track"


def test_a_value_needing_more_memory_than_the_machine_has_is_refused_by_the_constructor() -> None:
    """Tracker("dcf", template=10**9) was made, then its first frame grew arrays until the process died; the
    constructor refuses it as gflow track does, one line naming the value and the largest that fits."""
    for name, kw, says in (("dcf", {"template": 10**9}, "template must be at most"),
                           ("dcf", {"particles": 10**13}, "particles must be at most"),
                           ("dcf", {"scales": 10**12 + 1}, "scales must be at most"),
                           ("appearance", {"particles": 10**13}, "particles must be at most"),
                           ("chamfer", {"particles": 10**13}, "particles must be at most")):
        with pytest.raises(GflowError, match=says) as e:
            Tracker(name, **kw)
        assert "on this machine" in str(e.value) and "\n" not in str(e.value)
        assert str(e.value).endswith(f"got {next(iter(kw.values()))}")


def test_a_box_narrower_than_chamfers_calibration_is_said_as_such() -> None:
    """A 1-pixel-wide box was 'calibration box ... does not overlap the 64x48 image', of a box that does: it covers
    fewer pixels than the edges' thresholds are calibrated on."""
    frame = np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    with pytest.raises(GflowError) as e:
        Tracker("chamfer").init(frame, (10, 10, 1, 20))
    assert str(e.value) == ("frame 0: the box 10,10,1,20 covers 1x20 pixels of the 64x48 image: the edges' thresholds "
                            "are calibrated on at least 2x2 of its pixels")
    Tracker("dcf").init(frame, (10, 10, 1, 20))  # no calibration on the box's pixels


def test_errors_are_exceptions_with_the_command_lines_messages(tmp_path, caviar1) -> None:
    with pytest.raises(UnknownParameter, match="unknown parameter n_expert of GFlowParams"):
        Tracker("gflow", n_expert=3)
    with pytest.raises(GflowError, match="sigma_w must be finite and > 0, got -1"):
        Tracker("gflow", sigma_w=-1.0)
    with pytest.raises(GflowError, match="unknown tracker 'csrt'"):
        Tracker("csrt")
    with pytest.raises(UnknownParameter, match="unknown parameter lamb of AppearanceParams"):
        Tracker("appearance", lamb=3.0)
    with pytest.raises(GflowError, match="n_scales must be odd"):
        Tracker("appearance", n_scales=2)
    with pytest.raises(UnknownParameter, match="unknown parameter lamb of ChamferParams"):
        Tracker("chamfer", lamb=3.0)
    with pytest.raises(GflowError, match="lam must be positive, got -1"):
        Tracker("chamfer", lam=-1.0)
    with pytest.raises(GflowError, match="tracker m2 needs model=MODEL.npz"):
        Tracker("m2")
    # the box and the source: the very lines gflow track prints
    bad = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "track", str(caviar1), "--init", "400,10,20,20",
                                "--out", str(tmp_path / "b.csv"), "--inline", "-q"], capture_output=True, text=True)
    assert bad.returncode == 2
    with pytest.raises(GflowError) as e:
        next(track(caviar1, init=(400, 10, 20, 20)))
    assert str(e.value) in bad.stderr and "lies outside the 384x288 image" in str(e.value)
    with pytest.raises(GflowError, match="source not found: nowhere"):
        next(track("nowhere", init=(1, 2, 3, 4)))
    with pytest.raises(GflowError, match=r"expected \(H, W\) or \(H, W, 3\) uint8, got float64"):
        Tracker("gflow").init(np.zeros((20, 20)), (1, 1, 5, 5))
    # one line each, and the classes users catch
    assert "\n" not in str(e.value) and issubclass(GflowError, ValueError) and issubclass(UnknownParameter, TypeError)


def test_the_api_starts_no_process() -> None:
    """Tracker runs in this process, also for a tracker run through its stages."""
    import psutil

    from gflow_core.synthetic import SyntheticScene

    before = set(psutil.Process().children(recursive=True))
    scene = SyntheticScene()
    t = Tracker("appearance", seed=1)
    t.init(scene.render(0), scene.truth_box(0))
    for k in range(1, 5):
        t.update(scene.render(k))
    assert set(psutil.Process().children(recursive=True)) == before
