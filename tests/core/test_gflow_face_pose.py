"""Head angles, expression and the following box (face_pose.py); the landmark error (landmark_error.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.gflow.face_pose import expression, following_box, rotation_from_angles, yaw_pitch_roll
from gflow_core.gflow.geometry import make_pose, rotation_matrices
from gflow_core.gflow.landmark_error import landmark_score

NOSE = np.array([0.0, 0.0, -1.0])  # the model's forward direction (toward the camera)
EYES = np.array([1.0, 0.0, 0.0])  # the eye line, image left to right


@pytest.mark.parametrize("ypr", [(20.0, 0.0, 0.0), (0.0, 15.0, 0.0), (0.0, 0.0, 10.0), (-35.0, 12.0, -7.0),
                                 (170.0, -60.0, 179.0)])
def test_angles_round_trip(ypr) -> None:
    r = rotation_from_angles(*ypr)
    np.testing.assert_allclose(yaw_pitch_roll(r), ypr, atol=1e-9)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


def test_angle_signs_as_seen_in_the_image() -> None:
    nose = rotation_from_angles(25.0, 0.0, 0.0) @ NOSE
    assert nose[0] > 0.4 and abs(nose[1]) < 1e-12  # yaw > 0: nose toward the image's right
    nose = rotation_from_angles(0.0, 25.0, 0.0) @ NOSE
    assert nose[1] < -0.4 and abs(nose[0]) < 1e-12  # pitch > 0: nose up (y grows downward)
    eyes = rotation_from_angles(0.0, 0.0, 25.0) @ EYES
    assert eyes[1] > 0.4 and abs(eyes[2]) < 1e-12  # roll > 0: clockwise in the image (the right end goes down)
    # the pose vector's rotation reads the same (geometry's Rodrigues)
    r = rotation_from_angles(-12.0, 8.0, 3.0)
    np.testing.assert_allclose(yaw_pitch_roll(rotation_matrices(make_pose(r, [0, 0], [1.0]))), [-12, 8, 3],
                               atol=1e-9)
    batch = np.stack([rotation_from_angles(a, 0, 0) for a in (5.0, -5.0)])
    np.testing.assert_allclose(yaw_pitch_roll(batch)[:, 0], [5.0, -5.0], atol=1e-9)


def test_expression_in_training_standard_deviations() -> None:
    c = np.array([50.0, 5.0, -1.0])
    np.testing.assert_allclose(expression(c, np.array([0.0, 0.05, 0.01])), [2.0, -2.0])
    np.testing.assert_allclose(expression(c, None), [0.1, -0.02])
    np.testing.assert_allclose(expression(c, np.array([0.0, 0.0, 0.01])), [0.0, -2.0])
    assert expression(np.array([50.0]), np.array([0.0])).shape == (0,)


def test_following_box_moves_and_scales_with_the_face() -> None:
    box0 = np.array([100.0, 50.0, 40.0, 60.0])
    u0 = make_pose(None, [118.0, 85.0], [60.0, 1.0])
    np.testing.assert_allclose(following_box(u0, u0, box0), box0, atol=1e-12)
    # translated by (7, -3): the box moves alike
    u = make_pose(rotation_from_angles(30, 0, 0), [125.0, 82.0], [60.0, -4.0])
    np.testing.assert_allclose(following_box(u, u0, box0), box0 + [7, -3, 0, 0], atol=1e-12)
    # 1.5 times larger about l: the offset of the box centre from l grows too
    u = make_pose(None, [118.0, 85.0], [90.0, 0.0])
    b = following_box(u, u0, box0)
    np.testing.assert_allclose(b[2:], [60.0, 90.0])
    np.testing.assert_allclose(b[:2] + b[2:] / 2, np.array([118.0, 85.0]) + 1.5 * (np.array([120.0, 80.0]) -
                                                                                    [118.0, 85.0]))
    assert following_box(np.stack([u0, u]), u0, box0).shape == (2, 4)


def _reference(T: int = 4) -> np.ndarray:
    ref = np.full((T, 468, 3), np.nan)
    for t in range(T):
        ref[t, :, :2] = 0.0
        ref[t, 33, :2], ref[t, 263, :2] = (100.0, 100.0), (140.0, 100.0)  # eye distance 40
        ref[t, 133, :2], ref[t, 362, :2] = (110.0, 100.0), (130.0, 100.0)
        ref[t, 61, :2], ref[t, 291, :2] = (110.0, 130.0), (130.0, 130.0)
        ref[t, :, 2] = 0.0
    return ref


def test_landmark_error_on_a_hand_made_case() -> None:
    ref = _reference()
    ref[3] = np.nan  # no face found in frame 3
    ids = (33, 133, 362, 263, 61, 291)
    pts = {t: {i: tuple(ref[t, i, :2]) for i in ids} for t in range(3)}
    pts[1] = {i: (x + 3.0, y + 4.0) for i, (x, y) in pts[1].items()}  # every point 5 px off
    pts[1][1] = (0.0, 0.0)  # a landmark that is not scored changes nothing
    del pts[2][61]  # frame 2 misses a scored point
    s = landmark_score(ref, pts)
    assert (s.frames, s.missing) == (3, 1)
    assert s.per_frame == {0: (0.0, 0.0), 1: (5.0 / 40.0, 5.0)}
    assert s.nme == pytest.approx(0.0625) and s.px == pytest.approx(2.5)
    assert landmark_score(ref, pts, frames=[1]).nme == pytest.approx(0.125)
    with pytest.raises(ValueError, match="none of the scored landmarks"):
        landmark_score(ref, {0: {1: (0.0, 0.0)}})
    with pytest.raises(ValueError, match="not all among"):
        landmark_score(ref[:, :100], pts)
