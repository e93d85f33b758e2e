"""Learning a morphable model (eq. 1) from 3-D landmark tracks.

The paper built its face model (38 points, ``k = 5`` morph bases) from a motion-capture
session of the subject. Here the same kind of model is learned from tracked 3-D landmarks
(e.g. MediaPipe Face Mesh's 468 points per frame), in four steps:

1. **Rigid pose removed** (generalised orthogonal Procrustes): each frame's landmarks are
   centred, rotated (a proper rotation, no reflection) and scaled onto a common reference,
   the reference being re-estimated as the mean of the aligned frames until it stops
   changing (:func:`procrustes_align`).
2. **Frontal, unit-height frame**: the mean is turned so that the line from the first to the
   second eye corner of ``frontal`` is the ``+x`` axis and the line from the eyes' midpoint
   to the mouth corners' midpoint points down (``+y``); ``z = x cross y`` then points away
   from the camera (the camera frame of :mod:`.geometry`). It is scaled to 1 model unit
   high, so ``c_1`` of a tracked pose is the face's height in pixels (as for the ellipsoid).
3. **Vertices**: all landmarks, or ``n`` of them chosen by farthest-point sampling of the
   frontal view (the most evenly spread subset, so that the texels cover the face), always
   keeping the landmarks named in ``keep`` (:func:`choose_vertices`). Each vertex keeps the
   index of the landmark it came from.
4. **Morph bases** (:func:`morph_bases`): ``h_i[:, 0]`` is the mean shape; ``h_i[:, 1:]`` are
   the ``k - 1`` leading principal components of the aligned shapes' deviations from the
   mean, after the deviations are made orthogonal to the mean itself, to its three
   infinitesimal rotations and to translation (so that scale, rotation and translation stay
   in ``c_1``, ``r`` and ``l`` and the morphs are deformations only). Each component is scaled
   to the mean shape's norm: a unit change of any ``c_j`` moves the vertices by the same RMS
   distance, so one random-walk std suits every coefficient. ``morph_std[j]`` is the spread of
   ``c_j / c_1`` over the training frames (``morph_std[0] = 0``): an expression coefficient in
   standard deviations is ``c_j / (c_1 morph_std[j])``.

The **reference box** says how a user's box sits on the face: given boxes for the training
frames, each box is expressed in the frame's model units (about the landmarks' centroid,
divided by the frame's Procrustes scale) and the median over frames is kept; without boxes
it is the bounding box of the frontal mean. :func:`.head_model.pose_for_box` places the model
so that this box fills the initial box.

Departures from the paper: the training shapes are a face tracker's landmarks on ordinary
video (of one or more people), not motion capture; the bases are principal components (the
paper does not say how its bases were made).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .geometry import skew
from .head_model import MorphableModel

__all__ = [
    "FRONTAL_MEDIAPIPE",
    "EVAL_LANDMARKS",
    "LearnedFace",
    "procrustes_align",
    "frontal_rotation",
    "choose_vertices",
    "morph_bases",
    "reference_box",
    "learn_morphable",
]

#: MediaPipe Face Mesh indices that define the frontal frame: outer eye corners (image left,
#: image right on a frontal face) and mouth corners.
FRONTAL_MEDIAPIPE = (33, 263, 61, 291)
#: The six points a face tracker is scored on (eye corners 33, 133, 362, 263; mouth corners
#: 61, 291), kept among the vertices whatever their number.
EVAL_LANDMARKS = (33, 133, 362, 263, 61, 291)


@dataclass(frozen=True)
class LearnedFace:
    """A learned morphable model and what it was learned from.

    Attributes
    ----------
    model : MorphableModel
        With ``landmarks``, ``reference_box`` and ``morph_std`` set.
    explained : (k - 1,) float64
        Fraction of the deformation variance (after the rigid parts are removed) each morph
        basis explains.
    residual_rms : float
        RMS distance (model units) between the training shapes (chosen vertices, aligned)
        and their projection onto the model's span.
    frames : int
        Training frames used (frames with a NaN landmark are left out).
    """

    model: MorphableModel
    explained: np.ndarray
    residual_rms: float
    frames: int


def _check_tracks(tracks: np.ndarray, name: str = "landmarks") -> np.ndarray:
    a = np.asarray(tracks)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"{name} must have shape (frames, landmarks, 3), got {a.shape}")
    if a.shape[1] < 4:
        raise ValueError(f"{name} need at least 4 landmarks per frame, got {a.shape[1]}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"{name} must be floating point (x, y, z in pixels), got dtype {a.dtype}")
    return np.asarray(a, dtype=np.float64)


def _rotation_onto(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Proper rotations ``R`` (row-vector convention: ``src @ R ~ dst``) and the optimal scales'
    numerators ``trace(S D)``, for centred ``src`` (T, N, 3) and ``dst`` (N, 3)."""
    m = np.einsum("tni,nj->tij", src, dst)  # src^T dst
    u, s, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    # R = U diag(1, 1, det(U V^T)) V^T   (orthogonal Procrustes without reflection)
    u = u.copy()
    u[:, :, 2] *= d[:, None]
    s = s.copy()
    s[:, 2] *= d
    return u @ vt, s.sum(axis=1)


