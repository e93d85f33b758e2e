"""How well a face model learned from one half of david_indoor spans the landmarks of the other half.

One command: ``python bench/bench_gflow_shape_space.py [--split 335] [-k 5,1] [--vertices 160]``

The model of ``gflow learn gflow ../shared/data/david_indoor --frames 0:335`` (and of ``--frames
335:669``) is learned here the same way (``learn_morphable``: Procrustes, the frontal unit-height
frame, 160 vertices, the mean shape and k - 1 principal deformations; boxes only place the model's
reference box, so they are left out), with each ``-k`` (5, the default model's; 1, the mean shape
alone). Every frame with landmarks, of the half it was learned from (in-sample) and of the other
half (held out), is then fitted by the model: a similarity (scale, rotation, translation) of the
frame's landmarks at the model's vertices onto the model's shape, and the morph coefficients of that
shape (``mean + sum_j c_j h_j``, ``c_1`` = 1), found in turn until they stop changing (each step
least squares, so the error only falls). The error is the RMS 3-D distance of the vertices from the
fitted shape, in face heights (the model's unit), over every fitted frame.

Printed, per half and k: the frames, the learner's own residual (what ``gflow learn gflow`` prints:
the deformations with their linearised rigid part and their mean removed, beyond the morphs) and the
fit's RMS in-sample and held out. Nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import table  # noqa: E402

from gflow_core.gflow.morphable_learn import learn_morphable  # noqa: E402
from pipeline.io.landmarks import read_landmarks, resolve_landmarks  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "david_indoor"


def rotations_onto(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(T, 3, 3) proper rotations ``R`` with ``src[t] @ R`` nearest ``dst[t]`` (both (T, n, 3), centred):
    orthogonal Procrustes without reflection."""
    u, _, vt = np.linalg.svd(np.einsum("tni,tnj->tij", src, dst))
    d = np.sign(np.linalg.det(u @ vt))
    u = u.copy()
    u[:, :, 2] *= np.where(d == 0, 1.0, d)[:, None]
    return u @ vt


def fit_rms(frames: np.ndarray, bases: np.ndarray, iters: int = 200, tol: float = 1e-12) -> float:
    """RMS distance (model units) of each frame's vertices, fitted by a similarity and the morph
    coefficients, from the model's shape.

    Parameters
    ----------
    frames : (T, n, 3) float64
        Landmarks at the model's vertices (any units), finite.
    bases : (n, 3, k) float64
        The model's ``h_i``; ``bases[:, :, 0]`` the mean shape, its coefficient held at 1.
    iters, tol : the alternation's cap and the change of the squared error at which it stops.

    Returns
    -------
    float
        ``sqrt(sum over frames and vertices of |s x R + t - shape|^2 / (T n))``.
    """
    n, _, k = bases.shape
    mean = bases[:, :, 0]
    morphs = bases[:, :, 1:].reshape(n * 3, k - 1)
    xc = frames - frames.mean(axis=1, keepdims=True)
    norms2 = (xc * xc).sum(axis=(1, 2))
    shape = np.repeat(mean[None], frames.shape[0], axis=0)
    last = np.inf
    for _ in range(iters):
        cen = shape.mean(axis=1, keepdims=True)
        rot = rotations_onto(xc, shape - cen)
        num = np.einsum("tni,tij,tnj->t", xc, rot, shape - cen)  # trace of (x R)^T (shape - centroid)
        fitted = (num / norms2)[:, None, None] * np.einsum("tni,tij->tnj", xc, rot) + cen
        if k > 1:
            c = np.linalg.lstsq(morphs, (fitted - mean[None]).reshape(len(xc), -1).T, rcond=None)[0]
            shape = mean[None] + (morphs @ c).T.reshape(-1, n, 3)
        err = float(((fitted - shape) ** 2).sum())
        if last - err <= tol * max(err, 1e-30):
            break
        last = err
    return float(np.sqrt(err / (frames.shape[0] * n)))


def halves(lm: np.ndarray, split: int) -> dict[str, np.ndarray]:
    """The two halves' frames with every landmark, by name (``0:split``, ``split:T``)."""
    out = {}
    for a, b in ((0, split), (split, lm.shape[0])):
        part = lm[a:b]
        out[f"{a}:{b}"] = part[np.isfinite(part).all(axis=(1, 2))]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", type=int, default=335, help="first frame of the second half (default 335)")
    ap.add_argument("-k", default="5,1", help="morph bases to learn with, comma-separated (default 5,1)")
    ap.add_argument("--vertices", type=int, default=160, help="vertices kept (default 160, gflow learn gflow's)")
    args = ap.parse_args()
    ks = [int(v) for v in args.k.split(",")]
    if not (DATA / "landmarks.npz").is_file():
        raise SystemExit(f"{DATA} (landmarks.npz) not found: this benchmark needs ../shared/data/david_indoor")
    lm = read_landmarks(resolve_landmarks(str(DATA)), dims=(3,))
    parts = halves(lm, args.split)
    rows = []
    for learned, train in parts.items():
        (other, test), = ((n, p) for n, p in parts.items() if n != learned)
        for k in ks:
            face = learn_morphable([train], k=k, n_vertices=args.vertices)
            sel = face.model.landmarks
            rows.append([learned, other, k, f"{len(train)} / {len(test)}", f"{face.residual_rms:.4f}",
                         f"{fit_rms(train[:, sel], face.model.bases):.4f}",
                         f"{fit_rms(test[:, sel], face.model.bases):.4f}"])
    print(f"Shape space of david_indoor's halves ({args.vertices} vertices), RMS in face heights")
    print(table(rows, ["learned on", "held out", "k", "frames (in / out)", "learner's residual",
                       "fit in-sample", "fit held out"]))


if __name__ == "__main__":
    main()
