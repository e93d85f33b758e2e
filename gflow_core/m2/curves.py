"""Curves as padded point sets, and the chamfer image of a point set (Toyama & Blake 2002, eq. 4-5).

A *curve* here is what the paper's curve r_z(s) becomes in practice: the set of edge
points of one training item, (x, y) in pixels (origin at the top-left pixel centre),
relative to the item's reference point. A batch of N curves with different numbers of
points is stored padded to a common P, with the true lengths alongside.

The chamfer image gamma(z, r) = min_s' g(|r_z(s') - r|) of a point set z (eq. 5) is
built on a canvas ``upsample`` times finer than the pixel grid with SciPy's exact (labelled)
distance transform, which finds the nearest point of z; the distance to it is then
computed exactly in floating point (:class:`PointChamferImage`), so point sets with
sub-pixel coordinates (after centring or a similarity transform) keep their accuracy.
Points off the canvas get an upper bound of the true distance that keeps increasing
away from the canvas, so direct descent (:mod:`.align`) never stalls on a plateau.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .. import similarity
from ..features import PROFILES

__all__ = ["Curves", "subsample_points", "PointChamferImage", "profile_g"]

#: Largest canvas side accepted for a point-set chamfer image (pixels of the canvas).
MAX_CANVAS = 8192


def subsample_points(points: np.ndarray, max_points: int) -> np.ndarray:
    """Keep at most ``max_points`` points, evenly spaced along the given order (deterministic).

    Parameters
    ----------
    points : (P, 2) float64
    max_points : int, >= 1

    Returns
    -------
    (min(P, max_points), 2) float64
    """
    pts = np.asarray(points, dtype=np.float64)
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    if pts.shape[0] <= max_points:
        return pts.copy()
    pick = np.linspace(0, pts.shape[0] - 1, max_points).round().astype(np.intp)
    return pts[pick]


@dataclass(frozen=True)
class Curves:
    """N curves (point sets) padded to P points.

    Attributes
    ----------
    points : (N, P, 2) float64
        (x, y) in pixels. Rows past ``n_points[i]`` repeat the valid points cyclically,
        so they are finite and inside the curve's extent, but every computation masks them.
    n_points : (N,) int64
        Number of valid points of each curve, in ``[1, P]``.
    """

    points: np.ndarray
    n_points: np.ndarray

    def __post_init__(self) -> None:
        p = np.asarray(self.points, dtype=np.float64)
        if p.ndim != 3 or p.shape[2] != 2 or p.shape[1] < 1:
            raise ValueError(f"curve points must be (N, P, 2) with P >= 1, got shape {p.shape}")
        n = np.asarray(self.n_points)
        if n.shape != (p.shape[0],):
            raise ValueError(f"n_points must be ({p.shape[0]},), got {n.shape}")
        if n.size and (not np.issubdtype(n.dtype, np.integer) and not np.all(n == np.round(n))):
            raise ValueError("n_points must be integers")
        n = n.astype(np.int64)
        if n.size and ((n < 1).any() or (n > p.shape[1]).any()):
            raise ValueError(f"every curve needs between 1 and P={p.shape[1]} points")
        if not np.isfinite(p).all():
            raise ValueError("curve points contain NaN or inf")
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "n_points", n)

    @classmethod
    def from_list(cls, curves: Sequence[np.ndarray], max_points: int | None = None) -> "Curves":
        """Pad a list of (P_i, 2) point sets, subsampling each to at most ``max_points``.

        Raises
        ------
        ValueError
            If the list is empty or any point set is empty or not (P_i, 2).
        """
        if len(curves) == 0:
            raise ValueError("no curves given")
        pts = []
        for i, c in enumerate(curves):
            c = np.asarray(c, dtype=np.float64)
            if c.ndim != 2 or c.shape[1] != 2 or c.shape[0] < 1:
                raise ValueError(f"curve {i} must be (P, 2) with P >= 1, got shape {c.shape}")
            pts.append(subsample_points(c, max_points) if max_points is not None else c)
        p_max = max(c.shape[0] for c in pts)
        out = np.empty((len(pts), p_max, 2))
        for i, c in enumerate(pts):
            out[i] = np.resize(c, (p_max, 2)) if c.shape[0] < p_max else c
        return cls(out, np.array([c.shape[0] for c in pts], dtype=np.int64))

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def __getitem__(self, idx: int | slice | np.ndarray) -> "Curves":
        """Sub-batch; an integer gives a batch of one."""
        sel = [int(idx)] if isinstance(idx, (int, np.integer)) else idx
        return Curves(self.points[sel], self.n_points[sel])

    def curve(self, i: int) -> np.ndarray:
        """(n_points[i], 2) float64, the valid points of curve i."""
        return self.points[i, : self.n_points[i]]

    def to_list(self) -> list[np.ndarray]:
        return [self.curve(i) for i in range(len(self))]

    @property
    def mask(self) -> np.ndarray:
        """(N, P) bool, True on valid points."""
        return np.arange(self.points.shape[1])[None, :] < self.n_points[:, None]

    def transformed(self, alphas: np.ndarray) -> "Curves":
        """T_alpha applied to each curve (sec. 3.2): r -> u + R(theta) s r.

        Parameters
        ----------
        alphas : (N, 4) or (4,) float64, (ux, uy, theta, s); one transform per curve or one for all.
        """
        a = similarity.check_alpha(alphas)
        if a.ndim == 1:
            a = np.broadcast_to(a, (len(self), 4))
        if a.shape[0] != len(self):
            raise ValueError(f"need one transform per curve ({len(self)}), got {a.shape[0]}")
        return Curves(similarity.apply_many(a, self.points), self.n_points)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper (x, y) corners of all valid points, (2,) float64 each."""
        m = self.mask
        v = self.points[m]
        return v.min(axis=0), v.max(axis=0)

    def centroids(self) -> np.ndarray:
        """(N, 2) float64 mean of the valid points of each curve."""
        m = self.mask[..., None]
        return (self.points * m).sum(axis=1) / self.n_points[:, None]


