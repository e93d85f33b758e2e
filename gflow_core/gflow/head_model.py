"""Morphable models: validation, a generic rigid head, and the model array format.

:class:`MorphableModel` holds the fixed morph bases ``h_i`` of eq. 1 (the paper's
``3 x k`` matrix per vertex) as one ``(n, 3, k)`` array.

Generic head
------------
:class:`EllipsoidHead` is a generic rigid head (``k = 1``): the front part of an
ellipsoid, sampled on a longitude/latitude grid. Vertex ``i`` has the unit-sphere
direction ``q_i = (sin(lon) cos(lat), sin(lat), -cos(lon) cos(lat))`` (``-z`` faces
the camera) and sits at ``a * q_i`` where ``a`` are the semi-axes in model units.
:func:`fit_head_model_to_box` scales it so that, at the identity rotation, the
bounding box of its projected vertices is exactly the given box. The model is
*textured* only in the sense of G-flow: the texture is not part of the model but is
inferred by the filter (eq. 7-10), initialised from the first frame.

Model array format (the user-supplied model file, ``.npz``)
----------------------------------------------------------
:func:`model_to_arrays` / :func:`model_from_arrays` convert a model to and from a
flat ``dict[str, numpy.ndarray]``; ``pipeline/`` writes and reads it with
``numpy.savez`` / ``numpy.load(allow_pickle=False)``. Keys:

==================  ===========  ======  ==========================================
key                 shape        dtype   meaning
==================  ===========  ======  ==========================================
``format_version``  ``()``       int     ``2`` (:data:`MODEL_FORMAT_VERSION`; ``1``, the
                                         same without the optional face keys, is
                                         read too)
``bases``           ``(n,3,k)``  float   ``bases[i, :, j]`` = vertex ``i`` in morph
                                         basis ``j`` (model units, camera-aligned
                                         axes: x right, y down, z away from camera)
``triangles``       ``(T, 3)``   int     optional: vertex indices of mesh triangles
                                         (drawing only; not used by the filter)
``landmarks``       ``(n,)``     int     optional: the index of the reference
                                         landmark each vertex was learned from
                                         (distinct, >= 0; :mod:`.morphable_learn`)
``reference_box``   ``(4,)``     float   optional: ``(x, y, w, h)`` in model units
                                         about the origin, at the identity rotation
                                         and ``c = (1, 0, ...)``: where a user's box
                                         sits on the object (:func:`pose_for_box`)
``morph_std``       ``(k,)``     float   optional: training spread of ``c_j / c_1``
                                         (``>= 0``; for reading expressions in
                                         standard deviations)
==================  ===========  ======  ==========================================

``n >= 3``, ``k >= 1``, every value finite, triangle indices in ``[0, n)``. Any
other key is an error (so that a typo fails early). The rotation centre is the
model origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import make_pose, project, pose_size

__all__ = [
    "MODEL_FORMAT_VERSION",
    "MorphableModel",
    "EllipsoidHead",
    "validate_box",
    "fit_head_to_box",
    "fit_head_model_to_box",
    "model_to_arrays",
    "model_from_arrays",
    "bounding_box",
    "pose_for_box",
]

#: Version of the model array format written by :func:`model_to_arrays`.
MODEL_FORMAT_VERSION = 2
#: Model array format versions :func:`model_from_arrays` reads.
READABLE_FORMAT_VERSIONS = (1, 2)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class MorphableModel:
    """A morphable model: ``n`` vertices in ``k`` morph bases (eq. 1).

    Attributes
    ----------
    bases : (n, 3, k) float64
        ``bases[i]`` is the paper's ``h_i`` (3 x k).
    triangles : (T, 3) int64 or None
        Optional mesh for drawing.
    landmarks : (n,) int64 or None
        The reference landmark each vertex was learned from (a learned face,
        :mod:`.morphable_learn`); None for other models.
    reference_box : (4,) float64 or None
        ``(x, y, w, h)`` in model units about the origin (identity rotation, ``c = (1, 0, ...)``):
        where a user's box sits on the object. None: the projected vertices' bounding box.
    morph_std : (k,) float64 or None
        Spread of ``c_j / c_1`` over the training frames.

    Raises
    ------
    ValueError
        On a wrong shape, fewer than 3 vertices, non-finite values, bad triangles or landmark
        indices.
    """

    bases: np.ndarray
    triangles: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    reference_box: np.ndarray | None = None
    morph_std: np.ndarray | None = None

    def __post_init__(self) -> None:
        b = np.asarray(self.bases)
        if not (np.issubdtype(b.dtype, np.floating) or np.issubdtype(b.dtype, np.integer)):
            raise ValueError(f"model bases must be numeric, got dtype {b.dtype}")
        if b.ndim != 3 or b.shape[1] != 3:
            raise ValueError(f"model bases must have shape (n, 3, k), got {b.shape}")
        n, _, k = b.shape
        if n < 3:
            raise ValueError(f"model needs at least 3 vertices, got n={n}")
        if k < 1:
            raise ValueError(f"model needs at least one morph basis, got k={k}")
        b = np.array(b, dtype=np.float64, order="C")
        if not np.isfinite(b).all():
            raise ValueError("model bases contain NaN or infinite values")
        object.__setattr__(self, "bases", _readonly(b))
        if self.triangles is not None:
            t = np.asarray(self.triangles)
            if not np.issubdtype(t.dtype, np.integer):
                raise ValueError(f"model triangles must be integers, got dtype {t.dtype}")
            if t.ndim != 2 or t.shape[1] != 3:
                raise ValueError(f"model triangles must have shape (T, 3), got {t.shape}")
            if t.size and (t.min() < 0 or t.max() >= n):
                raise ValueError(f"model triangle indices must lie in [0, {n}), got [{t.min()}, {t.max()}]")
            object.__setattr__(self, "triangles", _readonly(np.array(t, dtype=np.int64, order="C")))
        if self.landmarks is not None:
            lm = np.asarray(self.landmarks)
            if not np.issubdtype(lm.dtype, np.integer) or lm.shape != (n,):
                raise ValueError(f"model landmarks must be {n} integers (one per vertex), got {lm.dtype} {lm.shape}")
            if lm.size and (lm.min() < 0 or np.unique(lm).size != n):
                raise ValueError("model landmarks must be distinct non-negative indices")
            object.__setattr__(self, "landmarks", _readonly(np.array(lm, dtype=np.int64)))
        if self.reference_box is not None:
            rb = np.asarray(self.reference_box, dtype=np.float64)
            if rb.shape != (4,) or not np.isfinite(rb).all() or rb[2] <= 0 or rb[3] <= 0:
                raise ValueError(f"model reference_box must be a finite (x, y, w, h) with w, h > 0, got "
                                 f"{np.asarray(self.reference_box).tolist()}")
            object.__setattr__(self, "reference_box", _readonly(rb.copy()))
        if self.morph_std is not None:
            ms = np.asarray(self.morph_std, dtype=np.float64)
            if ms.shape != (k,) or not np.isfinite(ms).all() or (ms < 0).any():
                raise ValueError(f"model morph_std must be {k} finite numbers >= 0, got {ms.shape}")
            object.__setattr__(self, "morph_std", _readonly(ms.copy()))

    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n``."""
        return self.bases.shape[0]

    @property
    def n_bases(self) -> int:
        """Number of morph bases ``k``."""
        return self.bases.shape[2]

    @property
    def pose_size(self) -> int:
        """Length ``P = 5 + k`` of this model's pose vector."""
        return pose_size(self.n_bases)

    def check_poses(self, poses: np.ndarray, name: str = "poses") -> np.ndarray:
        """Validate pose vectors ``(..., P)`` for this model; returns them as float64."""
        u = np.asarray(poses, dtype=np.float64)
        if u.ndim < 1 or u.shape[-1] != self.pose_size:
            raise ValueError(
                f"{name} must have last dimension P = 5 + k = {self.pose_size} for this model, got shape {u.shape}"
            )
        if not np.isfinite(u).all():
            raise ValueError(f"{name} contain NaN or infinite values")
        return u


