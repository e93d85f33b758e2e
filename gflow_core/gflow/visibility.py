"""Self-occlusion of a morphable model's vertices: which vertices the head itself hides at a pose.

G-flow's observation model (Marks et al. NIPS 2004, sec. 2, eq. 2-4) renders every vertex ``i`` of
the object at its projection ``x_i(u)``: the texel ``V_i`` is seen through the one-to-one map
``a_v``, whatever the pose. A real head turned toward profile hides the vertices on its far side
behind itself, and the frame there shows whatever lies beyond the head (the wall, the hair, the ear);
eq. 13 scores those vertices' texels against it, and eq. 7-8 learn it into them.

This module gives each vertex a visibility weight ``v_i in [0, 1]`` from its surface normal under
the pose, as AAM and 3DMM fitting do for self-occlusion (a vertex whose normal faces away from the
camera is culled; Romdhani & Vetter, ICCV 2003; Matthews, Xiao & Baker, IJCV 2007, "2D vs. 3D
deformable face models"):

* the normals ``n_i`` (:func:`vertex_normals`) are those of the model's mean shape (the first
  basis, ``h_i`` with ``c = (1, 0, ...)``): the plane fitted by least squares to each vertex's
  nearest neighbours (the model has no mesh the filter could use), turned to point away from a
  point behind the shape (outward);
* under the weak-perspective camera of eq. 1 (``x_i = g r h_i c + l``, the camera looking along
  ``+z``) the cosine between the rotated normal and the direction toward the camera is
  ``cos_i(u) = -(r n_i)_z`` (:func:`facing`);
* ``v_i(u) = clip(cos_i(u) / c0, 0, 1)`` (:func:`visibility_weights`): a vertex facing the camera
  within ``arccos(c0)`` counts fully, one seen edge-on or from behind not at all, and between them
  its weight falls linearly with the cosine (``c0 = GFlowConfig.self_occlusion``).

Depth ordering (a z-buffer: a vertex behind the nose at a three-quarter view, facing the camera
but covered) is not modelled: the model's 160 vertices are too sparse to raster.

How the weights enter the filter (:mod:`.pose_opinion`, :mod:`.filter`) is a departure from the
paper described there: each vertex's texture term of eq. 13-14 is multiplied by ``v_i`` at the
expert's previous pose, its remainder replaced by its expectation under the texel's Gaussian, and
its texel's Kalman update (eq. 7-8) observes the frame with noise ``sigma_w / v_i`` at the new pose
(none at ``v_i = 0``: the texel keeps its prediction). It is off by default: on david_indoor it did not
bring the landmark NME at every 3rd frame to 0.10, and it cost the nine shared sequences' AUC
(docs/gflow-development.md, "Self-occlusion").
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .geometry import rotation_matrices

__all__ = ["vertex_normals", "facing", "visibility_weights", "NEIGHBOURS"]

#: Neighbours (besides the vertex itself) of the plane fitted for a vertex's normal.
NEIGHBOURS = 8


def vertex_normals(bases: np.ndarray, neighbours: int = NEIGHBOURS) -> np.ndarray:
    """Outward unit normals ``(n, 3)`` of the mean shape ``bases[:, :, 0]`` of a model ``(n, 3, k)``.

    Each is the direction of least spread (the eigenvector of the smallest eigenvalue of the
    scatter matrix) of the vertex and its ``neighbours`` nearest vertices, signed to point away
    from ``C = centroid + (0, 0, span)``, a point behind the shape (``+z`` is away from the camera,
    ``span`` the shape's largest extent). Fewer than three vertices: every normal is ``(0, 0, -1)``
    (toward the camera). Read-only; computed once per model (cached on the bases' bytes).
    """
    b = np.ascontiguousarray(bases, dtype=np.float64)
    return _normals(b.tobytes(), b.shape, int(neighbours))


@lru_cache(maxsize=8)
def _normals(raw: bytes, shape: tuple[int, ...], neighbours: int) -> np.ndarray:
    p = np.frombuffer(raw, dtype=np.float64).reshape(shape)[:, :, 0]
    n = p.shape[0]
    out = np.tile(np.array([0.0, 0.0, -1.0]), (n, 1))
    if n >= 3:
        k = min(max(neighbours, 2), n - 1)
        d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=-1)
        near = np.argsort(d2, axis=1, kind="stable")[:, : k + 1]  # the vertex itself first
        q = p[near] - p[near].mean(axis=1, keepdims=True)  # (n, k+1, 3)
        scatter = q.transpose(0, 2, 1) @ q
        _, vecs = np.linalg.eigh(scatter)
        out = vecs[:, :, 0]  # the smallest eigenvalue's eigenvector, (n, 3)
        span = float(np.max(p.max(axis=0) - p.min(axis=0)))
        behind = p.mean(axis=0) + np.array([0.0, 0.0, span])
        sign = np.where(((p - behind) * out).sum(axis=-1) < 0.0, -1.0, 1.0)
        out = out * sign[:, None]
    out = np.ascontiguousarray(out / np.linalg.norm(out, axis=-1, keepdims=True))
    out.setflags(write=False)
    return out


def facing(normals: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """``cos_i(u) = -(r n_i)_z`` ``(..., n)``: the cosine between each rotated normal ``(n, 3)`` and the
    direction toward the camera, at poses ``(..., P)`` (only their rotation counts)."""
    r = rotation_matrices(poses)  # (..., 3, 3)
    # (r n_i)_z = r[2, :] . n_i
    return -(r[..., 2, None, :] * normals).sum(axis=-1)


def visibility_weights(normals: np.ndarray, poses: np.ndarray, cos0: float) -> np.ndarray:
    """``v_i(u) = clip(cos_i(u) / cos0, 0, 1)`` ``(..., n)`` (:func:`facing`); ``cos0`` in ``(0, 1]``."""
    if not 0.0 < cos0 <= 1.0:
        raise ValueError(f"the visibility cosine must be in (0, 1], got {cos0!r}")
    return np.clip(facing(normals, poses) / cos0, 0.0, 1.0)
