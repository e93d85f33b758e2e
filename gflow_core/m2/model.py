"""The learned M2 model and its array form for storage (Toyama & Blake 2002, sec. 2.2).

:class:`M2Model` holds the learned parameters Lambda: the metric and its parameters, the
exemplars x~_k (curves or patches), the kernel parameters d_k, sigma_k (eq. 10-11), the
mixture weights pi_k, the Markov matrix M and the AR(1) process on alpha (sec. 4.3),
and the reference box size that maps a box (x, y, w, h) to a transform alpha.

:meth:`M2Model.to_arrays` gives a flat ``dict[str, np.ndarray]`` with numeric and
fixed-width unicode arrays only (``np.savez`` / ``np.load(allow_pickle=False)`` safe);
:meth:`M2Model.from_arrays` checks the format version, every key, shape, dtype and value
and raises ``ValueError`` naming what is wrong.

Array keys (format version 3; version 1 files, which have no ``app_*`` arrays, and version 2
files, which have no ``train_scale``, are read too)
--------------------------------------------------------------------------------------------
format_version  () int64           FORMAT_VERSION
metric          () str             "chamfer" | "shuffle" | "l2"
kernel          () str             "moments" | "mle"
profile         () str             chamfer profile ("quadratic" | "truncated" | "linear")
g0              () float64         truncation level, squared pixels
upsample        () int64           chamfer canvas upsampling used in learning
shuffle_radius  () int64           shuffle neighbourhood radius r
exemplar_curves (K, P, 2) float64  curve metrics only: x~_k points (x, y), item frame
exemplar_n_points (K,) int64       curve metrics only
exemplar_patches (K, h, w) float64 patch metrics only
exemplar_frame  (K,) int64         frame index of each exemplar in its training sequence (-1 if unknown)
d, sigma, pi    (K,) float64
markov          (K, K) float64
ar_A, ar_B      (4, 4) float64;  ar_mean (4,) float64
ref_size        (2,) float64       (w, h) of the reference box in item coordinates
train_scale     () float64         the largest scale s of a training item (its size over the
                                   reference box); version 3 (older files: inf, see below)
app_patches     (K, th, tw, 4) float32  optional (curve metrics): appearance exemplars a_k
                                   (:mod:`.appearance_metric`); with it app_sigma, app_d (K,) float64
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..features import PROFILES
from .curves import Curves
from .distances import METRICS, Metric, make_metric
from .dynamics import ARDynamics
from .kernel import KERNEL_METHODS
from .appearance_metric import AppearanceKernels
from .patch_tracking import PatchExemplars
from .tracking import ContourExemplars

__all__ = ["M2Model", "FORMAT_VERSION"]

FORMAT_VERSION = 3
#: format versions this code reads
READS_VERSIONS = (1, 2, 3)

_SCALARS = {"format_version": "i", "metric": "U", "kernel": "U", "profile": "U", "g0": "f", "upsample": "i",
            "shuffle_radius": "i"}
_COMMON = ("exemplar_frame", "d", "sigma", "pi", "markov", "ar_A", "ar_mean", "ar_B", "ref_size")
_CURVE = ("exemplar_curves", "exemplar_n_points")
_PATCH = ("exemplar_patches",)
_APPEARANCE = ("app_patches", "app_sigma", "app_d")


def _stable(dyn: ARDynamics) -> ARDynamics:
    """``dyn``, unless its transition matrix A has an eigenvalue of modulus above 1: an AR(1) process that diverges,
    which no learned one does (Yule-Walker's estimate has none; a random walk's A = I has 1), and whose particles
    run off to boxes of no size or of every size, where a tracker spent minutes on each frame."""
    radius = float(np.max(np.abs(np.linalg.eigvals(dyn.A))))
    if radius > 1.0 + 1e-6:
        raise ValueError(f"ar_A has an eigenvalue of modulus {radius:.3g} > 1: the AR(1) process would diverge "
                         f"(a learned one has none above 1)")
    return dyn


@dataclass(frozen=True)
class M2Model:
    """Everything learned by :func:`gflow_core.m2.learn.learn`.

    Attributes
    ----------
    metric : str, "chamfer", "shuffle" or "l2".
    kernel : str, "moments" (eq. 10) or "mle" (eq. 11).
    exemplars : Curves (K curves, chamfer) or (K, h, w) float64 patches.
    d, sigma, pi : (K,) float64, kernel dimension, width and mixture weight.
    markov : (K, K) float64, rows sum to 1.
    dynamics : ARDynamics on beta = (ux, uy, theta, log s).
    ref_size : (2,) float64, (w, h) of the reference box in item coordinates.
    exemplar_frame : (K,) int64, frame index (TrainingSet.frame_index) of each exemplar (-1 if unknown).
    profile, g0, upsample : chamfer parameters.
    shuffle_radius : int, shuffle neighbourhood radius.
    appearance : AppearanceKernels or None, appearance exemplars and kernels beside chamfer
        (curve metrics only, :mod:`.appearance_metric`).
    train_scale : float, the largest scale s of a training item (its size over the reference box);
        a target tracked at a larger s gets the angle and scale noise of the dynamics scaled down
        (:func:`.dynamics.at_resolution`). inf for files of format version 2 and older (their
        dynamics are used as learned).
    """

    metric: str
    kernel: str
    exemplars: Curves | np.ndarray
    d: np.ndarray
    sigma: np.ndarray
    pi: np.ndarray
    markov: np.ndarray
    dynamics: ARDynamics
    ref_size: np.ndarray
    exemplar_frame: np.ndarray | None = None
    profile: str = "quadratic"
    g0: float = 100.0
    upsample: int = 2
    shuffle_radius: int = 1
    appearance: AppearanceKernels | None = None
    train_scale: float = float("inf")

    def __post_init__(self) -> None:
        if self.metric not in METRICS:
            raise ValueError(f"unknown metric {self.metric!r}; choose one of {sorted(METRICS)}")
        if self.kernel not in KERNEL_METHODS:
            raise ValueError(f"unknown kernel estimator {self.kernel!r}; choose one of {KERNEL_METHODS}")
        if self.profile not in PROFILES:
            raise ValueError(f"unknown chamfer profile {self.profile!r}")
        if not (np.isfinite(self.g0) and self.g0 > 0):
            raise ValueError(f"g0 must be positive, got {self.g0}")
        if int(self.upsample) != self.upsample or self.upsample < 1:
            raise ValueError(f"upsample must be a positive integer, got {self.upsample}")
        if int(self.shuffle_radius) != self.shuffle_radius or self.shuffle_radius < 0:
            raise ValueError(f"shuffle_radius must be a non-negative integer, got {self.shuffle_radius}")
        kind = METRICS[self.metric].kind
        if kind == "curve":
            if not isinstance(self.exemplars, Curves):
                raise ValueError(f"metric {self.metric!r} needs curve exemplars (Curves)")
            K = len(self.exemplars)
        else:
            ex = np.asarray(self.exemplars, dtype=np.float64)
            if ex.ndim != 3 or min(ex.shape) < 1:
                raise ValueError(f"patch exemplars must be (K, h, w), got shape {ex.shape}")
            if not np.isfinite(ex).all():
                raise ValueError("patch exemplars contain NaN or inf")
            object.__setattr__(self, "exemplars", ex)
            K = ex.shape[0]
        if K < 1:
            raise ValueError("a model needs at least one exemplar")
        for name in ("d", "sigma", "pi"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (K,):
                raise ValueError(f"{name} must have shape ({K},), got {v.shape}")
            if not np.isfinite(v).all():
                raise ValueError(f"{name} contains NaN or inf")
            object.__setattr__(self, name, v)
        if (self.sigma <= 0).any():
            raise ValueError("kernel widths sigma must be positive")
        if (self.d <= 0).any():
            raise ValueError("kernel dimensions d must be positive")
        if (self.pi < 0).any() or not np.isclose(self.pi.sum(), 1.0):
            raise ValueError("mixture weights pi must be non-negative and sum to 1")
        m = np.asarray(self.markov, dtype=np.float64)
        if m.shape != (K, K):
            raise ValueError(f"markov must have shape ({K}, {K}), got {m.shape}")
        if not np.isfinite(m).all() or (m < 0).any() or not np.allclose(m.sum(axis=1), 1.0):
            raise ValueError("markov must be finite, non-negative, with rows summing to 1")
        object.__setattr__(self, "markov", m)
        if not isinstance(self.dynamics, ARDynamics):
            raise ValueError("dynamics must be an ARDynamics")
        rs = np.asarray(self.ref_size, dtype=np.float64)
        if rs.shape != (2,) or not np.isfinite(rs).all() or (rs <= 0).any():
            raise ValueError(f"ref_size must be (2,) positive, got {rs}")
        object.__setattr__(self, "ref_size", rs)
        ei = np.full(K, -1, dtype=np.int64) if self.exemplar_frame is None else np.asarray(self.exemplar_frame)
        if ei.shape != (K,) or not np.issubdtype(ei.dtype, np.integer):
            raise ValueError(f"exemplar_frame must be ({K},) integers, got shape {ei.shape} dtype {ei.dtype}")
        object.__setattr__(self, "exemplar_frame", ei.astype(np.int64))
        object.__setattr__(self, "g0", float(self.g0))
        object.__setattr__(self, "upsample", int(self.upsample))
        object.__setattr__(self, "shuffle_radius", int(self.shuffle_radius))
        object.__setattr__(self, "train_scale", float(self.train_scale))
        if not self.train_scale > 0:  # inf allowed (older files), NaN refused
            raise ValueError(f"train_scale must be positive, got {self.train_scale}")
        if self.appearance is not None:
            self._check_appearance(K)

    def _check_appearance(self, K: int) -> None:
        a = self.appearance
        assert a is not None
        if self.kind != "curve":
            raise ValueError("appearance exemplars go with contour (chamfer) models only")
        p = np.asarray(a.patches)
        if p.ndim != 4 or p.shape[0] != K or min(p.shape[1:3]) < 2 or p.shape[3] < 1:
            raise ValueError(f"appearance patches must be ({K}, th, tw, C), got shape {p.shape}")
        if not np.isfinite(p).all():
            raise ValueError("appearance patches contain NaN or inf")
        sig = np.asarray(a.sigma, dtype=np.float64)
        d = np.asarray(a.d, dtype=np.float64)
        if sig.shape != (K,) or d.shape != (K,) or not (np.isfinite(sig).all() and np.isfinite(d).all()):
            raise ValueError(f"appearance sigma and d must be ({K},) and finite")
        if (sig <= 0).any() or (d <= 0).any():
            raise ValueError("appearance sigma and d must be positive")
        object.__setattr__(self, "appearance", AppearanceKernels(patches=p.astype(np.float32), sigma=sig, d=d))

    # ----------------------------------------------------------------------------------

    @property
    def K(self) -> int:
        """Number of exemplars."""
        return int(self.d.shape[0])

    @property
    def kind(self) -> str:
        """"curve" or "patch"."""
        return METRICS[self.metric].kind

    def make_metric(self) -> Metric:
        """The distance function the model was learned with."""
        if self.metric == "chamfer":
            return make_metric("chamfer", profile=self.profile, g0=self.g0, upsample=self.upsample)
        if self.metric == "shuffle":
            return make_metric("shuffle", radius=self.shuffle_radius)
        return make_metric(self.metric)

    def to_contour_exemplars(self) -> ContourExemplars:
        """The tracker's :class:`~gflow_core.m2.tracking.ContourExemplars` (curve metrics only)."""
        if self.kind != "curve":
            raise ValueError(f"a {self.metric!r} model has patch exemplars, not contours; use to_patch_exemplars()")
        ex = self.exemplars
        assert isinstance(ex, Curves)
        return ContourExemplars(curves=ex.points, n_points=ex.n_points, sigma=self.sigma, d=self.d, pi=self.pi,
                                markov=self.markov, dynamics=self.dynamics)

    def to_patch_exemplars(self) -> PatchExemplars:
        """:class:`~gflow_core.m2.patch_tracking.PatchExemplars` (patch metrics only)."""
        if self.kind != "patch":
            raise ValueError(f"a {self.metric!r} model has contour exemplars; use to_contour_exemplars()")
        assert isinstance(self.exemplars, np.ndarray)
        return PatchExemplars(patches=self.exemplars, sigma=self.sigma, d=self.d, pi=self.pi, markov=self.markov,
                              metric=self.make_metric())

    def alpha_from_box(self, box: tuple[float, float, float, float]) -> np.ndarray:
        """Transform placing the reference box on an image box (x, y, w, h): (cx, cy, 0, s), (4,) float64."""
        x, y, w, h = (float(v) for v in box)
        if not (w > 0 and h > 0):
            raise ValueError(f"box must have positive size, got {box}")
        s = np.sqrt(w * h / (self.ref_size[0] * self.ref_size[1]))
        return np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0, 0.0, s])

    def match_scale(self, box: tuple[float, float, float, float]) -> float:
        """The factor that resamples a frame so a target whose first box is ``box`` appears at the
        model's reference size: 1 / s_0 (s_0 of :meth:`alpha_from_box`) where s_0 exceeds
        ``train_scale`` (a target larger than every training target), else 1 (within the training
        sizes, and for files of format 2 and older, which do not say)."""
        s0 = float(self.alpha_from_box(box)[3])
        return 1.0 / s0 if s0 > self.train_scale else 1.0

    # ----------------------------------------------------------------------------------

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat dict of arrays (see the module docstring for keys); no object arrays."""
        out: dict[str, np.ndarray] = {
            "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
            "metric": np.array(self.metric),
            "kernel": np.array(self.kernel),
            "profile": np.array(self.profile),
            "g0": np.array(self.g0, dtype=np.float64),
            "upsample": np.array(self.upsample, dtype=np.int64),
            "shuffle_radius": np.array(self.shuffle_radius, dtype=np.int64),
            "exemplar_frame": np.array(self.exemplar_frame, dtype=np.int64),  # set by __post_init__
            "d": self.d.copy(),
            "sigma": self.sigma.copy(),
            "pi": self.pi.copy(),
            "markov": self.markov.copy(),
            "ar_A": self.dynamics.A.copy(),
            "ar_mean": self.dynamics.mean.copy(),
            "ar_B": self.dynamics.B.copy(),
            "ref_size": self.ref_size.copy(),
            "train_scale": np.array(self.train_scale, dtype=np.float64),
        }
        if isinstance(self.exemplars, Curves):
            out["exemplar_curves"] = self.exemplars.points.copy()
            out["exemplar_n_points"] = self.exemplars.n_points.copy()
            if self.appearance is not None:
                out["app_patches"] = self.appearance.patches.copy()
                out["app_sigma"] = self.appearance.sigma.copy()
                out["app_d"] = self.appearance.d.copy()
        else:
            out["exemplar_patches"] = np.array(self.exemplars, dtype=np.float64)
        return out

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> "M2Model":
        """Rebuild a model from :meth:`to_arrays` output (e.g. an ``np.load``-ed npz).

        Raises
        ------
        ValueError
            Wrong or missing format version, missing or unexpected keys, wrong dtypes or
            shapes, or invalid values (NaN, negative sigma, rows not summing to 1, ...).
        """
        keys = set(arrays.keys())
        if "format_version" not in keys:
            raise ValueError("not an M2 model: no 'format_version' array")
        try:
            v = np.asarray(arrays["format_version"])
            if v.shape != () or v.dtype.kind not in "iu":
                raise TypeError
            version = int(v)
        except (TypeError, ValueError):
            raise ValueError("M2 model 'format_version' must be a scalar integer") from None
        if version not in READS_VERSIONS:
            raise ValueError(f"M2 model format version {version} is not supported (this code reads versions "
                             f"{', '.join(map(str, READS_VERSIONS))}); re-learn the model")

        def get(name: str, kind: str | None = None, shape: tuple | None = None) -> np.ndarray:
            if name not in keys:
                raise ValueError(f"M2 model is missing the array {name!r}")
            a = np.asarray(arrays[name])
            if a.dtype == object:
                raise ValueError(f"M2 model array {name!r} has dtype object (pickled data is not accepted)")
            if kind is not None and a.dtype.kind not in kind:
                raise ValueError(f"M2 model array {name!r} has dtype {a.dtype}, expected kind {kind!r}")
            if shape is not None and a.shape != shape:
                raise ValueError(f"M2 model array {name!r} has shape {a.shape}, expected {shape}")
            return a

        metric = str(get("metric", "U", ()))
        if metric not in METRICS:
            raise ValueError(f"M2 model has unknown metric {metric!r}")
        kind = METRICS[metric].kind
        expected = set(_SCALARS) | set(_COMMON) | set(_CURVE if kind == "curve" else _PATCH) \
            | ({"train_scale"} if version >= 3 else set())
        missing = sorted(expected - keys)
        if missing:
            raise ValueError(f"M2 model is missing the array(s) {missing}")
        has_app = version >= 2 and kind == "curve" and bool(keys & set(_APPEARANCE))
        if has_app:
            missing = sorted(set(_APPEARANCE) - keys)
            if missing:
                raise ValueError(f"M2 model has appearance exemplars but is missing the array(s) {missing}")
            expected |= set(_APPEARANCE)
        extra = sorted(keys - expected)
        if extra:
            raise ValueError(f"M2 model has unexpected array(s) {extra} for metric {metric!r}")
        scal = {n: get(n, "iu" if t == "i" else ("fiu" if t == "f" else t), ()) for n, t in _SCALARS.items()}
        d = get("d", "fiu")
        if d.ndim != 1 or d.size < 1:
            raise ValueError(f"M2 model array 'd' must be (K,) with K >= 1, got shape {d.shape}")
        K = d.shape[0]
        if kind == "curve":
            pts = get("exemplar_curves", "f")
            if pts.ndim != 3 or pts.shape[0] != K or pts.shape[2] != 2:
                raise ValueError(f"M2 model array 'exemplar_curves' must be ({K}, P, 2), got {pts.shape}")
            n_pts = get("exemplar_n_points", "iu", (K,))
            exemplars: Curves | np.ndarray = Curves(pts, n_pts)
        else:
            exemplars = get("exemplar_patches", "f")
            if exemplars.ndim != 3 or exemplars.shape[0] != K:
                raise ValueError(f"M2 model array 'exemplar_patches' must be ({K}, h, w), got {exemplars.shape}")
        appearance = None
        if has_app:
            appearance = AppearanceKernels(patches=get("app_patches", "f"), sigma=get("app_sigma", "fiu", (K,)),
                                           d=get("app_d", "fiu", (K,)))
        try:
            dyn = _stable(ARDynamics(A=get("ar_A", "f", (4, 4)), mean=get("ar_mean", "f", (4,)),
                                     B=get("ar_B", "f", (4, 4))))
        except ValueError as e:
            raise ValueError(f"M2 model dynamics: {e}") from None
        return cls(metric=metric, kernel=str(scal["kernel"]), exemplars=exemplars, d=d,
                   sigma=get("sigma", "fiu", (K,)), pi=get("pi", "fiu", (K,)), markov=get("markov", "f", (K, K)),
                   dynamics=dyn, ref_size=get("ref_size", "fiu", (2,)),
                   exemplar_frame=get("exemplar_frame", "iu", (K,)), profile=str(scal["profile"]),
                   g0=float(scal["g0"]), upsample=int(scal["upsample"]), shuffle_radius=int(scal["shuffle_radius"]),
                   appearance=appearance,
                   train_scale=float(get("train_scale", "fiu", ())) if version >= 3 else float("inf"))
