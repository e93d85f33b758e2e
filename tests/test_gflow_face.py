"""The face tracker end to end: `gflow learn gflow`, the built-in face model on real frames,
`gflow track --points-out`, `gflow eval --landmarks`, and the face outputs of the estimate."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from gflow_scenes import pose_estimates
from pipeline.cli.trackers.gflow import make_plan
from pipeline.io.modelfile import BUILTIN_MODELS, load_meta, load_model
from pipeline.runtime.inline import run_inline

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "david_indoor"
needs_data = pytest.mark.skipif(not (DATA / "landmarks.npz").is_file(),
                                reason="needs ../shared/data/david_indoor (frames and landmarks.npz)")
SCORED = (33, 133, 362, 263, 61, 291)


@pytest.fixture
def gflow(gflow_cmd):
    """Run the gflow command line: ``gflow("learn", ...)`` -> CompletedProcess (text), in a process of its own
    forked from one that has already imported the command line (tests/cli_fork.py)."""
    import subprocess

    import cli_fork

    def run(*args: str) -> subprocess.CompletedProcess:
        return cli_fork.run_command([*gflow_cmd, *args], capture_output=True, text=True, timeout=120)

    return run


def _synthetic_landmarks(path: Path, frames: int = 40) -> np.ndarray:
    """A landmark file in MediaPipe's layout: a random 468-point 'face' turning and changing shape."""
    rng = np.random.default_rng(0)
    face = rng.uniform(-1, 1, (468, 3)) * [20.0, 25.0, 8.0]
    face[[33, 263, 61, 291]] = [[-12, -8, 0], [12, -8, 0], [-7, 10, 0], [7, 10, 0]]
    morph = rng.standard_normal((468, 3))
    a = np.sin(np.linspace(0, 6, frames))
    x = face[None] + 0.8 * a[:, None, None] * morph[None]
    x[:, :, :2] += [160.0, 120.0]
    x[5] = np.nan  # a frame without a face
    np.savez(path, landmarks=x.astype(np.float32))
    return x


