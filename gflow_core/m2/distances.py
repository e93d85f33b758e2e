"""Distance functions rho for the Metric Mixture model (Toyama & Blake 2002, sec. 3.1).

A :class:`Metric` is the only thing the learning code (:mod:`.exemplars`, :mod:`.kernel`,
:mod:`.learn`) knows about the items it clusters. It must provide

* ``pairwise(a, b)``: the (A, B) matrix rho(a_i, b_j), vectorised;
* ``reference(b, j, extent)``: a function items -> rho(items_i, b_j) for repeated
  evaluation against one fixed item (direct descent over alpha, sec. 4.1-4.2);
* ``transform(items, alphas)``: T_alpha applied to each item (sec. 3.2);
* ``to_image(exemplars, features, alphas, k)``: rho(T_alpha x~_k, z) of particles against
  the current frame's features (eq. 7).

Three metrics are provided:

``ChamferMetric``  curves (:class:`.curves.Curves`), non-symmetric chamfer distance
    rho(z~, z) = integral ds gamma(z, r_z~(s)) (eq. 4-5), computed from the chamfer image
    of the *second* argument, with the quadratic g(u) = u^2 or truncated min(u^2, g0) profile.
``ShuffleMetric``  patches, (N, h, w) float64: squared L2 after matching each pixel of the
    first patch to the most similar pixel within the (2r+1)^2 neighbourhood of the
    corresponding pixel of the second (Kutulakos 2000; sec. 3.1.1).
``L2Metric``  patches: plain squared L2 (the ``ml2`` comparison of sec. 5.2).

Departures from the paper
-------------------------
* The curve integral of eq. 4-5 is the *mean* over the curve's points (ds = 1/P), as in
  :mod:`.chamfer`; the patch distances are likewise the *mean* over pixels of the squared
  differences, not the sum. Both only rescale rho by a constant per item size: d of
  eq. 10-11 is unchanged and sigma absorbs the factor.
* Curves are point sets (edge pixels), not parametric curves; the min over s'(s) of eq. 4
  is the nearest point.
* The shuffle distance ignores neighbours outside the second patch (no padding values
  enter the minimum); the zero offset is always available.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable, ClassVar, Literal, cast

import numpy as np

from .. import similarity
from ..features import PROFILES, Profile, chamfer_image, edge_map, to_grey
from .chamfer import chamfer_distance
from .curves import Curves, PointChamferImage, profile_g
from .edge_settings import BLUR, CANNY_HIGH, CANNY_LOW, G0, PROFILE

__all__ = ["Metric", "ChamferMetric", "ShuffleMetric", "L2Metric", "make_metric", "METRICS", "check_patches"]

Items = Any  # Curves for curve metrics, (N, h, w) float64 for patch metrics


class Metric(ABC):
    """A distance function rho(a, b) >= 0 on training items (not necessarily symmetric)."""

    #: Registered name, stored in the learned model.
    name: ClassVar[str]
    #: ``"curve"`` (items are :class:`Curves`) or ``"patch"`` (items are (N, h, w) float64).
    kind: ClassVar[Literal["curve", "patch"]]

    @abstractmethod
    def check_items(self, items: Items) -> Items:
        """Validate and normalise a batch of items; raise ValueError if malformed or empty."""

    @abstractmethod
    def pairwise(self, a: Items, b: Items) -> np.ndarray:
        """Distance matrix D[i, j] = rho(a_i, b_j), (A, B) float64."""

    @abstractmethod
    def reference(self, b: Items, j: int, extent: float = 0.0) -> Callable[[Items], np.ndarray]:
        """A function ``f(items) -> (N,)`` giving rho(items_i, b_j), for repeated calls.

        ``extent`` (pixels) is how far transformed items may stray from ``b_j``; a
        curve metric sizes its chamfer canvas with it.
        """

    @abstractmethod
    def transform(self, items: Items, alphas: np.ndarray) -> Items:
        """T_alpha applied to each item, alphas (N, 4) or (4,) (sec. 3.2)."""

    @abstractmethod
    def features(self, frame: np.ndarray) -> np.ndarray:
        """Per-frame observation features that :meth:`to_image` reads (chamfer image or patch)."""

    @abstractmethod
    def to_image(self, exemplars: Items, features: np.ndarray, alphas: np.ndarray | None = None,
                 k: np.ndarray | None = None) -> np.ndarray:
        """rho(T_alpha x~_k, z) for particles (alpha, k) against one frame's features (eq. 7)."""

    def params(self) -> dict[str, float | str | int]:
        """Constructor parameters (stored in the model so the metric can be rebuilt)."""
        return {}

    @staticmethod
    def n_items(items: Items) -> int:
        return len(items)

    @staticmethod
    def subset(items: Items, idx: np.ndarray | int) -> Items:
        if isinstance(items, Curves):
            return items[idx]
        idx = np.atleast_1d(np.asarray(idx))
        return items[idx]