def procrustes_align(shapes: np.ndarray, max_iter: int = 100, tol: float = 1e-12) -> tuple[np.ndarray, np.ndarray,
                                                                                            np.ndarray, np.ndarray]:
    """Generalised orthogonal Procrustes analysis of 3-D shapes (rotation, scale, translation).

    Parameters
    ----------
    shapes : (T, N, 3) float64
        Landmarks of each frame, finite.
    max_iter : int
    tol : float
        Stop when the reference moves by less than this (unit-norm shapes).

    Returns
    -------
    aligned : (T, N, 3) float64
        ``s_t (X_t - centroid_t) R_t``, each frame fitted to the reference.
    mean : (N, 3) float64
        The reference: mean of ``aligned``, centred, of unit Frobenius norm.
    scales : (T,) float64
        ``s_t`` (reference units per input unit).
    centroids : (T, 3) float64
    """
    x = _check_tracks(shapes, "shapes")
    if not np.isfinite(x).all():
        raise ValueError("shapes contain NaN or infinite values (drop the frames without landmarks first)")
    cen = x.mean(axis=1)
    xc = x - cen[:, None, :]
    norms = np.sqrt((xc * xc).sum(axis=(1, 2)))
    if (norms <= 0).any():
        raise ValueError("a frame's landmarks all coincide")
    ref = xc[0] / norms[0]
    aligned = xc
    scales = 1.0 / norms
    for _ in range(max_iter):
        rot, num = _rotation_onto(xc, ref)
        # s_t = trace(S D) / |X_t|^2 minimises |s X_t R - ref|^2
        scales = num / norms ** 2
        aligned = scales[:, None, None] * (xc @ rot)
        new = aligned.mean(axis=0)
        new /= np.sqrt((new * new).sum())
        moved = float(np.sqrt(((new - ref) ** 2).sum()))
        ref = new
        if moved < tol:
            break
    return aligned, ref, scales, cen


def frontal_rotation(mean: np.ndarray, frontal: Sequence[int]) -> np.ndarray:
    """Rotation turning a mean shape to face the camera (row vectors: ``mean @ R``).

    Parameters
    ----------
    mean : (N, 3) float64
    frontal : 4 landmark indices ``(eye_a, eye_b, mouth_a, mouth_b)``: ``eye_a -> eye_b`` becomes
        ``+x`` (image right), the eyes' midpoint -> the mouth's midpoint ``+y`` (down).

    Returns
    -------
    (3, 3) float64, a proper rotation.
    """
    ea, eb, ma, mb = (int(i) for i in frontal)
    n = mean.shape[0]
    if min(ea, eb, ma, mb) < 0 or max(ea, eb, ma, mb) >= n:
        raise ValueError(f"frontal landmarks {tuple(frontal)} must lie in [0, {n})")
    x = mean[eb] - mean[ea]
    nx = np.linalg.norm(x)
    if not np.isfinite(nx) or nx <= 0:  # dividing by it printed numpy's warning before the error below
        raise ValueError(f"the eye corners {ea} and {eb} coincide in the mean shape: cannot tell which way the face "
                         f"looks")
    x /= nx
    y = 0.5 * (mean[ma] + mean[mb]) - 0.5 * (mean[ea] + mean[eb])
    y -= (y @ x) * x
    ny = np.linalg.norm(y)
    if not np.isfinite(ny) or ny <= 0:
        raise ValueError("the frontal landmarks are collinear: cannot tell which way the face looks")
    y /= ny
    z = np.cross(x, y)
    # new coordinates (x . p, y . p, z . p): p @ [x y z]
    return np.stack([x, y, z], axis=1)


