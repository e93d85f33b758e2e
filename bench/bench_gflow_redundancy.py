"""How many of G-flow's vertices make one independent residual on david_indoor (``data_temper``).

One command: ``python bench/bench_gflow_redundancy.py [--frames 0,348,351]``

Eq. 13 multiplies one Gaussian per vertex as if the residuals were independent. Neighbouring
vertices read overlapping pixels of a frame blurred by the contrast normalisation, so they are not.
This measures by how much, with the built-in face model placed in david_indoor's first box (its
vertices' nearest-neighbour spacing) and the contrast-normalised frames (``contrast_sigma`` 5)
over that box: the correlation ``rho(d)`` of the frame with itself moved by ``d`` pixels
(averaged over the four axis directions; between vertices, at their offset, and 0 beyond
``--max-lag``), and two redundancies: of the data term's quadratic form, ``kappa_2 = sum_ij
rho_ij^2 / n`` (the variance of a sum of ``n`` squared standardised residuals with correlations
``rho_ij`` is ``2 sum_ij rho_ij^2``, that of ``n / kappa_2`` independent ones), and of its linear
part, ``kappa_1 = sum_ij rho_ij / n`` (the variance of the sum of the residuals themselves, which is
what the pose's gradient and the difference between two nearby poses weigh). The frame's correlation stands in for the residuals' (the texels are the face's
look, so the residual's texture is the frame's where the model misfits). Nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import table  # noqa: E402

from gflow_core.gflow.geometry import project  # noqa: E402
from gflow_core.gflow.head_model import pose_for_box  # noqa: E402
from gflow_core.gflow.image import local_contrast  # noqa: E402
from pipeline.io.modelfile import BUILTIN_MODELS, load_model  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "david_indoor"
BOX = np.array([169.0, 76.0, 46.0, 60.0])  # david_indoor's first box, as bench_gflow_pace.py
CONTRAST_SIGMA = 5.0  # GFlowParams.contrast_sigma


def correlation(patch: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Correlation of the zero-mean ``patch`` (h, w) with itself moved by integer ``(dx, dy)`` (any shape),
    over the overlapping pixels."""
    p = patch - patch.mean()
    h, w = p.shape
    var = float((p * p).mean())
    out = np.zeros(dx.shape)
    for i, (a, b) in enumerate(zip(dx.ravel(), dy.ravel())):
        a, b = int(a), int(b)
        if abs(a) >= w or abs(b) >= h:
            continue
        p1 = p[max(b, 0):h + min(b, 0), max(a, 0):w + min(a, 0)]
        p2 = p[max(-b, 0):h + min(-b, 0), max(-a, 0):w + min(-a, 0)]
        out.flat[i] = float((p1 * p2).mean()) / var
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", default="0,348,351", help="david_indoor frames, comma-separated")
    ap.add_argument("--max-lag", type=float, default=10.0, help="rho = 0 beyond this many pixels")
    args = ap.parse_args()
    if not (DATA / "frames").is_dir():
        print(f"error: no frames in {DATA}", file=sys.stderr)
        return 2
    try:
        frames = [int(v) for v in args.frames.split(",")]
    except ValueError:
        print(f"error: --frames must be integers, got {args.frames!r}", file=sys.stderr)
        return 2
    model = load_model(BUILTIN_MODELS["face"])
    first = cv2.imread(str(DATA / "frames" / "000000.jpg"), cv2.IMREAD_GRAYSCALE)
    xy = project(model.bases, pose_for_box(model, BOX, first.shape))  # (n, 2)
    n = len(xy)
    dist = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    spacing = float(np.median(np.sort(dist, axis=1)[:, 1]))
    print(f"{n} vertices in the first box, nearest-neighbour spacing {spacing:.2f} px (median)")
    x0, y0 = np.floor(xy.min(axis=0)).astype(int)
    x1, y1 = np.ceil(xy.max(axis=0)).astype(int)
    lags = np.arange(0, int(args.max_lag) + 1)
    rows = []
    for k in frames:
        path = DATA / "frames" / f"{k:06d}.jpg"
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            print(f"error: cannot read {path}", file=sys.stderr)
            return 2
        patch = local_contrast(img / 255.0, CONTRAST_SIGMA)[y0:y1, x0:x1]
        # rho(d) averaged over the directions: the offsets (dx, dy) rounded to whole pixels
        off = np.rint(xy[:, None] - xy[None]).astype(int)
        near = dist <= args.max_lag
        rho = np.zeros((n, n))
        rho[near] = correlation(patch, off[..., 0][near], off[..., 1][near])
        radial = [float(correlation(patch, np.array([d, 0, -d, 0]), np.array([0, d, 0, -d])).mean()) for d in lags]
        # kappa = sum_ij rho_ij^2 / n
        kappa2 = float((rho * rho).sum() / n)
        # kappa_1 = sum_ij rho_ij / n
        kappa1 = float(rho.sum() / n)
        rows.append([k] + [f"{r:.2f}" for r in radial] + [f"{kappa2:.2f}", f"{kappa1:.2f}"])
    print(table(rows, ["frame"] + [f"rho({d})" for d in lags] + ["kappa_2", "kappa_1"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
