"""Learning a complete M2 model from training items (Toyama & Blake 2002, sec. 4).

:func:`learn` runs, in order:

1. exemplars (sec. 4.1, :mod:`.exemplars`): minimax datum, alignment by direct descent,
   evenly spaced initial centres, k-medoids (eq. 8-9), pi_k proportional to N_k;
2. validation distances (sec. 4.2): the validation set is the training set less the
   exemplars; for each z_v the best exemplar and transform
   min_{alpha, k} rho(T_alpha x~_k, z_v) by direct descent (:func:`.align.refine_alpha`)
   give rho_v;
3. kernel parameters d_k, sigma_k by moments (eq. 10) or MLE (eq. 11), :mod:`.kernel`;
4. dynamics (sec. 4.3, :mod:`.learn_dynamics`) from the training states
   X_t = (alpha_t, k_t): alpha_t is the item's image placement composed with its
   best-exemplar transform, k_t its best exemplar; Markov matrix by histogramming and
   AR(1) on beta by Yule-Walker.

Departures from the paper
-------------------------
* Sec. 4.2's search over *all* exemplars and alpha is restricted to the
  ``n_candidates`` exemplars nearest in the aligned distance matrix (which is already
  computed), each refined over alpha from the item's alignment alpha_t*. With patch
  metrics there is no alpha (sec. 5.2) and the nearest exemplar is exact.
* The cluster of a validation item for eq. 10-11 is its best exemplar from this search
  (the exemplar whose kernel rho_v measures), which is normally its k-medoids cluster.
* Sec. 4.2 takes the validation set "z_v" unaligned; the descent starts from the
  item's alignment alpha_t*, and with ``symmetric=True`` alpha is chosen by the
  symmetrised distance while rho_v is the directed rho(T_alpha x~_k, z_v) of eq. 7.
* The dynamics are learned on the states of *all* training items (exemplars included,
  each with its own alignment), in frame order, within runs of consecutive frames.
* With ``frames`` (contour models), an appearance metric is learned beside chamfer
  (:mod:`.appearance_metric`): a_k is exemplar k's region at its training state, and
  d'_k, sigma'_k are fitted to rho_a of the validation items to their best exemplar (the
  one the chamfer search chose), by the same estimator as the chamfer kernels.
* Summary of the other departures, detailed in each module: symmetrised alignment and
  clustering (:mod:`.align`, :mod:`.exemplars`), a maximin k-medoids start kept when
  better (:mod:`.exemplars`), pooled kernels for clusters with fewer than 10 validation
  items and eq. 11 applied exactly instead of note 4.2.1(1)'s 4/e rule (:mod:`.kernel`),
  a Dirichlet prior on the Markov counts and a random walk on translation
  (:mod:`.learn_dynamics`), means instead of sums in rho (:mod:`.distances`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal, Sequence

import numpy as np

from .. import similarity
from .appearance_metric import DEFAULT_MAX_AREA, learn_appearance
from .align import DEFAULT_BOUNDS, DEFAULT_STEP, refine_alpha
from .curves import Curves
from .distances import Items, Metric, make_metric
from .exemplars import ExemplarFit, check_k, learn_exemplars
from .kernel import CURVE_KERNEL_FLOOR, KERNEL_METHODS, KernelFit, fit_kernels
from .learn_dynamics import DEFAULT_NOISE_FLOOR, learn_ar, learn_markov, split_runs
from .model import M2Model
from .training import TrainingSet

__all__ = ["learn", "learn_detailed", "Validation", "LearnResult", "validation_distances"]

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class Validation:
    """Sec. 4.2 output for every training item.

    Attributes
    ----------
    is_validation : (T,) bool, False for the exemplars themselves.
    k : (T,) int64, best exemplar of each item (an exemplar's own index for exemplars).
    alpha : (T, 4) float64, z_t ~ T_alpha x~_k (item frame).
    rho : (T,) float64, rho(T_alpha x~_k, z_t) (0 for exemplars).
    """

    is_validation: np.ndarray
    k: np.ndarray
    alpha: np.ndarray
    rho: np.ndarray


@dataclass(frozen=True)
class LearnResult:
    """Everything :func:`learn_detailed` computed (for diagnostics and benchmarks)."""

    model: M2Model
    exemplar_fit: ExemplarFit
    validation: Validation
    kernel: KernelFit
    states_alpha: np.ndarray  # (T, 4) image alpha_t
    states_k: np.ndarray  # (T,) k_t


def validation_distances(metric: Metric, items: Items, fit: ExemplarFit, n_candidates: int = 3,
                         aligned: bool = True, symmetric: bool = True, step: np.ndarray = DEFAULT_STEP,
                         bounds: np.ndarray = DEFAULT_BOUNDS, progress: Progress | None = None) -> Validation:
    """rho_v = min_{alpha, k} rho(T_alpha x~_k, z_v) for the training set less the exemplars (sec. 4.2).

    Parameters
    ----------
    metric : Metric
    items : T (unaligned) training items z_t.
    fit : ExemplarFit from :func:`.exemplars.learn_exemplars`.
    n_candidates : int, exemplars refined over alpha per item (nearest first).
    aligned : bool, refine alpha (curves); False uses the aligned distance matrix only (patches).
    symmetric : bool, choose alpha by the symmetrised distance (:mod:`.align`); rho_v is the
        directed rho(T_alpha x~_k, z_v) either way.
    """
    T = metric.n_items(items)
    med = fit.clusters.medoids
    K = med.size
    is_val = np.ones(T, dtype=bool)
    is_val[med] = False
    k_out = fit.clusters.labels.copy()
    alpha_out = fit.alpha_star.copy()
    rho_out = np.zeros(T)
    # rho(x~_k, x_t*) for every exemplar and item, (K, T): nearest candidates first
    Dk = fit.D_cluster[med]
    val = np.nonzero(is_val)[0]
    images: dict = {}
    if progress:
        progress("validation", 0, val.size)
    for i, v in enumerate(val):
        if not aligned:
            # min_k rho(x~_k, z_v), directed (no alpha)
            kb = int(np.argmin(fit.D[med, v]))
            k_out[v], rho_out[v] = kb, fit.D[med[kb], v]
            continue
        order = np.argsort(Dk[:, v], kind="stable")
        cand = order[: max(1, min(n_candidates, K))]
        # alpha_v = argmin_alpha rho(T_alpha x~_k, z_v), starting from alpha_v* (z_v ~ T_alpha* x_v*)
        a, r = refine_alpha(metric, fit.exemplars, cand, items, int(v), fit.alpha_star[v], symmetric=symmetric,
                            step=step, bounds=bounds, exemplar_images=images)
        b = int(np.argmin(r))
        k_out[v], alpha_out[v], rho_out[v] = cand[b], a[b], r[b]
        if progress and (i + 1) % 16 == 0:
            progress("validation", i + 1, val.size)
    if progress:
        progress("validation", val.size, val.size)
    return Validation(is_validation=is_val, k=k_out, alpha=alpha_out, rho=rho_out)


def _as_training(items: Any, metric: Metric) -> TrainingSet:
    if isinstance(items, TrainingSet):
        if items.kind != metric.kind:
            raise ValueError(f"metric {metric.name!r} works on {metric.kind} items but the training set holds "
                             f"{items.kind} items")
        return items
    if metric.kind == "curve":
        if isinstance(items, np.ndarray) and items.ndim == 3 and items.shape[-1] != 2:
            raise ValueError(f"metric {metric.name!r} works on curves; got an array of shape {items.shape}")
        its = metric.check_items(items)
        lo, hi = its.bounds()
        ref = np.maximum(hi - lo + 1.0, 1.0)
    else:
        if isinstance(items, Curves):
            raise ValueError(f"metric {metric.name!r} works on patches, got curves")
        its = metric.check_items(items)
        ref = np.array([its.shape[2], its.shape[1]], dtype=np.float64)
    n = metric.n_items(its)
    return TrainingSet(items=its, placement=np.tile(similarity.IDENTITY, (n, 1)), frame_index=np.arange(n),
                       sequence=np.zeros(n, dtype=np.int64), ref_size=ref, kind=metric.kind)


def learn_detailed(items: TrainingSet | Curves | np.ndarray | list, metric: str | Metric = "chamfer", K: int = 10,
                   kernel: Literal["moments", "mle"] = "moments", *, metric_params: dict | None = None,
                   align: bool | None = None, symmetric: bool = True, init: Literal["best", "spaced"] = "best",
                   n_candidates: int = 3, max_iter: int = 50, min_samples: int = 10,
                   d_range: tuple[float, float] = (0.5, 1000.0), trivial_ratio: float | None = None,
                   markov_prior: float = 1.0, translation: Literal["random_walk", "ar"] = "random_walk",
                   noise_floor: np.ndarray = DEFAULT_NOISE_FLOOR, step: np.ndarray = DEFAULT_STEP,
                   bounds: np.ndarray = DEFAULT_BOUNDS, kernel_floor: float | None = None,
                   frames: Sequence[np.ndarray] | None = None,
                   appearance_area: int = DEFAULT_MAX_AREA, progress: Progress | None = None) -> LearnResult:
    """:func:`learn`, returning the intermediate results too (see :class:`LearnResult`)."""
    if kernel not in KERNEL_METHODS:
        raise ValueError(f"unknown kernel estimator {kernel!r}; choose one of {KERNEL_METHODS}")
    m = make_metric(metric, **(metric_params or {}))
    # the kernels' pixel floor: a contour model's by default, none for patches (their distances are not px^2)
    floor = (CURVE_KERNEL_FLOOR if m.kind == "curve" else 0.0) if kernel_floor is None else kernel_floor
    ts = _as_training(items, m)
    z = m.check_items(ts.items)
    T = m.n_items(z)
    check_k(T, K)
    if K == T:
        raise ValueError(f"K={K} equals the number of training items: no validation items are left to learn the "
                         "kernel widths (sec. 4.2); use fewer exemplars or more frames")
    aligned = m.kind == "curve" if align is None else bool(align)
    fit = learn_exemplars(m, z, K, align=aligned, max_iter=max_iter, symmetric=symmetric, init=init, step=step,
                          bounds=bounds, progress=progress)
    val = validation_distances(m, z, fit, n_candidates=n_candidates, aligned=aligned, symmetric=symmetric, step=step,
                               bounds=bounds, progress=progress)
    if progress:
        progress("kernel", 0, 1)
    kf = fit_kernels(val.rho[val.is_validation], val.k[val.is_validation], K, method=kernel,
                     min_samples=min_samples, d_range=d_range, trivial_ratio=trivial_ratio, min_rho=floor)
    if progress:
        progress("kernel", 1, 1)
        progress("dynamics", 0, 1)
    # X_t = (alpha_t, k_t): image point = T_placement T_alpha (exemplar point)
    states_alpha = np.array([similarity.compose(p, a) for p, a in zip(ts.placement, val.alpha)])
    runs = split_runs(ts.frame_index, ts.sequence)
    markov = learn_markov([val.k[r] for r in runs], K, prior=markov_prior)
    if sum(max(r.size - 1, 0) for r in runs) >= 2:
        dyn = learn_ar([states_alpha[r] for r in runs], translation=translation, noise_floor=noise_floor)
    else:
        raise ValueError("need at least 2 consecutive-frame transitions in the training items to learn dynamics "
                         "(sec. 4.3); are the frames a sequence?")
    if progress:
        progress("dynamics", 1, 1)
    appearance = None
    if frames is not None:
        if m.kind != "curve":
            raise ValueError("appearance exemplars (frames=...) go with contour metrics only")
        if len(frames) != T:
            raise ValueError(f"frames: need the grey frame of each of the {T} training items, got {len(frames)}")
        if progress:
            progress("appearance", 0, 1)
        appearance = learn_appearance(frames, states_alpha, fit.clusters.medoids, val.is_validation, val.k,
                                      ts.ref_size, method=kernel, max_area=appearance_area,
                                      min_samples=min_samples, d_range=d_range)
        if progress:
            progress("appearance", 1, 1)
    mp = m.params()
    model = M2Model(metric=m.name, kernel=kernel, exemplars=fit.exemplars, d=kf.d, sigma=kf.sigma, pi=fit.pi,
                    markov=markov, dynamics=dyn, ref_size=ts.ref_size,
                    exemplar_frame=ts.frame_index[fit.clusters.medoids],
                    profile=str(mp.get("profile", "quadratic")), g0=float(mp.get("g0", 100.0)),
                    upsample=int(mp.get("upsample", 2)), shuffle_radius=int(mp.get("radius", 1)),
                    appearance=appearance, train_scale=float(np.max(ts.placement[:, 3])))
    return LearnResult(model=model, exemplar_fit=fit, validation=val, kernel=kf, states_alpha=states_alpha,
                       states_k=val.k)


def learn(items: TrainingSet | Curves | np.ndarray | list, metric: str | Metric = "chamfer", K: int = 10,
          kernel: Literal["moments", "mle"] = "moments", *, progress: Progress | None = None,
          **options: Any) -> M2Model:
    """Learn an M2 model (exemplars, kernels, dynamics) from training items (sec. 4).

    Parameters
    ----------
    items : TrainingSet (from :mod:`.training`, carries image placements and frame indices),
        or bare items in time order: Curves / a list of (P_i, 2) point sets for the chamfer
        metric, (T, h, w) patches for "shuffle" / "l2" (placements then default to identity).
    metric : "chamfer", "shuffle", "l2" or a :class:`.distances.Metric` instance.
    K : int, number of exemplars, 1 <= K < T.
    kernel : "moments" (eq. 10, default) or "mle" (eq. 11).
    progress : callable(stage, done, total), optional; stages in order are "datum", "align",
        "distances" (curves), "kmedoids", "validation", "kernel", "dynamics".
    **options
        metric_params (dict, e.g. ``{"profile": "truncated", "g0": 50}``), align (bool),
        symmetric (True: align and cluster by the symmetrised distance), init ("best" | "spaced"),
        n_candidates (3), max_iter (50), min_samples (10), d_range ((0.5, 1000)),
        trivial_ratio (None), markov_prior (1.0), translation ("random_walk" | "ar"),
        noise_floor ((4,)), step, bounds (alignment search, beta units); kernel_floor (None: 0.5 px^2 for
        contour models, :data:`.kernel.CURVE_KERNEL_FLOOR`, and 0 for patch models; a cluster whose mean
        validation distance is at most this gets the pooled kernel, :func:`.kernel.fit_kernels`'s ``min_rho``);
        frames (the grey frame of every training item: also learn appearance exemplars and
        kernels, :mod:`.appearance_metric`), appearance_area (grid points per appearance exemplar);
        see :func:`learn_detailed` and the modules it calls.

    Returns
    -------
    M2Model

    Raises
    ------
    ValueError
        No training items, a single item, K > T or K == T (no validation set), a metric
        that does not match the items, or no consecutive frames to learn dynamics from.
    """
    return learn_detailed(items, metric, K, kernel, progress=progress, **options).model
