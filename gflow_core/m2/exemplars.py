"""Learning the mixture centres x~_k: minimax datum, alignment, k-medoids (Toyama & Blake 2002, sec. 4.1).

1. Datum by the minimax rule  z_0* = argmin_z max_{z' != z} rho(z, z').
2. Alignment  alpha_t* = argmin_alpha rho(T_alpha^-1 z_t*, z_0*),  x_t* = T_alpha_t*^-1 z_t*
   (direct descent, :mod:`.align`).
3. Initial centres: a subsequence of the x_t*, evenly spaced in distance,
   rho(x~_{k+1}, x~_k) ~ rho_c, with rho_c found by bisection to give K centres.
4. k-medoids: assignment k_t = argmin_k rho(x~_k, x_t*)                          (8)
   and minimax representative  x~_k = argmin_{x in C_k} max_{x' in C_k - {x}} rho(x, x')   (9),
   repeated until the centres stop changing.
5. pi_k proportional to N_k.

Everything but the alignment works on a precomputed distance matrix D[i, j] = rho(x_i, x_j)
(first argument = row), so it applies to any :class:`.distances.Metric`.

Departures from the paper
-------------------------
* Step 3 walks the training items in the order given (time order): a new centre starts
  at the first item whose distance from the previous centre reaches rho_c. rho_c is
  bisected so that the walk gives as close to K centres as possible; the result is then
  made *exactly* K by merging the closest consecutive centres (too many) or adding the
  item farthest from every centre (too few).
* ``init="best"`` (the default) also runs k-medoids from a farthest-point (maximin)
  initialisation started at the datum and keeps whichever result has the lower total
  distance sum_t rho(x~_{k_t}, x_t). A spaced walk along a sequence that revisits
  poses can miss a pose entirely (e.g. poses A B C B A C with K = 3 gives centres in
  A and C only), and minimax k-medoids cannot move a centre across to it.
  ``init="spaced"`` is the paper's initialisation alone.
* Every centre is forced into its own cluster during assignment (ties in eq. 8, e.g.
  duplicate frames, could otherwise leave a cluster empty).
* With ``symmetric=True`` (the default) the datum, the initial spacing, the assignment
  (eq. 8) and the minimax representative (eq. 9) use the symmetrised distance
  (rho(a, b) + rho(b, a)) / 2 instead of the directed chamfer distance. With the directed
  distance the minimax rule prefers items whose few points lie on everybody else's
  edges: on caviar1 the datum was a frame in which an occluder left only the left edge
  of the pedestrian, and everything was then aligned to that fragment. The kernel
  statistics (sec. 4.2) still use the directed distance of eq. 7. ``symmetric=False``
  follows the paper literally.
* The alignment of :mod:`.align`: symmetrised objective and a box constraint.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from ..similarity import invert
from .align import DEFAULT_BOUNDS, DEFAULT_STEP, align_to_reference
from .distances import Items, Metric

__all__ = ["minimax_index", "spaced_walk", "evenly_spaced_centres", "maximin_centres", "kmedoids", "kmedoids_cost",
           "KMedoids", "ExemplarFit", "learn_exemplars", "pairwise_with_progress", "check_k"]

Progress = Callable[[str, int, int], None]


def check_k(n_items: int, K: int) -> None:
    """Raise ValueError unless 2 <= n_items and 1 <= K <= n_items."""
    if n_items == 0:
        raise ValueError("no training items: M2 needs a training sequence with a visible foreground")
    if n_items == 1:
        raise ValueError("a single training item: M2 needs at least 2 (and more than K) to learn exemplars "
                         "and their kernel widths")
    if int(K) != K or K < 1:
        raise ValueError(f"number of exemplars K must be a positive integer, got {K}")
    if K > n_items:
        raise ValueError(f"K={K} exemplars requested but only {n_items} training items")


def _check_square(D: np.ndarray) -> np.ndarray:
    D = np.asarray(D, dtype=np.float64)
    if D.ndim != 2 or D.shape[0] != D.shape[1] or D.shape[0] == 0:
        raise ValueError(f"distance matrix must be square and non-empty, got shape {D.shape}")
    if np.isnan(D).any():
        raise ValueError("distance matrix contains NaN")
    return D


def minimax_index(D: np.ndarray, members: np.ndarray | None = None) -> int:
    """Minimax representative  argmin_{x in C} max_{x' in C - {x}} rho(x, x')  (sec. 4.1, eq. 9).

    Parameters
    ----------
    D : (T, T) float64, D[i, j] = rho(x_i, x_j).
    members : (n,) int64, the set C (default: everything).

    Returns
    -------
    int, index into D (not into ``members``). A singleton's representative is itself.
    """
    D = _check_square(D)
    m = np.arange(D.shape[0]) if members is None else np.asarray(members, dtype=np.int64)
    if m.size == 0:
        raise ValueError("minimax of an empty set")
    if m.size == 1:
        return int(m[0])
    sub = D[np.ix_(m, m)].copy()
    np.fill_diagonal(sub, -np.inf)  # x' ranges over C - {x}
    # x~ = argmin_x max_{x' != x} rho(x, x')                                          (9)
    return int(m[np.argmin(sub.max(axis=1))])


def spaced_walk(D: np.ndarray, rho_c: float) -> list[int]:
    """Indices of a subsequence with rho(x_next, x_prev_centre) >= rho_c, walking in order (step 2)."""
    centres = [0]
    for t in range(1, D.shape[0]):
        # rho(x~_{k+1}, x~_k) >= rho_c
        if D[t, centres[-1]] >= rho_c:
            centres.append(t)
    return centres


def evenly_spaced_centres(D: np.ndarray, K: int, n_bisect: int = 60) -> tuple[np.ndarray, float]:
    """K initial centres evenly spaced in distance along the sequence (sec. 4.1 step 2).

    Parameters
    ----------
    D : (T, T) float64, distances between aligned items in time order.
    K : int, 1 <= K <= T.

    Returns
    -------
    centres : (K,) int64, distinct indices, ascending.
    rho_c : float, the spacing found by bisection.
    """
    D = _check_square(D)
    T = D.shape[0]
    if not 1 <= K <= T:
        raise ValueError(f"need 1 <= K <= {T}, got K={K}")
    lo, hi = 0.0, float(D.max()) * (1.0 + 1e-9) + 1e-300
    best = spaced_walk(D, lo)  # every item: T >= K centres
    best_rc = lo
    for _ in range(n_bisect):
        mid = 0.5 * (lo + hi)
        c = spaced_walk(D, mid)
        if len(c) >= K:
            lo, best, best_rc = mid, c, mid  # the largest rho_c still giving >= K centres
            if len(c) == K:
                break
        else:
            hi = mid
    centres = list(best)
    # too many: merge the closest consecutive pair (drop the later centre)
    while len(centres) > K:
        gaps = [D[centres[i], centres[i - 1]] for i in range(1, len(centres))]
        del centres[1 + int(np.argmin(gaps))]
    # too few (only when bisection cannot split a tie): add the item farthest from every centre
    while len(centres) < K:
        near = D[centres].min(axis=0)
        near[centres] = -np.inf
        centres.append(int(np.argmax(near)))
    return np.sort(np.array(centres, dtype=np.int64)), best_rc


def maximin_centres(D: np.ndarray, K: int, first: int = 0) -> np.ndarray:
    """Farthest-point initialisation: start at ``first``, then repeatedly add the item whose
    distance from its nearest centre, rho(x~_k, x_t), is largest. Returns (K,) int64 distinct indices."""
    D = _check_square(D)
    if not 1 <= K <= D.shape[0]:
        raise ValueError(f"need 1 <= K <= {D.shape[0]}, got K={K}")
    centres = [int(first)]
    near = D[first].copy()
    near[first] = -np.inf
    for _ in range(K - 1):
        c = int(np.argmax(near))
        centres.append(c)
        near = np.minimum(near, D[c])
        near[centres] = -np.inf
    return np.array(centres, dtype=np.int64)


def kmedoids_cost(D: np.ndarray, res: "KMedoids") -> float:
    """Total distance sum_t rho(x~_{k_t}, x_t) of a clustering."""
    return float(D[res.medoids[res.labels], np.arange(D.shape[0])].sum())


@dataclass(frozen=True)
class KMedoids:
    """Result of :func:`kmedoids`.

    Attributes
    ----------
    medoids : (K,) int64, indices of the exemplars x~_k.
    labels : (T,) int64, cluster of each item (eq. 8).
    sizes : (K,) int64, N_k.
    n_iter : int, iterations run.
    converged : bool, True if the medoids stopped changing.
    """

    medoids: np.ndarray
    labels: np.ndarray
    sizes: np.ndarray
    n_iter: int
    converged: bool


def _assign(D: np.ndarray, medoids: np.ndarray) -> np.ndarray:
    # k_t = argmin_k rho(x~_k, x_t)                                                    (8)
    labels = np.argmin(D[medoids], axis=0).astype(np.int64)
    labels[medoids] = np.arange(medoids.size)  # a centre belongs to its own cluster
    return labels


def kmedoids(D: np.ndarray, init: np.ndarray, max_iter: int = 50) -> KMedoids:
    """k-medoids with the minimax representative (sec. 4.1 steps 3-5, eq. 8-9).

    Parameters
    ----------
    D : (T, T) float64, D[i, j] = rho(x_i, x_j).
    init : (K,) int64, distinct initial centres.
    max_iter : int

    Returns
    -------
    KMedoids
    """
    D = _check_square(D)
    med = np.asarray(init, dtype=np.int64).copy()
    if med.ndim != 1 or med.size == 0 or np.unique(med).size != med.size:
        raise ValueError("initial centres must be a non-empty list of distinct indices")
    if med.min() < 0 or med.max() >= D.shape[0]:
        raise ValueError(f"initial centres must index the {D.shape[0]} items")
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        labels = _assign(D, med)
        new = np.array([minimax_index(D, np.nonzero(labels == k)[0]) for k in range(med.size)], dtype=np.int64)
        if np.array_equal(new, med):
            converged = True
            break
        med = new
    labels = _assign(D, med)
    sizes = np.bincount(labels, minlength=med.size).astype(np.int64)
    return KMedoids(medoids=med, labels=labels, sizes=sizes, n_iter=it, converged=converged)


def pairwise_with_progress(metric: Metric, a: Items, b: Items, stage: str, progress: Progress | None,
                           block: int = 32) -> np.ndarray:
    """``metric.pairwise(a, b)`` computed in column blocks, calling ``progress(stage, done, total)``."""
    nb = metric.n_items(b)
    if progress is None:
        return metric.pairwise(a, b)
    out = np.empty((metric.n_items(a), nb))
    progress(stage, 0, nb)
    for j0 in range(0, nb, block):
        j = np.arange(j0, min(nb, j0 + block))
        out[:, j] = metric.pairwise(a, metric.subset(b, j))
        progress(stage, int(j[-1]) + 1, nb)
    return out


@dataclass(frozen=True)
class ExemplarFit:
    """Everything sec. 4.1 produces.

    Attributes
    ----------
    aligned : T aligned items x_t* (same type as the input).
    alpha_star : (T, 4) float64, z_t ~ T_alpha_t* x_t*.
    datum : int, index of z_0*.
    D : (T, T) float64, rho between aligned items, D[i, j] = rho(x_i*, x_j*) (directed).
    D_cluster : (T, T) float64, the matrix clustering used: D, or (D + D^T) / 2 if symmetric.
    init : (K,) int64, initial centres of the clustering kept (step 2 or maximin).
    rho_c : float, their spacing.
    clusters : KMedoids
    exemplars : K items x~_k = aligned[clusters.medoids].
    pi : (K,) float64, pi_k = N_k / T.
    """

    aligned: Items
    alpha_star: np.ndarray
    datum: int
    D: np.ndarray
    D_cluster: np.ndarray
    init: np.ndarray
    rho_c: float
    clusters: KMedoids
    exemplars: Items
    pi: np.ndarray


def learn_exemplars(metric: Metric, items: Items, K: int, align: bool | None = None, max_iter: int = 50,
                    symmetric: bool = True, init: Literal["best", "spaced"] = "best",
                    step: np.ndarray = DEFAULT_STEP, bounds: np.ndarray = DEFAULT_BOUNDS,
                    progress: Progress | None = None) -> ExemplarFit:
    """Sec. 4.1 end to end: datum, alignment, evenly spaced initial centres, k-medoids, pi_k.

    Parameters
    ----------
    metric : Metric
    items : T training items z_t* in time order, roughly aligned (centred on their
        reference point), e.g. from :mod:`.training`.
    K : int, number of exemplars, 1 <= K <= T.
    align : bool, run step 1's alignment (default: True for curves, False for patches,
        which sec. 5.2 uses without transforms).
    max_iter : int, k-medoids iterations.
    symmetric : bool, use the symmetrised distance for the datum, alignment (:mod:`.align`)
        and clustering (module notes).
    init : {"best", "spaced"}, k-medoids initialisation (module notes).
    step, bounds : (4,) float64, alignment search parameters (:mod:`.align`).
    progress : callable(stage, done, total), optional.

    Raises
    ------
    ValueError
        No items, a single item, K larger than the number of items, or an unknown ``init``.
    """
    if init not in ("best", "spaced"):
        raise ValueError(f"unknown k-medoids initialisation {init!r}; choose 'best' or 'spaced'")
    items = metric.check_items(items)
    T = metric.n_items(items)
    check_k(T, K)
    align = metric.kind == "curve" if align is None else bool(align)
    alpha = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (T, 1))
    if align:
        D0 = pairwise_with_progress(metric, items, items, "datum", progress)
        if symmetric:
            D0 = 0.5 * (D0 + D0.T)
        # z_0* = argmin_z max_{z' != z} rho(z, z')
        datum = minimax_index(D0)
        if progress:
            progress("align", 0, T)
        alpha, _ = align_to_reference(metric, items, items, datum, symmetric=symmetric, step=step, bounds=bounds)
        if progress:
            progress("align", T, T)
        # x_t* = T_alpha_t*^-1 z_t*
        aligned = metric.transform(items, invert(alpha))
        D = pairwise_with_progress(metric, aligned, aligned, "distances", progress)
    else:
        aligned = items
        D = pairwise_with_progress(metric, aligned, aligned, "distances", progress)
    Dc = 0.5 * (D + D.T) if symmetric else D
    if not align:
        datum = minimax_index(Dc)
    init_c, rho_c = evenly_spaced_centres(Dc, K)
    if progress:
        progress("kmedoids", 0, 1)
    clusters = kmedoids(Dc, init_c, max_iter=max_iter)
    if init == "best":
        alt_init = maximin_centres(Dc, K, first=datum)
        alt = kmedoids(Dc, alt_init, max_iter=max_iter)
        if kmedoids_cost(Dc, alt) < kmedoids_cost(Dc, clusters):
            clusters, init_c = alt, alt_init
    if progress:
        progress("kmedoids", 1, 1)
    # pi_k proportional to N_k
    pi = clusters.sizes / clusters.sizes.sum()
    return ExemplarFit(aligned=aligned, alpha_star=alpha, datum=datum, D=D, D_cluster=Dc, init=init_c, rho_c=rho_c,
                       clusters=clusters, exemplars=metric.subset(aligned, clusters.medoids), pi=pi)
