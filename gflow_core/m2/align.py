"""Direct descent over the similarity transform alpha (Toyama & Blake 2002, sec. 4.1-4.2).

The paper aligns every training item to a datum, and every validation item to its best
exemplar, by "direct descent" on

    alpha_t* = argmin_alpha rho(T_alpha^-1 z_t*, z_0*)                      (sec. 4.1, step 1)
    alpha_v  = argmin_alpha rho(T_alpha x~, z_v)                            (sec. 4.2)

Here direct descent is a *compass (pattern) search* in beta = (ux, uy, theta, log s):
each iteration polls the 8 points beta +- step_i e_i, moves to the best one if it
lowers rho, and otherwise halves the step; it stops when every step is below
``min_step``. It needs no gradients (rho need not be differentiable: chamfer distance,
shuffle distance) and is vectorised over many independent searches at once: all
searches that are still running are polled in one call of the objective.

Departure from the paper: the search is confined to a box around the start
(``bounds``). The chamfer distance is not symmetric, so shrinking a curve onto a dense
part of the reference lowers rho without aligning anything; bounding the scale, the
rotation and the shift keeps the descent to the "approximately aligned" regime the
paper assumes.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .. import similarity
from .distances import Metric, Items
from .dynamics import from_beta, to_beta

__all__ = ["pattern_search", "DEFAULT_STEP", "DEFAULT_BOUNDS", "align_to_reference", "refine_alpha"]

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


def _curve_or_patch_objective(metric: Metric, items: Items, ref: Callable[[Items], np.ndarray],
                              inverse: bool) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    def objective(idx: np.ndarray, betas: np.ndarray) -> np.ndarray:
        n, m, _ = betas.shape
        alphas = from_beta(betas.reshape(-1, 4))
        if inverse:
            alphas = similarity.invert(alphas)
        sub = metric.subset(items, np.repeat(idx, m))
        return ref(metric.transform(sub, alphas)).reshape(n, m)

    return objective


def align_to_reference(metric: Metric, items: Items, reference: Items, j: int = 0,
                       alpha0: np.ndarray | None = None, step: np.ndarray = DEFAULT_STEP,
                       bounds: np.ndarray = DEFAULT_BOUNDS, min_step_ratio: float = 1.0 / 64
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Align every item to one reference datum (sec. 4.1 step 1).

        alpha_t* = argmin_alpha rho(T_alpha^-1 z_t, z_0)

    Parameters
    ----------
    metric : Metric
    items : N training items z_t (Curves or (N, h, w) patches).
    reference : a batch holding the datum z_0 at index ``j``.
    alpha0 : (N, 4) float64, starting alpha (default: identity).
    step, bounds : (4,) float64 in beta = (ux, uy, theta, log s); the search stays within
        ``beta0 +- bounds``.

    Returns
    -------
    alpha : (N, 4) float64, alpha_t* (so that z_t ~ T_alpha x_t).
    rho : (N,) float64, rho(T_alpha*^-1 z_t, z_0) at the optimum.
    """
    items = metric.check_items(items)
    n = metric.n_items(items)
    a0 = np.tile(similarity.IDENTITY, (n, 1)) if alpha0 is None else similarity.check_alpha(alpha0).reshape(n, 4)
    b0 = to_beta(a0)
    bounds = np.asarray(bounds, dtype=np.float64)
    extent = float(np.hypot(bounds[0], bounds[1]))
    if metric.kind == "curve":
        # room for the rotation / scale bounds too: a point at radius R moves by up to R (e^b - 1 + b_theta)
        lo, hi = items.bounds()
        radius = float(np.abs(np.concatenate([lo, hi])).max())
        extent += radius * (np.expm1(bounds[3]) + bounds[2])
    ref = metric.reference(reference, j, extent=extent)
    obj = _curve_or_patch_objective(metric, items, ref, inverse=True)
    b, f = pattern_search(obj, b0, step, b0 - bounds, b0 + bounds, min_step_ratio)
    return from_beta(b), f


def refine_alpha(metric: Metric, exemplars: Items, candidates: np.ndarray, target: Items, j: int,
                 alpha0: np.ndarray, step: np.ndarray = DEFAULT_STEP, bounds: np.ndarray = DEFAULT_BOUNDS,
                 min_step_ratio: float = 1.0 / 64) -> tuple[np.ndarray, np.ndarray]:
    """Best transform of each candidate exemplar onto one validation item (sec. 4.2).

        alpha_v = argmin_alpha rho(T_alpha x~_k, z_v),   k in candidates

    Parameters
    ----------
    metric : Metric
    exemplars : K exemplars x~_k.
    candidates : (C,) int64, exemplar indices to try.
    target : a batch holding z_v at index ``j``.
    alpha0 : (4,) or (C, 4) float64, starting transform(s).

    Returns
    -------
    alpha : (C, 4) float64, rho : (C,) float64
    """
    cand = np.asarray(candidates, dtype=np.int64)
    sub = metric.subset(exemplars, cand)
    a0 = similarity.check_alpha(alpha0)
    a0 = np.broadcast_to(a0, (cand.size, 4)) if a0.ndim == 1 else a0
    b0 = to_beta(a0)
    bounds = np.asarray(bounds, dtype=np.float64)
    extent = float(np.hypot(bounds[0], bounds[1]))
    if metric.kind == "curve":
        lo, hi = sub.bounds()
        radius = float(np.abs(np.concatenate([lo, hi])).max())
        extent += radius * (np.expm1(bounds[3]) + bounds[2]) + float(np.abs(a0[:, :2]).max())
    ref = metric.reference(target, j, extent=extent)
    obj = _curve_or_patch_objective(metric, sub, ref, inverse=False)
    b, f = pattern_search(obj, b0, step, b0 - bounds, b0 + bounds, min_step_ratio)
    return from_beta(b), f