# --------------------------------------------------------------------------------------
# Chamfer distance on curves
# --------------------------------------------------------------------------------------


class ChamferMetric(Metric):
    """Non-symmetric chamfer distance between curves (eq. 4-5).

    rho(a, b) = mean over the points r of a of gamma(b, r), where gamma(b, .) is the
    chamfer image of b with profile g.

    Parameters
    ----------
    profile : {"quadratic", "truncated", "linear"}
        g(u) = u^2, min(u^2, g0) or u. The paper's kernel (sec. 3.3.3) assumes quadratic
        or truncated quadratic.
    g0 : float
        Truncation level in squared pixels (truncated profile only).
    upsample : int
        Canvas pixels per image pixel for point-set chamfer images (1 / (2 upsample) px
        rasterisation error).
    method : {"image", "kdtree"}
        ``image``: chamfer image on a canvas, bilinear sampling (fast, the paper's eq. 5);
        ``kdtree``: exact nearest-point distances (slow, for checking).
    canny_low, canny_high, blur : float
        Canny parameters of :meth:`features` (frames -> chamfer image).
    """

    name = "chamfer"
    kind = "curve"

    def __init__(self, profile: str = PROFILE, g0: float = G0, upsample: int = 2,
                 method: Literal["image", "kdtree"] = "image", canny_low: float = CANNY_LOW,
                 canny_high: float = CANNY_HIGH, blur: float = BLUR) -> None:
        if profile not in PROFILES:
            raise ValueError(f"unknown chamfer profile {profile!r}; choose one of {PROFILES}")
        if profile == "truncated" and not g0 > 0:
            raise ValueError(f"truncation level g0 must be positive, got {g0}")
        if method not in ("image", "kdtree"):
            raise ValueError(f"unknown chamfer method {method!r}; choose 'image' or 'kdtree'")
        if int(upsample) != upsample or upsample < 1:
            raise ValueError(f"upsample must be a positive integer, got {upsample}")
        self.profile = profile
        self.g0 = float(g0)
        self.upsample = int(upsample)
        self.method = method
        self.canny_low, self.canny_high, self.blur = float(canny_low), float(canny_high), float(blur)

    def params(self) -> dict[str, float | str | int]:
        return {"profile": self.profile, "g0": self.g0, "upsample": self.upsample}

    def check_items(self, items: Items) -> Curves:
        if isinstance(items, Curves):
            c = items
        else:
            if items is None or len(items) == 0:
                raise ValueError("no training curves given")
            c = Curves.from_list(list(items))
        if len(c) == 0:
            raise ValueError("no training curves given")
        return c

    def _image(self, pts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> PointChamferImage:
        return PointChamferImage(pts, lo, hi, self.profile, self.g0, self.upsample)

    def point_image(self, points: np.ndarray, extent: float = 0.0) -> PointChamferImage:
        """Chamfer image gamma(z, .) of one point set z, (P, 2), on a canvas reaching ``extent`` px beyond it."""
        pts = np.asarray(points, dtype=np.float64)
        return self._image(pts, pts.min(axis=0) - 1.0 - extent, pts.max(axis=0) + 1.0 + extent)

    def pairwise(self, a: Curves, b: Curves) -> np.ndarray:
        """D[i, j] = rho(a_i, b_j) = mean_s gamma(b_j, r_{a_i}(s)), (A, B) float64 (eq. 5).

        One chamfer image per b_j, on a canvas covering every point of a and b.
        """
        a, b = self.check_items(a), self.check_items(b)
        out = np.empty((len(a), len(b)))
        if self.method == "kdtree":
            from scipy.spatial import cKDTree  # imported here: most processes never need it

            mask = a.mask
            for j in range(len(b)):
                u, _ = cKDTree(b.curve(j)).query(a.points.reshape(-1, 2))
                g = profile_g(u.reshape(mask.shape), self.profile, self.g0)
                # rho = (1/P) sum_s g(min_s' |r_b(s') - r_a(s)|)                       (eq. 4)
                out[:, j] = np.where(mask, g, 0.0).sum(axis=1) / a.n_points
            return out
        lo_a, hi_a = a.bounds()
        lo_b, hi_b = b.bounds()
        lo = np.minimum(lo_a, lo_b) - 1.0
        hi = np.maximum(hi_a, hi_b) + 1.0
        for j in range(len(b)):
            img = self._image(b.curve(j), lo, hi)
            out[:, j] = img.distance(a.points, a.n_points)
        return out

    def reference(self, b: Curves, j: int, extent: float = 0.0) -> Callable[[Curves], np.ndarray]:
        b = self.check_items(b)
        pts = b.curve(j)
        if self.method == "kdtree":
            from scipy.spatial import cKDTree

            tree = cKDTree(pts)

            def f_tree(items: Curves) -> np.ndarray:
                u, _ = tree.query(items.points.reshape(-1, 2))
                g = profile_g(u.reshape(items.points.shape[:2]), self.profile, self.g0)
                return np.where(items.mask, g, 0.0).sum(axis=1) / items.n_points

            return f_tree
        img = self.point_image(pts, extent)

        def f(items: Curves) -> np.ndarray:
            return img.distance(items.points, items.n_points)

        return f

    def transform(self, items: Curves, alphas: np.ndarray) -> Curves:
        return self.check_items(items).transformed(alphas)

    def features(self, frame: np.ndarray) -> np.ndarray:
        """(H, W) image -> (H, W) float32 chamfer image gamma(z, .) of its Canny edges (eq. 5)."""
        edges = edge_map(to_grey(frame), self.canny_low, self.canny_high, self.blur)
        return chamfer_image(edges, cast(Profile, self.profile), self.g0)

    def to_image(self, exemplars: Curves, features: np.ndarray, alphas: np.ndarray | None = None,
                 k: np.ndarray | None = None, outside: float | None = None) -> np.ndarray:
        """rho(T_alpha x~_k, z) for N particles (eq. 5, 7).

        Parameters
        ----------
        exemplars : Curves, K exemplars in their own frame.
        features : (H, W) float32 chamfer image of the frame.
        alphas : (N, 4) float64, particle transforms (required).
        k : (N,) int64, particle exemplar indices (default: all zeros).
        outside : float, gamma for points off the image (default: image maximum).

        Returns
        -------
        (N,) float64
        """
        if alphas is None:
            raise ValueError("the chamfer metric needs particle transforms alphas (N, 4)")
        a = similarity.check_alpha(alphas)
        a = a[None] if a.ndim == 1 else a
        k = np.zeros(a.shape[0], dtype=np.int64) if k is None else np.asarray(k, dtype=np.int64)
        curves = similarity.apply_many(a, exemplars.points[k])
        return chamfer_distance(features, curves, exemplars.n_points[k], outside=outside)


# --------------------------------------------------------------------------------------
# Patch distances
# --------------------------------------------------------------------------------------


def check_patches(items: Any, name: str = "patches") -> np.ndarray:
    """Validate a batch of patches: (N, h, w) finite, N >= 1, h, w >= 1. Returns float64."""
    p = np.asarray(items, dtype=np.float64)
    if p.ndim == 2:
        p = p[None]
    if p.ndim != 3 or p.shape[1] < 1 or p.shape[2] < 1:
        raise ValueError(f"{name} must be (N, h, w), got shape {p.shape}")
    if p.shape[0] == 0:
        raise ValueError(f"no {name} given")
    if not np.isfinite(p).all():
        raise ValueError(f"{name} contain NaN or inf")
    return p


class _PatchMetric(Metric):
    kind = "patch"

    def check_items(self, items: Items) -> np.ndarray:
        return check_patches(items)

    def reference(self, b: np.ndarray, j: int, extent: float = 0.0) -> Callable[[np.ndarray], np.ndarray]:
        ref = check_patches(b)[j : j + 1]
        return lambda items: self.pairwise(items, ref)[:, 0]

    def transform(self, items: np.ndarray, alphas: np.ndarray) -> np.ndarray:
        """z = T_alpha x for patches, I_z(T_alpha r) = I_x(r) (sec. 3.2), r centred on the patch centre."""
        p = check_patches(items)
        a = similarity.check_alpha(alphas)
        a = np.broadcast_to(a, (p.shape[0], 4)) if a.ndim == 1 else a
        h, w = p.shape[1:]
        centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0, 0.0, 1.0])
        out = np.empty_like(p)
        for i in range(p.shape[0]):
            # z(r) = x(T_alpha^-1 r): sample x at centre + T_alpha^-1 r
            out[i] = similarity.warp_patch(p[i], similarity.compose(centre, similarity.invert(a[i])), (h, w))
        return out

    def features(self, frame: np.ndarray) -> np.ndarray:
        """(h, w) grey or colour patch -> (h, w) float64 grey levels."""
        f = np.asarray(frame)
        if f.ndim == 3:
            f = to_grey(f)
        return check_patches(f, "observation")[0]

    def to_image(self, exemplars: np.ndarray, features: np.ndarray, alphas: np.ndarray | None = None,
                 k: np.ndarray | None = None) -> np.ndarray:
        """rho(x~_k, z) of the observed patch against exemplars (sec. 5.2: no alpha).

        Parameters
        ----------
        exemplars : (K, h, w) float64
        features : (h, w) float64, the observed patch z (already cropped / registered).
        alphas : must be None (patch tracking has no transform; crop the frame first).
        k : (N,) int64, optional. If given, returns the distance for each particle.

        Returns
        -------
        (K,) float64 if ``k`` is None, else (N,) float64 = rho[k].
        """
        if alphas is not None:
            raise ValueError("patch metrics track without transforms (sec. 5.2); crop the frame with "
                             "similarity.warp_patch and pass alphas=None")
        ex = check_patches(exemplars, "exemplars")
        z = check_patches(features, "observation")
        if z.shape[1:] != ex.shape[1:]:
            raise ValueError(f"observation patch {z.shape[1:]} does not match exemplar size {ex.shape[1:]}")
        rho = self.pairwise(ex, z)[:, 0]
        return rho if k is None else rho[np.asarray(k, dtype=np.int64)]


