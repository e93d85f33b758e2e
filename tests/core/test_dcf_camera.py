"""dcf's estimate of the camera's own motion from the background (``camera_motion``; gflow_core.dcf.camera):
the fit recovers a known similarity of a real frame whatever the target's box does, refuses frames that say
nothing of the camera, gives the same bits in every call and process; with the option the tracker follows a
target through a camera jolt the motion prior alone loses, changes nothing on a still camera, and its state
(the last frame's grey levels) goes into a snapshot and comes back bit for bit."""

from __future__ import annotations

import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from gflow_core.dcf import camera as cam
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER
from gflow_core.evaluation.metrics import centre_error
from gflow_core.params import added_later
from gflow_core.tracker import FrameRng, step
from tests.conftest import data_dir
from tests.core.test_dcf_tracker import Scene, _texture, _track

#: the target's box in tiger1's frame 10 (x, y, w, h)
BOX = (120.0, 80.0, 60.0, 70.0)


def _tiger() -> np.ndarray:
    frames = sorted((data_dir("tiger1") / "frames").iterdir())
    return cv2.cvtColor(cv2.imread(str(frames[10])), cv2.COLOR_BGR2GRAY)


def _warp(grey: np.ndarray, deg: float, scale: float, shift: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """``grey`` rolled by ``deg`` (OpenCV's sense: counter-clockwise on the screen) and scaled by ``scale`` about
    the box's centre, then shifted: (the warped frame, the (2, 3) matrix x_t = A x + b)."""
    c = (BOX[0] + BOX[2] / 2.0, BOX[1] + BOX[3] / 2.0)
    m = cv2.getRotationMatrix2D(c, deg, scale)
    m[:, 2] += shift
    H, W = grey.shape
    return cv2.warpAffine(grey, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), m


def _corner_error(a: np.ndarray, b: np.ndarray, shape: tuple[int, int]) -> float:
    """px, the largest distance between where the two (2, 3) matrices put the frame's corners."""
    H, W = shape
    pts = np.array([[0.0, 0.0], [W - 1.0, 0.0], [0.0, H - 1.0], [W - 1.0, H - 1.0]])
    return float(np.hypot(*((pts @ a[:, :2].T + a[:, 2]) - (pts @ b[:, :2].T + b[:, 2])).T).max())


def test_the_fit_recovers_a_known_similarity_of_a_real_frame_whatever_the_target_does() -> None:
    """tiger1's frame rolled by 12 degrees, zoomed by 5 % and shifted by (6, -4) px: the fit puts the frame's
    corners within 1 px of where the warp put them, its angle within 0.3 degrees (clockwise on the screen is
    positive: OpenCV's -12), its scale within 0.5 %; the target's box, moved on its own by 15 px in the warped
    frame, is not in the fit."""
    g = _tiger()
    w, m = _warp(g, -12.0, 1.05, (6.0, -4.0))
    x, y, bw, bh = (int(v) for v in BOX)
    w[y + 15:y + bh, x:x + bw] = w[y:y + bh - 15, x:x + bw]  # the target's own motion
    mo = cam.estimate(g, w, BOX)
    assert mo.inliers >= cam.MIN_INLIERS and not mo.still
    assert _corner_error(mo.matrix, m, g.shape) < 1.0
    assert abs(math.degrees(mo.angle) - 12.0) < 0.3
    assert abs(math.exp(mo.log_scale) - 1.05) < 0.005
    assert np.hypot(*(mo.apply(np.array([[10.0, 20.0]])) - (np.array([[10.0, 20.0]]) @ m[:, :2].T + m[:, 2]))[0]) < 1.0


def test_frames_that_say_nothing_of_the_camera_give_the_identity() -> None:
    """Two frames of independent noise (no point tracks both ways), a flat frame (no corner) and a textured
    frame whose only texture is the target's box (no corner outside it) are refused: the identity with no
    inlier. The same frame twice is a still camera: the identity, with its inliers."""
    rng = np.random.default_rng(0)
    a, b = (rng.integers(0, 256, (200, 260), dtype=np.uint8) for _ in range(2))
    assert cam.estimate(a, b, (100.0, 80.0, 30.0, 36.0)) == cam.IDENTITY
    flat = np.full((200, 260), 90, np.uint8)
    assert cam.estimate(flat, flat, (100.0, 80.0, 30.0, 36.0)) == cam.IDENTITY
    boxed = flat.copy()
    boxed[80:116, 100:130] = np.clip(_texture(rng, 36, 30, 5.0), 0, 255).astype(np.uint8)
    assert cam.estimate(boxed, np.roll(boxed, 3, axis=1), (100.0, 80.0, 30.0, 36.0)) == cam.IDENTITY
    still = cam.estimate(a, a, (100.0, 80.0, 30.0, 36.0))
    assert still.still and still.inliers >= cam.MIN_INLIERS


_CHILD = """
import cv2, sys
import numpy as np
from gflow_core.dcf import camera as cam
from tests.core.test_dcf_camera import BOX, _tiger, _warp
g = _tiger()
w, _ = _warp(g, -7.0, 0.98, (-9.0, 5.0))
sys.stdout.write(cam.estimate(g, w, BOX).matrix.tobytes().hex())
"""


def test_the_fit_gives_the_same_bits_in_every_call_and_process() -> None:
    """RANSAC's draws are OpenCV's own, seeded on every call: two calls and another process (another OpenCV
    thread pool) give the same matrix bit for bit."""
    g = _tiger()
    w, _ = _warp(g, -7.0, 0.98, (-9.0, 5.0))
    m1, m2 = cam.estimate(g, w, BOX), cam.estimate(g, w, BOX)
    assert m1.matrix.tobytes() == m2.matrix.tobytes() and m1.inliers == m2.inliers and not m1.still
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, check=True)
    assert out.stdout == m1.matrix.tobytes().hex()