def choose_vertices(points: np.ndarray, n: int | None, keep: Sequence[int] = ()) -> np.ndarray:
    """Landmarks to use as vertices: all (``n`` None or >= N), or ``n`` by farthest-point sampling.

    Starting from ``keep`` (or the landmark nearest the centroid when ``keep`` is empty), the
    landmark farthest from every chosen one is added until ``n`` are chosen (ties: the lowest
    index). Deterministic.

    Parameters
    ----------
    points : (N, 2) or (N, 3) float64
        Where the landmarks are (the frontal view of the mean: ``mean[:, :2]``).
    n : int or None
    keep : landmark indices always chosen.

    Returns
    -------
    (n,) int64, ascending.
    """
    p = np.asarray(points, dtype=np.float64)
    N = p.shape[0]
    keep = sorted({int(i) for i in keep})
    if keep and (keep[0] < 0 or keep[-1] >= N):
        raise ValueError(f"landmarks to keep must lie in [0, {N}), got {keep}")
    if n is None or n >= N:
        return np.arange(N, dtype=np.int64)
    if n < max(3, len(keep)):
        raise ValueError(f"need at least {max(3, len(keep))} vertices (3, and the {len(keep)} kept landmarks), "
                         f"got {n}")
    chosen = list(keep) or [int(np.argmin(((p - p.mean(axis=0)) ** 2).sum(axis=1)))]
    d = np.min(((p[:, None, :] - p[None, chosen, :]) ** 2).sum(axis=-1), axis=1)
    while len(chosen) < n:
        i = int(np.argmax(d))
        chosen.append(i)
        d = np.minimum(d, ((p - p[i]) ** 2).sum(axis=1))
    return np.array(sorted(chosen), dtype=np.int64)


def _rigid_generators(m: np.ndarray) -> np.ndarray:
    """Orthonormal basis ``(3n, 7)`` of the shape changes that are not deformations of ``m``
    (n, 3): its scale, three infinitesimal rotations ``w x m_i`` and three translations."""
    n = m.shape[0]
    cols = [m.reshape(-1)]
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        cols.append((m @ skew(e).T).reshape(-1))  # w x m_i for w = e_a
    for a in range(3):
        t = np.zeros((n, 3))
        t[:, a] = 1.0
        cols.append(t.reshape(-1))
    q, _ = np.linalg.qr(np.stack(cols, axis=1))
    return q