class L2Metric(_PatchMetric):
    """Mean squared difference of pixel values, rho(a, b) = (1/n) sum_p (a(p) - b(p))^2."""

    name = "l2"

    def pairwise(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        a, b = check_patches(a), check_patches(b)
        if a.shape[1:] != b.shape[1:]:
            raise ValueError(f"patch sizes differ: {a.shape[1:]} vs {b.shape[1:]}")
        fa = a.reshape(a.shape[0], -1)
        fb = b.reshape(b.shape[0], -1)
        # |a - b|^2 = |a|^2 + |b|^2 - 2 a.b
        d = (fa * fa).sum(1)[:, None] + (fb * fb).sum(1)[None, :] - 2.0 * fa @ fb.T
        return np.maximum(d, 0.0) / fa.shape[1]


class ShuffleMetric(_PatchMetric):
    """Shuffle distance (Kutulakos 2000) with neighbourhood radius r (sec. 3.1.1).

    rho(a, b) = (1/n) sum_p min_{|o|_inf <= r} (a(p) - b(p + o))^2

    Each pixel p of ``a`` is matched with the most similar pixel of ``b`` in the
    (2r+1)^2 window around p; neighbours outside ``b`` are ignored. Not symmetric.
    Vectorised over pairs, pixels and offsets with shifted copies of ``b``.

    Parameters
    ----------
    radius : int, r >= 0. r = 0 is :class:`L2Metric`.
    chunk : int, maximum number of (pair, pixel) elements held in memory at once.
    """

    name = "shuffle"

    def __init__(self, radius: int = 1, chunk: int = 4_000_000) -> None:
        if int(radius) != radius or radius < 0:
            raise ValueError(f"shuffle radius must be a non-negative integer, got {radius}")
        self.radius = int(radius)
        self.chunk = int(chunk)

    def params(self) -> dict[str, float | str | int]:
        return {"radius": self.radius}

    def _shifted(self, b: np.ndarray) -> np.ndarray:
        """(O, B, n) copies of b with b(p + o) at p, +inf where p + o is off the patch."""
        r = self.radius
        nb, h, w = b.shape
        pad = np.full((nb, h + 2 * r, w + 2 * r), np.inf)
        pad[:, r : r + h, r : r + w] = b
        out = np.empty(((2 * r + 1) ** 2, nb, h * w))
        i = 0
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                out[i] = pad[:, r + dy : r + dy + h, r + dx : r + dx + w].reshape(nb, -1)
                i += 1
        return out

    def pairwise(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        a, b = check_patches(a), check_patches(b)
        if a.shape[1:] != b.shape[1:]:
            raise ValueError(f"patch sizes differ: {a.shape[1:]} vs {b.shape[1:]}")
        fa = a.reshape(a.shape[0], -1)
        n = fa.shape[1]
        shifted = self._shifted(b)  # (O, B, n)
        out = np.empty((a.shape[0], b.shape[0]))
        rows = max(1, self.chunk // max(1, b.shape[0] * n))
        for i0 in range(0, a.shape[0], rows):
            ai = fa[i0 : i0 + rows, None, :]  # (A', 1, n)
            best = np.full((ai.shape[0], b.shape[0], n), np.inf)
            for sh in shifted:
                diff = ai - sh[None]
                np.minimum(best, diff * diff, out=best)
            # rho = (1/n) sum_p min_o (a(p) - b(p + o))^2
            out[i0 : i0 + rows] = best.mean(axis=2)
        return out


METRICS: dict[str, type[Metric]] = {"chamfer": ChamferMetric, "shuffle": ShuffleMetric, "l2": L2Metric}


def make_metric(name: str | Metric, **params: Any) -> Metric:
    """Metric by name (``"chamfer"``, ``"shuffle"``, ``"l2"``) with constructor parameters.

    A :class:`Metric` instance is returned unchanged (``params`` must then be empty).
    """
    if isinstance(name, Metric):
        if params:
            raise ValueError("pass metric parameters to the Metric constructor, not with an instance")
        return name
    if name not in METRICS:
        raise ValueError(f"unknown metric {name!r}; choose one of {sorted(METRICS)}")
    return METRICS[name](**params)
