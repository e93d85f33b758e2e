"""Direct descent over the similarity transform alpha (Toyama & Blake 2002, sec. 4.1-4.2).

The paper aligns every training item to a datum, and every validation item to its best
exemplar, by "direct descent" on

    alpha_t* = argmin_alpha rho(T_alpha^-1 z_t*, z_0*)                      (sec. 4.1, step 1)
    alpha_v  = argmin_alpha rho(T_alpha x~, z_v)                            (sec. 4.2)

Here direct descent is a *compass (pattern) search* in beta = (ux, uy, theta, log s):
each iteration polls the 8 points beta +- step_i e_i, moves to the best one if it
lowers rho, and otherwise halves the step; it stops when the step is below
``min_step_ratio`` times the initial one. It needs no gradients (rho need not be differentiable: chamfer distance,
shuffle distance) and is vectorised over many independent searches at once: all
searches that are still running are polled in one call of the objective.

Departures from the paper
-------------------------
* The chamfer distance is not symmetric: shrinking a curve onto a dense part of the
  reference lowers rho(T_alpha a, b) without aligning anything (on caviar1 the median
  item ran to the scale bound of the directed search). By default (``symmetric=True``) the descent therefore
  minimises rho(T_alpha a, b) + rho(b, T_alpha a), which a shrunken or displaced curve
  cannot game; the *directed* rho(T_alpha a, b) at that alpha is what is returned and
  what the kernel statistics of sec. 4.2 use. For curves the reverse term is computed
  from the chamfer image of a, in a's own frame: rho(b, T_alpha a) is the mean over b's
  points q of g(s |T_alpha^-1 q - a|).
* The search is confined to a box around the start (``bounds``), keeping it in the
  "approximately aligned" regime the paper assumes.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .. import similarity
from .curves import PointChamferImage
from .distances import ChamferMetric, Items, Metric
from .dynamics import from_beta, to_beta

__all__ = ["pattern_search", "DEFAULT_STEP", "DEFAULT_BOUNDS", "align_pairs", "align_to_reference", "refine_alpha"]

#: Initial compass step on beta = (ux px, uy px, theta rad, log s).
DEFAULT_STEP = np.array([2.0, 2.0, 0.05, 0.05])
#: Half-width of the search box around the start, beta units.
DEFAULT_BOUNDS = np.array([12.0, 12.0, 0.25, np.log(1.25)])


def pattern_search(objective: Callable[[np.ndarray, np.ndarray], np.ndarray], x0: np.ndarray,
                   step: np.ndarray, lower: np.ndarray, upper: np.ndarray, min_step_ratio: float = 1.0 / 64,
                   max_iter: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised compass search minimising N independent objectives.

    Parameters
    ----------
    objective : callable ``(idx (n,) int64, x (n, M, D) float64) -> (n, M) float64``
        Values of the searches ``idx`` at M points each.
    x0 : (N, D) float64, starting points (must satisfy the bounds).
    step : (D,) float64, initial step per coordinate (> 0).
    lower, upper : (D,) or (N, D) float64, box constraints.
    min_step_ratio : float, a search stops when step < min_step_ratio * initial step.
    max_iter : int, hard cap on iterations.

    Returns
    -------
    x : (N, D) float64, the minimisers found.
    f : (N,) float64, the objective there.
    """
    x = np.array(x0, dtype=np.float64, copy=True)
    n, dim = x.shape
    step0 = np.asarray(step, dtype=np.float64)
    if step0.shape != (dim,) or (step0 <= 0).any():
        raise ValueError(f"step must be ({dim},) and positive, got {step0}")
    lower = np.broadcast_to(np.asarray(lower, dtype=np.float64), (n, dim))
    upper = np.broadcast_to(np.asarray(upper, dtype=np.float64), (n, dim))
    idx_all = np.arange(n)
    f = objective(idx_all, x[:, None, :])[:, 0]
    scale = np.ones(n)  # current step = scale * step0
    # probe directions: +- e_i, (2D, D)
    dirs = np.concatenate([np.eye(dim), -np.eye(dim)])
    for _ in range(max_iter):
        active = np.nonzero(scale >= min_step_ratio)[0]
        if active.size == 0:
            break
        # x + scale * step0 * dir for every active search, clipped to the box
        probes = x[active, None, :] + scale[active, None, None] * step0[None, None, :] * dirs[None]
        probes = np.clip(probes, lower[active, None, :], upper[active, None, :])
        fp = objective(active, probes)
        best = np.argmin(fp, axis=1)
        fb = fp[np.arange(active.size), best]
        better = fb < f[active] - 1e-12 * np.abs(f[active])
        mv = active[better]
        x[mv] = probes[better, best[better]]
        f[mv] = fb[better]
        scale[active[~better]] *= 0.5
    return x, f