def _grid_directions(n_lon: int, n_lat: int, lon_max_deg: float, lat_max_deg: float) -> np.ndarray:
    lon = np.radians(np.linspace(-lon_max_deg, lon_max_deg, n_lon))
    lat = np.radians(np.linspace(-lat_max_deg, lat_max_deg, n_lat))
    LAT, LON = np.meshgrid(lat, lon, indexing="ij")  # rows = latitude (y), cols = longitude (x)
    q = np.stack([np.sin(LON) * np.cos(LAT), np.sin(LAT), -np.cos(LON) * np.cos(LAT)], axis=-1)
    return q.reshape(-1, 3)


def _grid_triangles(n_lon: int, n_lat: int) -> np.ndarray:
    idx = np.arange(n_lat * n_lon).reshape(n_lat, n_lon)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int64)


@dataclass(frozen=True)
class EllipsoidHead:
    """A generic head: the front of an ellipsoid, as a morphable model.

    Attributes
    ----------
    semi_axes : (3,) float64
        Ellipsoid semi-axes ``a`` in model units.
    n_lon, n_lat : int
        Grid size (``n = n_lon * n_lat`` vertices).
    lon_max_deg, lat_max_deg : float
        Half-range of the grid (< 90, the front part only).
    stretch : (3, k) float64
        Morph bases as axis stretches: with coefficients ``c`` the shape is the
        ellipsoid with semi-axes ``a * (stretch @ c)``. The default ``ones((3, 1))``
        is the rigid head (``k = 1``, ``c`` = scale).
    """

    semi_axes: np.ndarray = field(default_factory=lambda: np.array([0.5, 0.5, 0.5]))
    n_lon: int = 15
    n_lat: int = 15
    lon_max_deg: float = 60.0
    lat_max_deg: float = 60.0
    stretch: np.ndarray = field(default_factory=lambda: np.ones((3, 1)))

    def __post_init__(self) -> None:
        a = np.asarray(self.semi_axes, dtype=np.float64)
        if a.shape != (3,) or not np.isfinite(a).all() or (a <= 0).any():
            raise ValueError(f"semi_axes must be 3 positive finite numbers, got {self.semi_axes!r}")
        s = np.asarray(self.stretch, dtype=np.float64)
        if s.ndim != 2 or s.shape[0] != 3 or s.shape[1] < 1 or not np.isfinite(s).all():
            raise ValueError(f"stretch must be a finite (3, k) array, got shape {s.shape}")
        if self.n_lon < 2 or self.n_lat < 2:
            raise ValueError(f"n_lon and n_lat must be >= 2, got {self.n_lon}, {self.n_lat}")
        for nm in ("lon_max_deg", "lat_max_deg"):
            v = getattr(self, nm)
            if not (0.0 < v < 90.0):
                raise ValueError(f"{nm} must be in (0, 90) degrees, got {v}")
        object.__setattr__(self, "semi_axes", _readonly(a.copy()))
        object.__setattr__(self, "stretch", _readonly(s.copy()))

    def directions(self) -> np.ndarray:
        """Unit-sphere directions ``q_i`` of the vertices, ``(n, 3)`` float64."""
        return _grid_directions(self.n_lon, self.n_lat, self.lon_max_deg, self.lat_max_deg)

    def model(self) -> MorphableModel:
        """The morphable model: ``h_i[:, j] = a * stretch[:, j] * q_i``."""
        q = self.directions()
        bases = (self.semi_axes[None, :, None] * self.stretch[None, :, :]) * q[:, :, None]
        return MorphableModel(bases=bases, triangles=_grid_triangles(self.n_lon, self.n_lat))

    def effective_semi_axes(self, coefficients: np.ndarray) -> np.ndarray:
        """Semi-axes ``a * (stretch @ c)`` of the shape for coefficients ``c`` (pixels)."""
        return self.semi_axes * (self.stretch @ np.asarray(coefficients, dtype=np.float64))


