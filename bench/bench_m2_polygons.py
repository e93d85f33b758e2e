"""Synthetic-polygon test of the M2 dimension estimate (Toyama & Blake 2002, sec. 5.1.1, fig. 4).

Random star-shaped polygons with d vertices are perturbed by moving each vertex along
its radius (one degree of freedom per vertex, so the shape space has dimension d),
sampled as curves (a point every 0.5 px), and compared with the chamfer image of the
unperturbed polygon (quadratic profile, eq. 4-5). The dimension is then estimated from
the chamfer distances by moments (eq. 10) for growing cluster sizes N, and by MLE
(eq. 11) at the largest N. The paper reports d ~ 24 for true d = 22 at N = 1000.

Two perturbation models:

* ``whitened``: y = s H^-1/2 w, w ~ N(0, I_d), where H is the metric matrix of the
  appendix (rho ~ y^T H y, computed from the linearised normal displacement along each
  edge). This is the appendix's model, under which rho ~ s^2 chi^2_d exactly to first order.
* ``iid``: independent vertex displacements y ~ N(0, tau^2 I). Then rho is a weighted
  sum of chi^2_1 terms with the eigenvalues of H as weights, and the moments estimator
  converges to the effective dimension (tr H)^2 / tr(H^2) <= d (printed as "pred").

Both are scaled so that E rho = 1 px^2 (an RMS normal displacement of 1 px).

Usage:  python bench/bench_m2_polygons.py [--dims 4 8 12 16 22] [--polygons 3] [--samples 1000]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gflow_core.m2.curves import Curves
from gflow_core.m2.distances import ChamferMetric
from gflow_core.m2.kernel import mle, moments


def random_polygon(d: int, rng: np.random.Generator, radius: float = 60.0) -> np.ndarray:
    """(d, 2) vertices of a star-shaped polygon, angles jittered, radii in [0.75, 1.25] radius."""
    ang = 2 * np.pi * (np.arange(d) + rng.uniform(-0.25, 0.25, d)) / d
    r = radius * rng.uniform(0.75, 1.25, d)
    return np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)


def sample_polygon(v: np.ndarray, spacing: float) -> np.ndarray:
    """Points along the closed polygon every ~``spacing`` px (vertices included). (P, 2)."""
    out = []
    for i in range(v.shape[0]):
        a, b = v[i], v[(i + 1) % v.shape[0]]
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing)))
        t = np.arange(n)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


def metric_matrix(v: np.ndarray) -> np.ndarray:
    """H with rho ~ y^T H y for radial vertex displacements y (appendix, linearised eq. 4).

    On edge e = (i, i+1) with unit normal n_e, the normal displacement is
    (1 - t) c_i y_i + t c_{i+1} y_{i+1} with c_j = n_e . e_j (e_j the radial unit vector),
    and rho = (1/L) sum_e l_e int_0^1 (...)^2 dt = (1/L) sum_e l_e (a^2 + a b + b^2) / 3.
    """
    d = v.shape[0]
    e = v / np.linalg.norm(v, axis=1, keepdims=True)
    H = np.zeros((d, d))
    L = 0.0
    for i in range(d):
        j = (i + 1) % d
        t = v[j] - v[i]
        length = float(np.linalg.norm(t))
        n = np.array([t[1], -t[0]]) / length
        ci, cj = n @ e[i], n @ e[j]
        H[i, i] += length * ci * ci / 3
        H[j, j] += length * cj * cj / 3
        H[i, j] += length * ci * cj / 6
        H[j, i] += length * ci * cj / 6
        L += length
    return H / L


def chamfer_samples(v: np.ndarray, y: np.ndarray, metric: ChamferMetric, spacing: float) -> np.ndarray:
    """rho(perturbed_n, polygon) for each row of y (N, d) radial displacements. (N,)."""
    e = v / np.linalg.norm(v, axis=1, keepdims=True)
    ref = Curves.from_list([sample_polygon(v, 0.05)])
    rho_fn = metric.reference(ref, 0, extent=4.0 * float(np.abs(y).max()) + 4.0)
    curves = Curves.from_list([sample_polygon(v + yi[:, None] * e, spacing) for yi in y])
    return rho_fn(curves)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dims", type=int, nargs="+", default=[4, 8, 12, 16, 22])
    ap.add_argument("--polygons", type=int, default=5, help="random polygons per d")
    ap.add_argument("--samples", type=int, default=1000, help="perturbed polygons per polygon (largest N)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 30, 100, 300, 1000])
    ap.add_argument("--spacing", type=float, default=0.5, help="curve sample spacing, px")
    ap.add_argument("--upsample", type=int, default=8, help="chamfer canvas pixels per pixel")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sizes = [n for n in args.sizes if n <= args.samples]
    metric = ChamferMetric("quadratic", upsample=args.upsample)
    t_start = time.perf_counter()
    print(f"M2 dimension estimate on random polygons: {args.polygons} polygons per d, radius 60 px, "
          f"E rho = 1 px^2, quadratic chamfer (canvas 1/{args.upsample} px)")
    print("cells: moments estimate (eq. 10), mean +- sd over disjoint clusters of size N and polygons\n")
    head = "".join(f"{'N=' + str(n):>14}" for n in sizes)
    for mode in ("whitened", "iid"):
        print(f"[{mode}]")
        print(f"{'true d':>6} {'pred':>6}{head} {'MLE@' + str(sizes[-1]):>10} {'rho_a/rho_g':>11}")
        for d in args.dims:
            est: dict[int, list[float]] = {n: [] for n in sizes}
            d_mle, preds, ratios = [], [], []
            for p in range(args.polygons):
                rng = np.random.default_rng([args.seed, d, p])
                v = random_polygon(d, rng)
                H = metric_matrix(v)
                w = rng.standard_normal((args.samples, d))
                if mode == "whitened":
                    ev, U = np.linalg.eigh(H)
                    # y = s H^-1/2 w  ->  rho ~ s^2 |w|^2,  E rho = s^2 d = 1
                    y = (w @ (U @ np.diag(ev**-0.5) @ U.T).T) / np.sqrt(d)
                    preds.append(float(d))
                else:
                    # y = tau w  ->  E rho = tau^2 tr(H) = 1
                    y = w / np.sqrt(np.trace(H))
                    preds.append(float(np.trace(H) ** 2 / np.trace(H @ H)))
                rho = chamfer_samples(v, y, metric, args.spacing)
                for n in sizes:
                    for g in range(args.samples // n):
                        est[n].append(moments(rho[g * n : (g + 1) * n])[0])
                d_mle.append(mle(rho[: sizes[-1]])[0])
                ratios.append(rho.mean() / np.exp(np.log(rho).mean()))
            cells = "".join(f"{np.mean(est[n]):8.1f} +-{np.std(est[n]):4.1f}" for n in sizes)
            print(f"{d:6d} {np.mean(preds):6.1f}{cells} {np.mean(d_mle):10.1f} {np.mean(ratios):11.3f}")
        print()
    print(f"total time {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