def _extent(metric: Metric, items: Items, bounds: np.ndarray, shift: float = 0.0) -> float:
    """How far (pixels) transformed items can stray from their untransformed extent."""
    extent = float(np.hypot(bounds[0], bounds[1])) + shift + 2.0
    if metric.kind == "curve":
        lo, hi = items.bounds()
        radius = float(np.abs(np.concatenate([lo, hi])).max())
        # a point at radius R moves by up to R (e^b_s - 1 + b_theta)
        extent += radius * (np.expm1(bounds[3]) + bounds[2])
    return extent


def align_pairs(metric: Metric, moving: Items, fixed: Items, j: int, alpha0: np.ndarray, symmetric: bool = True,
                step: np.ndarray = DEFAULT_STEP, bounds: np.ndarray = DEFAULT_BOUNDS,
                min_step_ratio: float = 1.0 / 64,
                moving_images: dict[int, PointChamferImage] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """alpha_i = argmin_alpha rho(T_alpha m_i, f_j) [+ rho(f_j, T_alpha m_i)] for every moving item.

    Parameters
    ----------
    metric : Metric
    moving : n items m_i (Curves or (n, h, w) patches).
    fixed : a batch holding the fixed item f_j at index ``j``.
    alpha0 : (4,) or (n, 4) float64, starting transforms; the search stays within
        beta(alpha0) +- bounds.
    symmetric : bool, add the reverse distance to the objective (module notes).
    step, bounds : (4,) float64 in beta = (ux, uy, theta, log s).
    moving_images : dict, optional cache of the moving items' chamfer images (curves),
        keyed by position in ``moving``; filled as needed.

    Returns
    -------
    alpha : (n, 4) float64, the minimisers.
    rho : (n,) float64, the directed distances rho(T_alpha m_i, f_j) there.
    """
    moving = metric.check_items(moving)
    fixed = metric.check_items(fixed)
    n = metric.n_items(moving)
    a0 = similarity.check_alpha(alpha0)
    a0 = np.broadcast_to(a0, (n, 4)) if a0.ndim == 1 else a0.reshape(n, 4)
    b0 = to_beta(a0)
    bounds = np.asarray(bounds, dtype=np.float64)
    extent = _extent(metric, moving, bounds, float(np.abs(a0[:, :2]).max()))
    fwd = metric.reference(fixed, j, extent=extent)

    def forward(idx: np.ndarray, alphas: np.ndarray) -> np.ndarray:
        m = alphas.shape[0] // idx.size
        return fwd(metric.transform(metric.subset(moving, np.repeat(idx, m)), alphas)).reshape(idx.size, m)

    chamfer = metric if isinstance(metric, ChamferMetric) and metric.method == "image" else None
    if chamfer is not None:
        q = fixed.curve(j)
        cache = {} if moving_images is None else moving_images

        def backward(idx: np.ndarray, alphas: np.ndarray) -> np.ndarray:
            m = alphas.shape[0] // idx.size
            al = alphas.reshape(idx.size, m, 4)
            out = np.empty((idx.size, m))
            for r, i in enumerate(idx):
                img = cache.get(int(i))
                if img is None:
                    img = cache[int(i)] = chamfer.point_image(moving.curve(int(i)), extent)
                # rho(f, T_alpha m) = mean_q g(s |T_alpha^-1 q - m|)
                pts = similarity.apply_many(similarity.invert(al[r]), q)
                out[r] = img.distance(pts, np.full(m, q.shape[0]), scale=al[r, :, 3])
            return out
    else:
        ref = metric.subset(fixed, j)

        def backward(idx: np.ndarray, alphas: np.ndarray) -> np.ndarray:
            m = alphas.shape[0] // idx.size
            moved = metric.transform(metric.subset(moving, np.repeat(idx, m)), alphas)
            return metric.pairwise(ref, moved)[0].reshape(idx.size, m)

    def objective(idx: np.ndarray, betas: np.ndarray) -> np.ndarray:
        alphas = from_beta(betas.reshape(-1, 4))
        f = forward(idx, alphas)
        return f + backward(idx, alphas) if symmetric else f

    b, _ = pattern_search(objective, b0, step, b0 - bounds, b0 + bounds, min_step_ratio)
    alpha = from_beta(b)
    return alpha, forward(np.arange(n), alpha)[:, 0]


def align_to_reference(metric: Metric, items: Items, reference: Items, j: int = 0,
                       alpha0: np.ndarray | None = None, symmetric: bool = True, step: np.ndarray = DEFAULT_STEP,
                       bounds: np.ndarray = DEFAULT_BOUNDS, min_step_ratio: float = 1.0 / 64
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Align every training item to one datum (sec. 4.1 step 1).

        alpha_t* = argmin_alpha rho(T_alpha^-1 z_t, z_0)     (+ the reverse term if symmetric)

    The search runs over gamma = alpha^-1 (x_t = T_gamma z_t) with :func:`align_pairs`.

    Parameters
    ----------
    metric : Metric
    items : N training items z_t.
    reference : a batch holding the datum z_0 at index ``j``.
    alpha0 : (N, 4) float64, starting alpha (default: identity).

    Returns
    -------
    alpha : (N, 4) float64, alpha_t* (z_t ~ T_alpha x_t).
    rho : (N,) float64, the directed rho(T_alpha*^-1 z_t, z_0).
    """
    items = metric.check_items(items)
    n = metric.n_items(items)
    g0 = np.tile(similarity.IDENTITY, (n, 1)) if alpha0 is None else \
        similarity.invert(similarity.check_alpha(alpha0).reshape(n, 4))
    gamma, rho = align_pairs(metric, items, reference, j, g0, symmetric, step, bounds, min_step_ratio)
    return similarity.invert(gamma), rho


def refine_alpha(metric: Metric, exemplars: Items, candidates: np.ndarray, target: Items, j: int,
                 alpha0: np.ndarray, symmetric: bool = True, step: np.ndarray = DEFAULT_STEP,
                 bounds: np.ndarray = DEFAULT_BOUNDS, min_step_ratio: float = 1.0 / 64,
                 exemplar_images: dict[int, PointChamferImage] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Best transform of each candidate exemplar onto one validation item (sec. 4.2).

        alpha_v = argmin_alpha rho(T_alpha x~_k, z_v)   (+ the reverse term if symmetric),  k in candidates

    Parameters
    ----------
    metric : Metric
    exemplars : K exemplars x~_k.
    candidates : (C,) int64, exemplar indices to try.
    target : a batch holding z_v at index ``j``.
    alpha0 : (4,) or (C, 4) float64, starting transform(s).
    exemplar_images : dict, optional cache of exemplar chamfer images keyed by exemplar index.

    Returns
    -------
    alpha : (C, 4) float64, rho : (C,) float64 directed rho(T_alpha x~_k, z_v).
    """
    cand = np.asarray(candidates, dtype=np.int64)
    sub = metric.subset(exemplars, cand)
    base = {} if exemplar_images is None else exemplar_images
    local = {pos: base[int(k)] for pos, k in enumerate(cand) if int(k) in base}
    out = align_pairs(metric, sub, target, j, alpha0, symmetric, step, bounds, min_step_ratio, moving_images=local)
    for pos, img in local.items():
        base[int(cand[pos])] = img
    return out