def validate_box(box: np.ndarray, image_shape: tuple[int, int]) -> np.ndarray:
    """Check a box ``(x, y, w, h)`` (pixels, top-left corner) lies inside the image.

    The image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` in pixel coordinates (origin
    at the top-left pixel centre); the box must lie inside it, with ``w, h >= 1``.

    Returns
    -------
    (4,) float64
    """
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.shape != (4,):
        raise ValueError(f"box must be (x, y, w, h), got shape {np.shape(box)}")
    if not np.isfinite(b).all():
        raise ValueError(f"box contains NaN or infinite values: {b.tolist()}")
    H, W = (int(v) for v in image_shape)
    x, y, w, h = b
    if w < 1.0 or h < 1.0:
        raise ValueError(f"box must have width and height >= 1 pixel, got w={w}, h={h}")
    tol = 1e-9
    if x < -0.5 - tol or y < -0.5 - tol or x + w > W - 0.5 + tol or y + h > H - 0.5 + tol:
        raise ValueError(
            f"box (x={x}, y={y}, w={w}, h={h}) is not inside the {W}x{H} image "
            f"(allowed x in [-0.5, {W - 0.5}], y in [-0.5, {H - 0.5}])"
        )
    return b


def fit_head_to_box(
    box: np.ndarray,
    image_shape: tuple[int, int],
    *,
    n_lon: int = 15,
    n_lat: int = 15,
    lon_max_deg: float = 60.0,
    lat_max_deg: float = 60.0,
    depth_ratio: float = 1.0,
) -> tuple[EllipsoidHead, np.ndarray]:
    """Fit the generic ellipsoid head into a box.

    The model is 1 unit high (projected vertex extent at the identity rotation) and
    ``w / h`` units wide; its depth semi-axis is ``depth_ratio`` times its width
    semi-axis. The initial pose is the identity rotation, ``l`` = box centre and
    ``c = h`` (pixels per model unit), so the projected vertices' bounding box is the box.

    Parameters
    ----------
    box : (4,) float64
        ``(x, y, w, h)`` in pixels, ``(x, y)`` the top-left corner, origin at the
        top-left pixel centre.
    image_shape : (H, W)
    depth_ratio : float
        Depth semi-axis over width semi-axis.

    Returns
    -------
    head : EllipsoidHead
    pose0 : (6,) float64
    """
    b = validate_box(box, image_shape)
    if not (np.isfinite(depth_ratio) and depth_ratio > 0):
        raise ValueError(f"depth_ratio must be positive, got {depth_ratio}")
    unit = EllipsoidHead(np.ones(3), n_lon, n_lat, lon_max_deg, lat_max_deg)
    q = unit.directions()
    ext = q.max(axis=0) - q.min(axis=0)  # extents of the unit-sphere grid in x, y
    x, y, w, h = b
    ax = (w / h) / ext[0]
    ay = 1.0 / ext[1]
    head = EllipsoidHead(np.array([ax, ay, depth_ratio * ax]), n_lon, n_lat, lon_max_deg, lat_max_deg)
    centre = 0.5 * (q.max(axis=0) + q.min(axis=0))[:2] * np.array([ax, ay]) * h
    pose0 = make_pose(None, np.array([x + w / 2, y + h / 2]) - centre, np.array([h]))
    return head, pose0