class Jolted(Scene):
    """The scene filmed by a camera that jolts: from frame ``at`` the whole frame (background and target) is
    shifted by ``jolt`` (dx, dy) px. With ``twin`` (x, y), a copy of the target stands still there in the
    background."""

    def __init__(self, path, at: int, jolt: tuple[int, int], twin: tuple[int, int] | None = None,
                 seed: int = 0) -> None:
        super().__init__(path, seed)
        self.at, self.jolt = at, jolt
        if twin is not None:
            self.bg[twin[1]:twin[1] + 36, twin[0]:twin[0] + 30] = self.target

    def shift(self, t: int) -> tuple[int, int]:
        return self.jolt if t >= self.at else (0, 0)

    def truth(self, t: int) -> tuple[float, float, float, float]:
        x, y, w, h = super().truth(t)
        dx, dy = self.shift(t)
        return (x + dx, y + dy, w, h)

    def frame(self, t: int) -> np.ndarray:
        dx, dy = self.shift(t)
        x, y, w, h = super().truth(t)
        img = self.bg.copy()
        img[int(round(y)):int(round(y)) + 36, int(round(x)):int(round(x)) + 30] = self.target
        img = np.roll(img, (dy, dx), axis=(0, 1))
        img += np.random.default_rng([self.seed, t]).normal(0.0, 3.0, img.shape)
        return np.clip(img, 0, 255).astype(np.uint8)


def test_a_camera_jolt_is_followed_with_the_camera_motion_and_lost_without() -> None:
    """A target moving 3 px a frame, and its still twin in the background 43 px right of and 30 px above where
    it will be at frame 12, when the camera jolts by (-40, 30) px: the twin lands where the target was
    predicted, the target 50 px away. With ``camera_motion`` the prediction moves with the jolt and every frame
    is within 4 px of the truth; without, the motion prior takes the twin."""
    sc = Jolted(lambda t: (110.0 + 3.0 * t, 90.0), 12, (-40, 30), twin=(175, 42))
    frames = [sc.frame(t) for t in range(24)]
    truth = np.array([sc.truth(t) for t in range(24)])
    _, on = _track(frames, sc.truth(0), DCFParams(camera_motion=True))
    assert centre_error(truth, np.array([e.box for e in on])).max() < 4.0
    assert all(e.target_state == "tracked" for e in on)
    _, off = _track(frames, sc.truth(0))
    assert centre_error(truth[12:], np.array([e.box for e in off[12:]])).max() > 20.0


def test_on_a_still_camera_the_option_changes_nothing() -> None:
    """A still camera (the frames' noise only): every frame's fit is the identity, and the boxes are those of
    the tracker without the option, bit for bit."""
    sc = Scene(lambda t: (120.0 + 3.0 * t, 90.0 + t))
    frames = [sc.frame(t) for t in range(12)]
    _, on = _track(frames, sc.truth(0), DCFParams(camera_motion=True))
    _, off = _track(frames, sc.truth(0))
    assert [e.box for e in on] == [e.box for e in off]


def test_the_last_frame_is_kept_and_goes_into_arrays_and_comes_back_bit_for_bit() -> None:
    """With ``camera_motion`` the state keeps the last frame's grey levels on every frame (not only while the
    track is tentative); a snapshot keeps them and the restored state steps as the original through a jolt."""
    sc = Jolted(lambda t: (110.0 + 3.0 * t, 90.0), 8, (-20, 15))
    frames = [sc.frame(t) for t in range(14)]
    p = DCFParams(camera_motion=True, confirm=0)
    st, _ = _track(frames[:5], sc.truth(0), p)
    assert st.last_grey is not None and st.last_grey.dtype == np.uint8 and st.last_grey.shape == frames[0].shape[:2]
    assert _track(frames[:5], sc.truth(0), DCFParams(confirm=0))[0].last_grey is None
    arrays, values = to_arrays(st)
    back = from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), p)
    assert back.last_grey is not None and np.array_equal(back.last_grey, st.last_grey)
    for t in range(5, 14):
        obs = TRACKER.observe(p, frames[t])
        st, e1 = step(TRACKER, p, st, obs, FrameRng(1, 7, t))
        back, e2 = step(TRACKER, p, back, obs, FrameRng(1, 7, t))
        assert e1 == e2
    assert np.array_equal(st.last_grey, cam.grey8(TRACKER.observe(p, frames[13]).grey))


def test_the_option_is_off_by_default_and_refused_when_not_a_boolean() -> None:
    """Off by default, so recordings made before it (whose plans lack it) re-run as they were; a value that is
    not true or false is refused in one line naming it."""
    from pipeline.runtime.tracker_block import block_values

    assert DCFParams().camera_motion is False and "camera_motion" not in added_later(DCFParams)
    assert block_values(DCFParams, {"camera_motion": "true"})["camera_motion"] is True
    with pytest.raises(ValueError) as e:
        block_values(DCFParams, {"camera_motion": "maybe"})
    assert str(e.value) == "camera_motion must be true or false, got 'maybe'"