def test_learn_gflow_writes_a_morphable_face_model(tmp_path, gflow) -> None:
    _synthetic_landmarks(tmp_path / "landmarks.npz")
    with open(tmp_path / "groundtruth.csv", "w") as f:
        f.write("frame,x,y,w,h\n" + "".join(f"{t},140,95,40,50\n" for t in range(40)))
    out = tmp_path / "face.npz"
    r = gflow("learn", "gflow", str(tmp_path), "--boxes", "-k", "3", "--vertices", "50", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "k=3" in r.stdout and "n=50 vertices" in r.stdout and "39 frames" in r.stdout
    m = load_model(out)
    assert m.n_bases == 3 and m.n_vertices == 50 and set(SCORED) <= set(m.landmarks.tolist())
    assert m.reference_box is not None and m.morph_std is not None
    meta = load_meta(out)
    assert meta["k"] == 3 and meta["training_frames"] == 39 and meta["boxes"] == "yes"
    r = gflow("info", str(out))
    assert r.returncode == 0 and "50 vertices, 3 morph bases" in r.stdout


@pytest.mark.parametrize(("args", "message"), [
    (["--key", "points"], "no array 'points'"),
    (["-k", "0"], "-k must be a positive"),
    (["--vertices", "two"], "--vertices expects"),
    (["--frames", "100:200"], "none in --frames"),
])
def test_learn_gflow_bad_input_is_one_line(tmp_path, gflow, args, message) -> None:
    _synthetic_landmarks(tmp_path / "landmarks.npz")
    r = gflow("learn", "gflow", str(tmp_path / "landmarks.npz"), "--out", str(tmp_path / "m.npz"), *args)
    assert r.returncode != 0 and message in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


@pytest.mark.parametrize(("args", "rc", "message"), [
    (["-k", "50"], 2, "-k 50 morph bases need at least 50 frames with landmarks, got 39"),
    (["-k", "3", "--frames", "4:6"], 2, "got 1 in --frames 4:6"),
    (["--boxes", "{d}/far.csv"], 2, "no frame has both landmarks and a box"),
    (["--frames", "5:6"], 2, "no frame in --frames 5:6 has all its landmarks"),
    (["-k", "2", "--frames", "0:4"], 1, "a frame's landmarks all coincide"),  # found by the learning: its failure
])
def test_learn_gflow_exit_status_says_mistake_or_failure(tmp_path, gflow, args, rc, message) -> None:
    """A mistake in the command (too few training frames for -k, boxes on no training frame) is found before the
    learning begins (exit 2); training data the learning refuses is its failure (exit 1). Every refusal was exit 2."""
    x = _synthetic_landmarks(tmp_path / "landmarks.npz")
    x[2] = 0.0  # a frame's landmarks all in one point
    np.savez(tmp_path / "landmarks.npz", landmarks=x.astype(np.float32))
    (tmp_path / "far.csv").write_text("frame,x,y,w,h\n1000,140,95,40,50\n")
    r = gflow("learn", "gflow", str(tmp_path / "landmarks.npz"), "--out", str(tmp_path / "m.npz"), "-q",
              *[a.replace("{d}", str(tmp_path)) for a in args])
    assert r.returncode == rc, (r.returncode, r.stderr)
    assert r.stderr.strip() == r.stderr.strip().splitlines()[0] and "Traceback" not in r.stderr, r.stderr
    assert "gflow learn gflow: error: cannot learn a face model: " in r.stderr and message in r.stderr, r.stderr
    assert not (tmp_path / "m.npz").exists()


def test_learn_gflow_refuses_2d_landmarks(tmp_path, gflow) -> None:
    np.savez(tmp_path / "flat.npz", landmarks=np.zeros((5, 468, 2), np.float32))
    r = gflow("learn", "gflow", str(tmp_path / "flat.npz"), "--out", str(tmp_path / "m.npz"))
    assert r.returncode != 0 and "(frames, landmarks, 3)" in r.stderr and "Traceback" not in r.stderr


def test_eval_landmarks_on_a_hand_made_case(tmp_path, gflow) -> None:
    ref = np.full((3, 468, 3), np.nan, np.float32)
    for t in range(2):
        ref[t, :, :] = 0.0
        ref[t, [33, 133, 362, 263, 61, 291], :2] = [[100, 100], [110, 100], [130, 100], [150, 100], [110, 130],
                                                   [140, 130]]
    np.savez(tmp_path / "ref.npz", landmarks=ref)
    with open(tmp_path / "p.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "landmark", "x", "y"])
        for t, shift in ((0, 0.0), (1, 5.0)):  # frame 1: every point 5 px to the right
            for i in SCORED:
                w.writerow([t, i, ref[t, i, 0] + shift, ref[t, i, 1]])
    r = gflow("eval", "--landmarks", str(tmp_path / "ref.npz"), "--points", str(tmp_path / "p.csv"), "--json")
    assert r.returncode == 0, r.stderr
    import json

    s = json.loads(r.stdout)
    # frame 0 exact, frame 1: 5 px over an eye distance of 50 -> NME (0 + 0.1) / 2; frame 2 has no reference
    assert s == {"frames": 2, "missing": 0, "nme": pytest.approx(0.05), "px": pytest.approx(2.5)}
    r = gflow("eval", "--landmarks", str(tmp_path / "ref.npz"), "--points", str(tmp_path / "p.csv"))
    assert "landmark NME" in r.stdout and "0.0500" in r.stdout and "2.50 px" in r.stdout
    np.savez(tmp_path / "bad.npz", marks=ref)
    r = gflow("eval", "--landmarks", str(tmp_path / "bad.npz"), "--points", str(tmp_path / "p.csv"))
    assert r.returncode != 0 and "no array 'landmarks'" in r.stderr and "Traceback" not in r.stderr
    r = gflow("eval", "--landmarks", str(tmp_path / "ref.npz"))
    assert r.returncode != 0 and "go together" in r.stderr


def test_the_built_in_face_model_is_the_shipped_file() -> None:
    m = load_model(BUILTIN_MODELS["face"])
    meta = load_meta(BUILTIN_MODELS["face"])
    assert m.n_bases == 5 and m.landmarks is not None and set(SCORED) <= set(m.landmarks.tolist())
    assert m.reference_box is not None and "david_indoor" in meta["source"] and meta["k"] == 5
    assert BUILTIN_MODELS["face"].stat().st_size < 100_000  # small derived data, not the landmarks


@needs_data
def test_face_tracker_on_real_frames_reports_face_outputs(tmp_path) -> None:
    """The first 12 frames of david_indoor with the default graph (the built-in face model): the
    estimate carries the points with their landmark indices, angles, expression and confidence,
    and the first box is the initial box."""
    from pipeline.io.landmarks import read_landmarks

    init = [169.0, 76.0, 46.0, 60.0]
    over = {"source": {"kind": "folder", "path": str(DATA / "frames"), "stop": 12},
            "proposal": {"init": init, "seed": 1}, "filter": {"init": init, "seed": 1}}
    run_inline(make_plan("gflow", over), recording=str(tmp_path / "run.mcap"))
    est = pose_estimates(tmp_path / "run.mcap")
    assert sorted(est) == list(range(12))
    model = load_model(BUILTIN_MODELS["face"])
    ref = read_landmarks(DATA)
    np.testing.assert_allclose(est[0].box, init, atol=1e-9)
    errs = []
    for t, e in est.items():
        lm = e.landmarks.array()
        pts = e.mean_points.array()
        assert np.array_equal(lm, model.landmarks) and pts.shape == (model.n_vertices, 2)
        assert len(e.expression) == model.n_bases - 1 and all(np.isfinite(e.yaw_pitch_roll))
        assert 0.0 <= e.confidence <= 1.0 and e.target_state in ("tracked", "occluded", "lost")
        at = {int(i): k for k, i in enumerate(lm)}
        p = pts[[at[i] for i in SCORED]]
        r = ref[t, list(SCORED), :2]
        errs.append(np.linalg.norm(p - r, axis=1).mean() / np.linalg.norm(ref[t, 33, :2] - ref[t, 263, :2]))
    # on the first frames the face is placed from the box and followed: well under the 0.72 of a still template
    assert np.mean(errs) < 0.15, errs
    assert est[11].target_state == "tracked"


@needs_data
def test_face_processes_with_two_shards_equal_inline_with_one(tmp_path) -> None:
    """With the face model's departures on (contrast-normalised frames, texels reverting toward the
    first look, the morph prior, the frontal reset) and the background replica, two proposal
    processes and a filter process give exactly the inline run's estimates and states."""
    from gflow_scenes import payloads, plan_for
    from pipeline.runtime.launcher import Launcher
    from pipeline.runtime.transport import ZenohSettings, free_port

    frames = tmp_path / "frames"
    frames.mkdir()
    for t in range(10):
        (frames / f"{t:06d}.jpg").write_bytes((DATA / "frames" / f"{t:06d}.jpg").read_bytes())
    params = dict(n_experts=8, n_samples=4, background=True, seed=2)
    init = (169.0, 76.0, 46.0, 60.0)
    mp, inline = tmp_path / "mp.mcap", tmp_path / "inline.mcap"
    res = Launcher(plan_for(frames, init, shards=2, **params),
                   zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=str(mp), progress=False,
                   startup_timeout=60).run()
    assert res.ok, res.exits
    run_inline(plan_for(frames, init, shards=1, **params), recording=str(inline))
    a, b = payloads(mp), payloads(inline)
    assert len(a) == 2 * 10 and a == b


def test_overlays_draw_the_rotated_axes_and_the_angles() -> None:
    """The render stage's and `gflow render`'s overlays of a face estimate: every expert's points,
    the mean's, the three rotated axes from l (the paper's fig. 2) and the angles in the status line."""
    from gflow_core.gflow.face_pose import rotation_from_angles
    from gflow_msgs.messages import Frame, Header, NDArray, PoseEstimate
    from gflow_msgs.foxglove import LINE_LIST, POINTS
    from gflow_msgs.annotations import annotations_for

    r = rotation_from_angles(30.0, 0.0, 0.0)
    h = Header(stream="s", seq=4, stamp_ns=0)
    pts = np.zeros((3, 5, 2), np.float32)
    est = PoseEstimate(header=h, box=(0.0, 0.0, 10.0, 10.0), pose=(0, 0.52, 0, 50.0, 40.0, 60.0, 0.0),
                       pose_std=(0.0,) * 7, rotation=tuple(r.ravel()), spread_px=0.5, ess=3.0,
                       expert_points=NDArray.of(pts), mean_points=NDArray.of(pts[0]),
                       log_credibility=NDArray.of(np.zeros(3)), parents=NDArray.of(np.arange(3)),
                       landmarks=NDArray.of(np.arange(5, dtype=np.int32)), yaw_pitch_roll=(30.0, -0.2, 1.6),
                       expression=(0.5,))
    frame = Frame(header=h, image=NDArray.of(np.zeros((80, 100), np.uint8)))
    ann = annotations_for(frame, est, None)
    axes = [p for p in ann.points if p.type == LINE_LIST]
    assert len(axes) == 3 and sum(p.type == POINTS for p in ann.points) == 2
    # the x axis turned 30 degrees of yaw: from l = (50, 40), 0.5 c_1 cos(30) to the right
    x_end = axes[0].points[1]
    assert x_end.x - 0.5 == pytest.approx(50.0 + 30.0 * np.cos(np.radians(30.0)))
    assert "yaw 30 pitch 0 roll 2" in ann.texts[0].text


@needs_data
@pytest.mark.parametrize(("extra", "message"), [
    (["--tracker", "appearance"], "face points of --tracker gflow"),
    (["--tracker", "gflow", "--model", "ellipsoid"], "needs a learned face model"),
])
def test_points_out_needs_a_face_model(tmp_path, gflow, extra, message) -> None:
    r = gflow("track", str(DATA), "--init", "169,76,46,60", "--out", str(tmp_path / "b.csv"), "--points-out",
              str(tmp_path / "p.csv"), "--stop", "2", *extra)
    assert r.returncode != 0 and message in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "b.csv").exists()


@needs_data
def test_track_points_out_then_eval_landmarks(tmp_path, gflow) -> None:
    """The user's path: gflow track --points-out, then gflow eval --landmarks on the same frames."""
    pts = tmp_path / "p.csv"
    r = gflow("track", str(DATA), "--tracker", "gflow", "--init", "169,76,46,60", "--seed", "1", "--stop", "6",
              "--experts", "6", "--out", str(tmp_path / "b.csv"), "--points-out", str(pts), "--no-record",
              "--inline", "-q")
    assert r.returncode == 0, r.stderr
    from pipeline.io.landmarks import read_points

    got = read_points(pts)
    model = load_model(BUILTIN_MODELS["face"])
    assert sorted(got) == list(range(6)) and all(set(v) == set(model.landmarks.tolist()) for v in got.values())
    r = gflow("eval", "--landmarks", str(DATA), "--points", str(pts), "--frames", "0:6", "--json")
    assert r.returncode == 0, r.stderr
    import json

    s = json.loads(r.stdout)
    assert s["frames"] == 6 and s["missing"] == 0 and s["nme"] < 0.15


def test_scale_walk_is_relative_to_the_initial_face() -> None:
    """``scale_walk`` sets the random walk's std of the scale c_1 to that fraction of the initial
    |c_1| (so a face twice as large walks twice as far), leaves the morph coefficients' stds alone,
    and a negative or infinite value is refused naming it."""
    from gflow_core.gflow.geometry import COEF
    from gflow_core.gflow.params import GFlowParams
    from gflow_core.gflow.tracker import model_setup

    model = load_model(BUILTIN_MODELS["face"])
    k = model.n_bases
    stds = []
    for box in ((169.0, 76.0, 46.0, 60.0), (100.0, 40.0, 92.0, 120.0)):
        s = model_setup(GFlowParams(scale_walk=0.01), box, (240, 320), model)
        c1 = abs(float(s.pose0[COEF][0]))
        std = s.cfg.prior_std(k)[COEF]
        assert std[0] == pytest.approx(0.01 * c1)
        stds.append(std[0])
        plain = model_setup(GFlowParams(scale_walk=0.0), box, (240, 320), model).cfg.prior_std(k)[COEF]
        assert plain[0] == pytest.approx(0.2) and np.array_equal(std[1:], plain[1:])
    assert stds[1] == pytest.approx(2.0 * stds[0], rel=0.02)
    for bad in (-0.01, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="scale_walk"):
            GFlowParams(scale_walk=bad)


@needs_data
def test_texel_noise_adapt_learns_less_where_the_frame_does_not_fit() -> None:
    """``texel_noise_adapt``: a frame the experts' texels explain (the first frame again) is learned
    exactly as with the fixed ``sigma_w``; a frame they do not (its grey levels inverted) moves the
    texels less."""
    import cv2

    from gflow.backends import protocol_tracker
    from gflow_core.tracker import FrameRng

    img = cv2.imread(str(DATA / "frames" / "000000.jpg"))
    moved = {}
    for adapt in (False, True):
        tracker, params, res = protocol_tracker("gflow", {"texel_noise_adapt": adapt, "lost_guard": False,
                                                          "n_experts": 4, "n_samples": 2})
        state, _ = tracker.init(params, tracker.observe(params, img), (169.0, 76.0, 46.0, 60.0), FrameRng(1, 0, 0), res)
        for name, frame in (("same", img), ("inverted", 255 - img)):
            obs = tracker.observe(params, frame)
            prop = tracker.propose(params, state, obs, FrameRng(1, 0, 1))
            new, _ = tracker.update(params, state, prop, obs, FrameRng(1, 0, 1))
            # every expert starts with the first look's texels (no jitter), which the prediction keeps
            moved[adapt, name] = float(np.abs(new.experts.tex_mean - state.experts.tex_mean[0]).mean())
    assert moved[True, "same"] == moved[False, "same"]
    assert moved[True, "inverted"] < 0.8 * moved[False, "inverted"]