def fit_head_model_to_box(
    box: np.ndarray, image_shape: tuple[int, int], **kwargs
) -> tuple[MorphableModel, np.ndarray]:
    """Generic rigid head model and initial pose whose projected bounding box is ``box``.

    Same parameters as :func:`fit_head_to_box`.

    Returns
    -------
    model : MorphableModel
        ``k = 1``.
    pose0 : (6,) float64
    """
    head, pose0 = fit_head_to_box(box, image_shape, **kwargs)
    return head.model(), pose0


def pose_for_box(
    model: MorphableModel,
    box: np.ndarray,
    image_shape: tuple[int, int],
    coefficients: np.ndarray | None = None,
) -> np.ndarray:
    """Initial pose placing any morphable model (e.g. a user-supplied one) in a box.

    Identity rotation; coefficients ``s * c0`` with ``c0`` = ``coefficients`` (default
    ``(1, 0, ..., 0)``) and the scale ``s`` fitting the width and height of the model's box
    to the box's in the least-squares sense; translation putting the model's box centre at
    the box's centre. Exact when the aspect ratios agree. The model's box is its
    ``reference_box`` (where a user's box sits on a learned face) when it has one and
    ``coefficients`` is None, else the bounding box of the vertices projected at ``c0``.

    Parameters
    ----------
    model : MorphableModel
    box : (4,) float64
        ``(x, y, w, h)`` pixels, top-left corner, origin at the top-left pixel centre.
    image_shape : (H, W)
    coefficients : (k,) float64, optional

    Returns
    -------
    (5 + k,) float64
    """
    b = validate_box(box, image_shape)
    k = model.n_bases
    c0 = np.zeros(k) if coefficients is None else np.asarray(coefficients, dtype=np.float64).reshape(-1)
    if coefficients is None:
        c0[0] = 1.0
    if c0.shape != (k,) or not np.isfinite(c0).all():
        raise ValueError(f"coefficients must be {k} finite numbers, got {coefficients!r}")
    if model.reference_box is not None and coefficients is None:
        bb = np.asarray(model.reference_box)
    else:
        bb = bounding_box(project(model.bases, make_pose(None, [0.0, 0.0], c0)))
    bw, bh = bb[2], bb[3]
    if bw <= 0 and bh <= 0:
        raise ValueError("the model projects to a single point with these coefficients")
    s = (b[2] * bw + b[3] * bh) / (bw * bw + bh * bh)
    centre = bb[:2] + bb[2:] / 2
    return make_pose(None, b[:2] + b[2:] / 2 - s * centre, s * c0)


