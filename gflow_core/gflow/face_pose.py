"""What a face user reads off a G-flow pose: head angles, expression, and a box that follows the face.

Head angles
-----------
The model faces the camera at the identity rotation (its nose points along ``-z``, toward the
camera; :mod:`.geometry`'s camera frame: ``x`` right, ``y`` down, ``z`` away). The rotation of
a pose is decomposed as ``r = R_y(-yaw) R_x(-pitch) R_z(roll)`` (rotations about the camera's
axes, the roll applied first), with the signs chosen so that, as seen in the image:

* **yaw > 0**: the nose turns toward the image's right (the person turns to their left);
* **pitch > 0**: the nose turns up (the person looks up);
* **roll > 0**: the face turns clockwise in the image.

Angles are in degrees; yaw and roll in ``(-180, 180]``, pitch in ``[-90, 90]``.

Expression
----------
``c_j / (c_1 morph_std_j)`` for ``j = 2 .. k``: each morph coefficient relative to the scale
``c_1``, in standard deviations of what the model was learned from
(:mod:`.morphable_learn`).

The box
-------
The box the user gave on the first frame, moved with the face: its centre keeps its offset
from the projected model origin ``l`` (scaled with the face), and its size scales with ``c_1``
(:func:`following_box`). So the box keeps the user's convention (where the box sits on the
face) instead of becoming the outline of the mesh; it does not turn with the head.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .geometry import COEF, TRANS

__all__ = ["yaw_pitch_roll", "rotation_from_angles", "expression", "following_box"]


def yaw_pitch_roll(rotation: np.ndarray) -> np.ndarray:
    """Yaw, pitch and roll (degrees) of rotation matrices (conventions in the module docstring).

    Parameters
    ----------
    rotation : (..., 3, 3) float64

    Returns
    -------
    (..., 3) float64
    """
    r = np.asarray(rotation, dtype=np.float64)
    lead = r.shape[:-2]
    # r = R_Y(a) R_X(b) R_Z(c) (intrinsic Y, X', Z''), a = -yaw, b = -pitch, c = roll
    abc = Rotation.from_matrix(np.array(r.reshape(-1, 3, 3), copy=True)).as_euler("YXZ", degrees=True)
    out = abc * np.array([-1.0, -1.0, 1.0])
    out = np.where(out <= -180.0, out + 360.0, out)
    return (out + 0.0).reshape(lead + (3,))


def rotation_from_angles(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """The rotation matrix ``(3, 3)`` of yaw, pitch and roll in degrees (inverse of :func:`yaw_pitch_roll`)."""
    return Rotation.from_euler("YXZ", [-yaw, -pitch, roll], degrees=True).as_matrix()


def expression(coefficients: np.ndarray, morph_std: np.ndarray | None) -> np.ndarray:
    """Morph coefficients ``c_2 .. c_k`` in training standard deviations: ``c_j / (c_1 morph_std_j)``.

    Parameters
    ----------
    coefficients : (..., k) float64
    morph_std : (k,) float64 or None (the model has no training spread: ``c_j / c_1``)

    Returns
    -------
    (..., k - 1) float64 (0 where ``c_1`` or ``morph_std_j`` is 0)
    """
    c = np.asarray(coefficients, dtype=np.float64)
    rel = c[..., 1:] / np.where(c[..., :1] == 0.0, np.inf, c[..., :1])
    if morph_std is None:
        return rel
    s = np.asarray(morph_std, dtype=np.float64)[1:]
    return np.where(s > 0, rel / np.where(s > 0, s, 1.0), 0.0)


def following_box(pose: np.ndarray, pose0: np.ndarray, box0: np.ndarray) -> np.ndarray:
    """The first box moved and scaled with the face.

    ``centre_t = l_t + (c_1 / c_1^0) (centre_0 - l_0)``, ``size_t = (c_1 / c_1^0) size_0``.

    Parameters
    ----------
    pose : (..., P) float64
        Pose at ``t``.
    pose0 : (P,) float64
        The initial pose.
    box0 : (4,) float64
        ``(x, y, w, h)``, the initial box.

    Returns
    -------
    (..., 4) float64
    """
    u = np.asarray(pose, dtype=np.float64)
    u0 = np.asarray(pose0, dtype=np.float64)
    b0 = np.asarray(box0, dtype=np.float64)
    s = u[..., COEF][..., :1] / u0[COEF][0]
    centre = u[..., TRANS] + s * (b0[:2] + 0.5 * b0[2:] - u0[TRANS])
    size = s * b0[2:]
    return np.concatenate([centre - 0.5 * size, size], axis=-1)