def morph_bases(aligned: np.ndarray, mean: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Morph bases ``h_i`` (eq. 1) of aligned shapes: the mean, then ``k - 1`` principal deformations.

    Parameters
    ----------
    aligned : (T, n, 3) float64
        Shapes with the rigid pose removed (model units).
    mean : (n, 3) float64
    k : int >= 1

    Returns
    -------
    bases : (n, 3, k) float64
        ``bases[:, :, 0] = mean``; ``bases[:, :, j]`` the ``j``-th principal deformation, of the
        same Frobenius norm as ``mean``, sign fixed so that its largest component is positive.
    explained : (k - 1,) float64
        Fraction of the deformation variance each explains.
    morph_std : (k,) float64
        Std of the training frames' coefficients ``c_j / c_1`` (0 for ``j = 0``).
    residual_rms : float
        RMS per-vertex distance of the training shapes from the model's span.
    """
    T, n, _ = aligned.shape
    if not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k must be an integer >= 1, got {k!r}")
    if k - 1 > min(T - 1, 3 * n - 7):
        raise ValueError(f"k = {k} morph bases need more training frames than {T} (at least k) and vertices")
    norm_m = float(np.sqrt((mean * mean).sum()))
    d = (aligned - mean[None]).reshape(T, -1)
    g = _rigid_generators(mean)
    # deformations only: d <- d - G G^T d (scale, rotation and translation stay in c_1, r, l)
    d = d - (d @ g) @ g.T
    d = d - d.mean(axis=0)
    _, sv, vt = np.linalg.svd(d, full_matrices=False)
    var = sv ** 2
    total = float(var.sum())
    comps = vt[: k - 1]
    # a deterministic sign: the largest-magnitude component of each basis is positive
    big = np.argmax(np.abs(comps), axis=1)
    comps = comps * np.sign(comps[np.arange(k - 1), big])[:, None]
    bases = np.empty((n, 3, k))
    bases[:, :, 0] = mean
    for j in range(1, k):
        bases[:, :, j] = (norm_m * comps[j - 1]).reshape(n, 3)
    coef = d @ comps.T / norm_m  # (T, k - 1): c_j / c_1 of each frame
    morph_std = np.concatenate([[0.0], coef.std(axis=0)])
    resid = d - (d @ comps.T) @ comps
    residual_rms = float(np.sqrt((resid * resid).sum() / (T * n)))
    explained = var[: k - 1] / total if total > 0 else np.zeros(k - 1)
    return bases, explained, morph_std, residual_rms


def reference_box(tracks: np.ndarray, boxes: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Where a user's box sits on the face, in model units about the model's origin.

    Parameters
    ----------
    tracks : (T, N, 3) float64
        Landmarks (pixels) of the frames that have a box.
    boxes : (T, 4) float64
        ``(x, y, w, h)`` pixels of the same frames.
    scales : (T,) float64
        Model units per pixel of each frame (from the Procrustes fit).

    Returns
    -------
    (4,) float64
        Median over frames of ``((x - cx) s, (y - cy) s, w s, h s)``, ``(cx, cy)`` the landmarks'
        centroid in the image.
    """
    cen = tracks[:, :, :2].mean(axis=1)
    s = scales[:, None]
    rel = np.concatenate([(boxes[:, :2] - cen) * s, boxes[:, 2:] * s], axis=1)
    return np.median(rel, axis=0)


def learn_morphable(
    tracks: Sequence[np.ndarray],
    k: int = 5,
    n_vertices: int | None = None,
    *,
    boxes: Sequence[np.ndarray | None] | None = None,
    frontal: Sequence[int] | None = FRONTAL_MEDIAPIPE,
    keep: Sequence[int] = EVAL_LANDMARKS,
) -> LearnedFace:
    """Learn a morphable model (eq. 1) from 3-D landmark tracks of one or more videos.

    Parameters
    ----------
    tracks : sequence of (T_v, N, 3) floating
        Landmarks per frame, ``x, y`` in pixels and ``z`` in the same units (away from the
        camera); frames with any NaN are left out. Every track has the same ``N`` and layout.
    k : int
        Morph bases (the paper: 5); the first is the mean shape.
    n_vertices : int, optional
        Vertices to keep (farthest-point sampling, :func:`choose_vertices`); default all.
    boxes : sequence of (T_v, 4) or None, optional
        Per-track user boxes ``(x, y, w, h)`` of the same frames (NaN rows: no box), for the
        reference box; None: the frontal mean's bounding box.
    frontal : 4 indices, or None
        Landmarks defining the frontal frame (:func:`frontal_rotation`); None keeps the
        orientation of the first frame.
    keep : landmark indices always among the vertices (those outside ``[0, N)`` are ignored).

    Returns
    -------
    LearnedFace

    Raises
    ------
    ValueError
        No usable frame, tracks of different layouts, fewer usable frames than ``k``, or bad
        indices.
    """
    if len(tracks) == 0:
        raise ValueError("no landmark tracks to learn from")
    arrs = [_check_tracks(t, f"landmarks of track {i}") for i, t in enumerate(tracks)]
    N = arrs[0].shape[1]
    if any(a.shape[1] != N for a in arrs):
        raise ValueError(f"every track needs the same landmark layout, got {[a.shape[1] for a in arrs]} landmarks")
    if boxes is not None and len(boxes) != len(arrs):
        raise ValueError(f"need one box array (or None) per track: {len(boxes)} for {len(arrs)} tracks")
    good = [np.isfinite(a).all(axis=(1, 2)) for a in arrs]
    x = np.concatenate([a[g] for a, g in zip(arrs, good)])
    T = x.shape[0]
    if T == 0:
        raise ValueError("no frame has all its landmarks (every frame has a NaN)")
    if T < k:
        raise ValueError(f"k = {k} morph bases need at least {k} frames with landmarks, got {T}")
    aligned, mean, scales, _ = procrustes_align(x)
    rot = np.eye(3) if frontal is None else frontal_rotation(mean, frontal)
    mean = mean @ rot
    aligned = aligned @ rot
    # one model unit = the frontal mean's height
    unit = float(mean[:, 1].max() - mean[:, 1].min())
    mean, aligned, scales = mean / unit, aligned / unit, scales / unit
    sel = choose_vertices(mean[:, :2], n_vertices, [i for i in keep if 0 <= int(i) < N])
    bases, explained, morph_std, resid = morph_bases(aligned[:, sel], mean[sel], k)
    if boxes is not None and any(b is not None for b in boxes):
        bx = np.concatenate([np.full((g.sum(), 4), np.nan) if b is None else
                             np.asarray(b, dtype=np.float64).reshape(-1, 4)[g] for b, g in zip(boxes, good)])
        if bx.shape[0] != T:
            raise ValueError("every box array needs one row per frame of its track")
        ok = np.isfinite(bx).all(axis=1) & (bx[:, 2] > 0) & (bx[:, 3] > 0)
        if not ok.any():
            raise ValueError("no frame has both landmarks and a box")
        ref = reference_box(x[ok], bx[ok], scales[ok])
    else:
        lo, hi = mean[:, :2].min(axis=0), mean[:, :2].max(axis=0)
        ref = np.concatenate([lo, hi - lo])
    model = MorphableModel(bases=bases, landmarks=sel, reference_box=ref, morph_std=morph_std)
    return LearnedFace(model=model, explained=explained, residual_rms=resid, frames=T)