def profile_g(u: np.ndarray, profile: str, g0: float) -> np.ndarray:
    """The chamfer profile g(u) of eq. 4: ``u**2``, ``min(u**2, g0)`` or ``u`` (linear)."""
    if profile == "linear":
        return u
    # g(u) = u^2
    g = u * u
    if profile == "truncated":
        # g(u) = min(u^2, g0)
        g = np.minimum(g, g0)
    return g


class PointChamferImage:
    """Chamfer image gamma(z, .) of one point set z on an up-sampled canvas (eq. 5).

    The canvas holds, for every canvas pixel, the label of its nearest *seed* (a canvas
    pixel holding points of z) from SciPy's exact distance transform with indices; each seed
    keeps the mean of the points of z that fall in it (so z is resolved to one point per
    canvas pixel, 1 / upsample image pixels). The distance at a query point r
    is the exact Euclidean distance from r to the nearest of the seed points labelled at
    the 4 canvas pixels around r. This avoids both the thickening of a rasterised curve
    (a dense diagonal curve covers two canvas pixels, which would bias distances down by
    a quarter of a canvas pixel) and the overshoot of bilinear interpolation across the
    curve; points off the canvas use the labels at the nearest canvas pixels and get an
    upper bound of the true distance.

    Parameters
    ----------
    points : (P, 2) float64
        The point set z, (x, y) pixels.
    lo, hi : (2,) float64
        Canvas extent in pixels (x, y); must contain ``points``. The canvas spans
        ``[lo, hi]`` at ``upsample`` canvas pixels per image pixel.
    profile : {"quadratic", "truncated", "linear"}
    g0 : float
        Truncation level (squared pixels) of the truncated profile.
    upsample : int
        Canvas pixels per image pixel (>= 1).
    """

    def __init__(self, points: np.ndarray, lo: np.ndarray, hi: np.ndarray, profile: str = "quadratic",
                 g0: float = 100.0, upsample: int = 2) -> None:
        if profile not in PROFILES:
            raise ValueError(f"unknown chamfer profile {profile!r}; choose one of {PROFILES}")
        if profile == "truncated" and not g0 > 0:
            raise ValueError(f"truncation level g0 must be positive, got {g0}")
        if int(upsample) != upsample or upsample < 1:
            raise ValueError(f"upsample must be a positive integer, got {upsample}")
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 1:
            raise ValueError(f"point set must be (P, 2) with P >= 1, got shape {pts.shape}")
        if not np.isfinite(pts).all():
            raise ValueError("point set contains NaN or inf")
        self.profile = profile
        self.g0 = float(g0)
        self.up = int(upsample)
        self.lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        # canvas pixel (col, row) = (r - lo) * up
        w = max(int(np.ceil((hi[0] - self.lo[0]) * self.up)) + 1, 2)
        h = max(int(np.ceil((hi[1] - self.lo[1]) * self.up)) + 1, 2)
        if max(w, h) > MAX_CANVAS:
            raise ValueError(f"chamfer canvas {w}x{h} is too large; are the curves centred on their reference point?")
        c = np.rint((pts - self.lo) * self.up).astype(np.intp)
        c[:, 0] = np.clip(c[:, 0], 0, w - 1)
        c[:, 1] = np.clip(c[:, 1], 0, h - 1)
        lin = c[:, 1] * w + c[:, 0]
        # the distinct seed pixels, in row-major order
        seeds, inv_idx = np.unique(lin, return_inverse=True)
        cnt = np.bincount(inv_idx).astype(np.float64)
        self._seed_x = np.bincount(inv_idx, weights=pts[:, 0]) / cnt
        self._seed_y = np.bincount(inv_idx, weights=pts[:, 1]) / cnt
        # the nearest seed of every canvas pixel, by SciPy's exact EDT (no thread pool, so the
        # same on every machine; OpenCV's labelled transform is not, see features.distance_transform)
        not_seed = np.ones(h * w, dtype=bool)
        not_seed[seeds] = False
        from scipy import ndimage  # imported here: 0.3 s at start-up for the processes that never need it

        nearest = ndimage.distance_transform_edt(not_seed.reshape(h, w), return_distances=False,
                                                 return_indices=True)
        seed_of_pixel = np.full(h * w, -1, dtype=np.intp)
        seed_of_pixel[seeds] = np.arange(seeds.size)
        self._lab = seed_of_pixel[(nearest[0] * w + nearest[1]).ravel()]
        self.shape = (h, w)

    @property
    def gamma(self) -> np.ndarray:
        """(H, W) float64 canvas of gamma values at the canvas pixel centres, indexed (row, col)."""
        h, w = self.shape
        rows, cols = np.mgrid[0:h, 0:w]
        pts = np.stack([cols, rows], axis=-1) / self.up + self.lo
        return self(pts)

    def u(self, pts: np.ndarray) -> np.ndarray:
        """Distance (pixels) from points r to the nearest point of z; (..., 2) -> (...) float64."""
        h, w = self.shape
        r = np.asarray(pts, dtype=np.float64)
        rx, ry = r[..., 0], r[..., 1]
        x0 = np.clip((rx - self.lo[0]) * self.up, 0, w - 2).astype(np.intp)
        y0 = np.clip((ry - self.lo[1]) * self.up, 0, h - 2).astype(np.intp)
        i00 = y0 * w + x0
        best = None
        for off in (0, 1, w, w + 1):
            lab = self._lab.take(i00 + off)
            dx = rx - self._seed_x.take(lab)
            dy = ry - self._seed_y.take(lab)
            d2 = dx * dx + dy * dy
            best = d2 if best is None else np.minimum(best, d2, out=best)
        assert best is not None
        return np.sqrt(best)

    def __call__(self, pts: np.ndarray, scale: float | np.ndarray = 1.0) -> np.ndarray:
        """gamma(z, r) = g(scale * u(r)); (..., 2) -> (...) float64.

        The distance u is interpolated and g applied afterwards, so gamma of a dense
        straight curve shifted by delta is exactly g(delta) (bilinear interpolation of u^2
        would bias it by about 1 / (4 up^2)). ``scale`` multiplies distances (used to
        measure distances in a transformed frame, see :mod:`.align`).
        """
        return profile_g(np.asarray(scale) * self.u(pts), self.profile, self.g0)

    def distance(self, curves: np.ndarray, n_points: np.ndarray, scale: float | np.ndarray = 1.0) -> np.ndarray:
        """Chamfer distance rho(curve, z) = mean over the curve's points of gamma(z, r) (eq. 5).

        Parameters
        ----------
        curves : (..., P, 2) float64
        n_points : (...) int64
        scale : float or (...) float64, distances are multiplied by it before g.

        Returns
        -------
        (...) float64
        """
        g = self(curves, np.asarray(scale)[..., None])
        n = np.asarray(n_points)
        mask = np.arange(g.shape[-1]) < n[..., None]
        # rho = (1/P_k) sum_{s < P_k} gamma(z, r(s))                               (eq. 5)
        return np.where(mask, g, 0.0).sum(axis=-1) / np.maximum(n, 1)