def bounding_box(points: np.ndarray) -> np.ndarray:
    """Bounding box ``(x, y, w, h)`` of points ``(..., n, 2)`` -> ``(..., 4)``."""
    lo = points.min(axis=-2)
    hi = points.max(axis=-2)
    return np.concatenate([lo, hi - lo], axis=-1)


def model_to_arrays(model: MorphableModel) -> dict[str, np.ndarray]:
    """The model as the array dict of the model file format (module docstring)."""
    out = {
        "format_version": np.array(MODEL_FORMAT_VERSION, dtype=np.int64),
        "bases": np.array(model.bases, dtype=np.float64),
    }
    if model.triangles is not None:
        out["triangles"] = np.array(model.triangles, dtype=np.int64)
    for key in _FACE_KEYS:
        v = getattr(model, key)
        if v is not None:
            out[key] = np.array(v)
    return out


#: Optional keys of format version 2 (a learned face, :mod:`.morphable_learn`).
_FACE_KEYS = ("landmarks", "reference_box", "morph_std")


def model_from_arrays(d: dict[str, np.ndarray]) -> MorphableModel:
    """Build and validate a model from the array dict of the model file format.

    Raises
    ------
    ValueError
        On a missing or unknown key, a wrong version, shape or dtype, or bad values.
    """
    keys = set(d.keys())
    allowed = {"format_version", "bases", "triangles", *_FACE_KEYS}
    missing = {"format_version", "bases"} - keys
    if missing:
        raise ValueError(f"model arrays are missing key(s): {sorted(missing)}")
    unknown = keys - allowed
    if unknown:
        raise ValueError(f"model arrays have unknown key(s): {sorted(unknown)} (allowed: {sorted(allowed)})")
    ver = np.asarray(d["format_version"])
    if ver.shape != () or not np.issubdtype(ver.dtype, np.integer):
        raise ValueError(f"format_version must be an integer scalar, got shape {ver.shape} dtype {ver.dtype}")
    if int(ver) not in READABLE_FORMAT_VERSIONS:
        raise ValueError(f"unsupported model format_version {int(ver)} (this code reads "
                         f"{', '.join(map(str, READABLE_FORMAT_VERSIONS))})")
    if int(ver) == 1 and keys & set(_FACE_KEYS):
        raise ValueError(f"format_version 1 has no {sorted(keys & set(_FACE_KEYS))} (version 2 does)")
    bases = np.asarray(d["bases"])
    if not np.issubdtype(bases.dtype, np.floating):
        raise ValueError(f"bases must be floating point, got dtype {bases.dtype}")
    for key in ("reference_box", "morph_std"):
        if key in d and not np.issubdtype(np.asarray(d[key]).dtype, np.floating):
            raise ValueError(f"{key} must be floating point, got dtype {np.asarray(d[key]).dtype}")
    tri = d.get("triangles")
    return MorphableModel(bases=bases, triangles=None if tri is None else np.asarray(tri),
                          **{key: np.asarray(d[key]) for key in _FACE_KEYS if key in d})
