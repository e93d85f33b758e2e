"""Model files: learned or user-supplied models as ``.npz`` archives of plain arrays.

A model file is a ``numpy.savez`` archive (no pickle: it is read with
``np.load(..., allow_pickle=False)``) holding a ``kind`` entry, a 0-d unicode array that
says which model it is, plus the arrays of that model's own array format:

========== =========================================== ==============================================
``kind``   object                                      array format
========== =========================================== ==============================================
``"m2"``   :class:`gflow_core.m2.model.M2Model`        :meth:`M2Model.to_arrays` (versioned there)
``"morphable"`` :class:`gflow_core.gflow.head_model.MorphableModel`  :func:`head_model.model_to_arrays`
========== =========================================== ==============================================

Entries whose names start with ``meta_`` are file-level metadata (how the model was
made: the training source, the edge detector's thresholds...). They are not part of the
model's array format, are stripped before it is rebuilt, and are returned by
:func:`load_meta`. Metadata values are numbers or strings (0-d or 1-d arrays).

Every problem with a file (missing, truncated or corrupt, pickled arrays, no or unknown
``kind``, wrong format version, bad values) raises an error naming the file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from pipeline.io.npz_files import read_npz
from pipeline.io.path_errors import FolderForFile, MissingPath

__all__ = ["save_model", "load_model", "load_meta", "read_arrays", "describe", "KINDS", "META_PREFIX",
           "BUILTIN_MODELS", "model_path", "kind_of"]

#: model kinds a file may hold
KINDS = ("m2", "morphable")
#: prefix of file-level metadata entries
META_PREFIX = "meta_"
#: models shipped with the package, by name: a graph or ``--model`` may name them instead of a file
#: (``face``: learned by ``gflow learn gflow`` from david_indoor's MediaPipe landmarks, see docs/faces.md)
BUILTIN_MODELS = {"face": Path(__file__).resolve().parent.parent / "models" / "face.npz"}


def model_path(name: str | os.PathLike, base_dir: str | os.PathLike = ".") -> Path:
    """The file a model parameter names: a built-in model's file (:data:`BUILTIN_MODELS`), else the
    path relative to ``base_dir``."""
    if str(name) in BUILTIN_MODELS:
        return BUILTIN_MODELS[str(name)]
    return Path(base_dir, name)


def kind_of(obj: Any) -> str:
    """The kind (:data:`KINDS`) of a model object: ``"m2"`` for an M2Model, ``"morphable"`` for a MorphableModel."""
    from gflow_core.m2.model import M2Model

    if isinstance(obj, M2Model):
        return "m2"
    from gflow_core.gflow.head_model import MorphableModel

    if isinstance(obj, MorphableModel):
        return "morphable"
    raise TypeError(f"cannot save a {type(obj).__name__} as a model file; known kinds: {', '.join(KINDS)}")


def _to_arrays(obj: Any, kind: str) -> dict[str, np.ndarray]:
    if kind == "m2":
        return obj.to_arrays()
    from gflow_core.gflow.head_model import model_to_arrays

    return model_to_arrays(obj)


def _meta_arrays(meta: Mapping[str, Any] | None) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for k, v in (meta or {}).items():
        if not k.isidentifier():
            raise ValueError(f"metadata key {k!r} must be an identifier")
        a = np.asarray(v)
        if a.dtype == object or a.dtype.kind not in "biufU" or a.ndim > 1:
            raise ValueError(f"metadata {k!r} must be a number, a string or a 1-d array of them, got {v!r}")
        out[META_PREFIX + k] = a
    return out


def save_model(path: str | os.PathLike, obj: Any, meta: Mapping[str, Any] | None = None, new: bool = False) -> Path:
    """Write a model to ``path`` (``.npz``), atomically: under a hidden temporary name beside it
    (:func:`pipeline.io.recording_files.write_beside`), moved into place once complete. A write that
    fails (a full disk: an OSError naming ``path``) leaves neither file.

    Parameters
    ----------
    path : destination; the name is used as given (no ``.npz`` is appended).
    obj : M2Model or MorphableModel.
    meta : optional file-level metadata {name: number | str | 1-d array}, stored as
        ``meta_<name>`` and returned by :func:`load_meta`.
    new : never over a file (:func:`pipeline.io.recording_files.move_new`: a file that appeared under
        ``path`` while the model was written is an error); otherwise a file there is replaced.

    Returns
    -------
    Path of the written file.
    """
    kind = kind_of(obj)
    arrays: dict[str, Any] = _to_arrays(obj, kind)  # Any: np.savez's keywords also name its allow_pickle flag
    clash = [k for k in arrays if k == "kind" or k.startswith(META_PREFIX)]
    if clash:
        raise ValueError(f"model arrays use reserved name(s) {clash}")
    arrays = {"kind": np.array(kind), **arrays, **_meta_arrays(meta)}
    for k, a in arrays.items():
        if np.asarray(a).dtype == object:
            raise ValueError(f"model array {k!r} has dtype object; model files hold plain arrays only")
    from pipeline.io.recording_files import write_beside

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    write_beside(p, lambda f: np.savez(f, **arrays), replace=not new)
    return p


def read_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of a model file, read eagerly and checked for pickle-free content.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    IsADirectoryError
        A folder was given.
    ValueError
        The file is not a readable npz archive (truncated, corrupt, not a zip), or holds
        pickled (object) arrays. The message names the file.
    """
    p = Path(path)
    if p.is_dir():  # there, so "not found" would send the user looking for a file that exists
        raise FolderForFile(f"{p} is a folder, not a model file (give an .npz file)")
    if not p.is_file():
        raise MissingPath(f"model file not found: {p}")
    return read_npz(p, "model file")


def _split(path: Path, arrays: dict[str, np.ndarray]) -> tuple[str, dict[str, np.ndarray], dict[str, np.ndarray]]:
    if "kind" not in arrays:
        raise ValueError(f"{path}: not a gflow model file (no 'kind' entry; expected one of {', '.join(KINDS)})")
    k = arrays["kind"]
    if k.shape != () or k.dtype.kind != "U":
        raise ValueError(f"{path}: 'kind' must be a string, got {k.dtype} array of shape {k.shape}")
    kind = str(k)
    if kind not in KINDS:
        raise ValueError(f"{path}: unknown model kind {kind!r} (this gflow reads {', '.join(KINDS)})")
    body = {n: a for n, a in arrays.items() if n != "kind" and not n.startswith(META_PREFIX)}
    meta = {n[len(META_PREFIX):]: a for n, a in arrays.items() if n.startswith(META_PREFIX)}
    return kind, body, meta


def load_model(path: str | os.PathLike) -> Any:
    """Read a model file: an M2Model (kind ``"m2"``) or a MorphableModel (kind ``"morphable"``).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Corrupt or truncated file, pickled arrays, no or unknown ``kind``, another format
        version, or arrays the model rejects; the message names the file.
    """
    p = Path(path)
    kind, body, _ = _split(p, read_arrays(p))
    try:
        if kind == "m2":
            from gflow_core.m2.model import M2Model

            return M2Model.from_arrays(body)
        from gflow_core.gflow.head_model import model_from_arrays

        return model_from_arrays(body)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None


def load_meta(path: str | os.PathLike) -> dict[str, Any]:
    """File-level metadata of a model file as Python values (str, float, int or list)."""
    p = Path(path)
    _, _, meta = _split(p, read_arrays(p))
    return {k: (a.item() if a.ndim == 0 else a.tolist()) for k, a in meta.items()}


# ---------------------------------------------------------------------------------------
# gflow info MODEL.npz
# ---------------------------------------------------------------------------------------


def _stats(v: np.ndarray) -> dict[str, float]:
    v = np.asarray(v, dtype=np.float64)
    q = np.percentile(v, [0, 25, 50, 75, 100])
    return {"min": float(q[0]), "q25": float(q[1]), "median": float(q[2]), "q75": float(q[3]), "max": float(q[4]),
            "mean": float(v.mean())}


def _describe_m2(model) -> dict[str, Any]:
    K = model.K
    d = model.d
    rounded = np.rint(d).astype(int)
    vals, counts = np.unique(rounded, return_counts=True)
    m = model.markov
    # a cell "seen" is above the level the Dirichlet prior alone gives a row (1 / K)
    above = m > (1.0 / K) * 1.5 if K > 1 else np.ones_like(m, dtype=bool)
    pi_sorted = np.sort(model.pi)[::-1]
    # perplexity exp(H(pi)): the effective number of exemplars
    nz = model.pi[model.pi > 0]
    info: dict[str, Any] = {
        "kind": "m2",
        "metric": model.metric,
        "kernel": model.kernel,
        "K": K,
        "exemplar_kind": model.kind,
        "d": _stats(d),
        "d_histogram": {str(int(v)): int(c) for v, c in zip(vals, counts)},
        "sigma": _stats(model.sigma),
        "pi": {"max": float(pi_sorted[0]), "min": float(pi_sorted[-1]),
               "effective_K": float(np.exp(-(nz * np.log(nz)).sum())), "top5": [float(v) for v in pi_sorted[:5]]},
        "markov": {"diagonal_mean": float(np.mean(np.diag(m))),
                   "cells_above_prior_fraction": float(above.mean()),
                   "mean_cells_above_prior_per_row": float(above.sum(axis=1).mean()),
                   "row_entropy_mean_nats": float(np.mean(-(m * np.log(np.maximum(m, 1e-300))).sum(axis=1)))},
        "ar": {"A": model.dynamics.A.tolist(), "mean": model.dynamics.mean.tolist(),
               "noise_std": np.sqrt(np.diag(model.dynamics.B @ model.dynamics.B.T)).tolist(),
               "state": "beta = (ux px, uy px, theta rad, log s)"},
        "ref_size": model.ref_size.tolist(),
        "exemplar_frame": model.exemplar_frame.tolist(),
    }
    if model.kind == "curve":
        info["points_per_exemplar"] = _stats(model.exemplars.n_points)
        info["chamfer"] = {"profile": model.profile, "g0": model.g0, "upsample": model.upsample}
        if model.appearance is not None:
            a = model.appearance
            info["appearance"] = {"grid": [int(a.patches.shape[2]), int(a.patches.shape[1])],
                                  "channels": int(a.patches.shape[3]), "d": _stats(a.d), "sigma": _stats(a.sigma)}
    else:
        info["patch_shape"] = list(model.exemplars.shape[1:])
        if model.metric == "shuffle":
            info["shuffle_radius"] = model.shuffle_radius
    return info


def _describe_morphable(model) -> dict[str, Any]:
    info: dict[str, Any] = {"kind": "morphable", "vertices": int(model.n_vertices), "bases": int(model.n_bases),
                            "triangles": 0 if model.triangles is None else int(np.asarray(model.triangles).shape[0])}
    if model.landmarks is not None:
        info["landmarks"] = [int(v) for v in model.landmarks]
    if model.reference_box is not None:
        info["reference_box"] = [float(v) for v in model.reference_box]
    if model.morph_std is not None:
        info["morph_std"] = [float(v) for v in model.morph_std]
    return info


def _fmt_stats(s: dict[str, float], fmt: str = ".3g") -> str:
    return (f"min {s['min']:{fmt}}  q25 {s['q25']:{fmt}}  median {s['median']:{fmt}}  q75 {s['q75']:{fmt}}  "
            f"max {s['max']:{fmt}}  (mean {s['mean']:{fmt}})")


def describe(path: str | os.PathLike, as_json: bool = False) -> None:
    """Print what a model file holds (``gflow info MODEL.npz``)."""
    p = Path(path)
    model = load_model(p)
    meta = load_meta(p)
    kind = kind_of(model)
    info = _describe_m2(model) if kind == "m2" else _describe_morphable(model)
    info = {"file": str(p), "bytes": p.stat().st_size, **info, "meta": meta}
    if as_json:
        print(json.dumps(info, indent=1))
        return
    print(f"file:      {p}  ({info['bytes'] / 1024:.1f} KiB)")
    if kind == "morphable":
        print(f"model:     morphable (G-flow), {info['vertices']} vertices, {info['bases']} morph bases, "
              f"{info['triangles']} triangles")
        if "landmarks" in info:
            lm = info["landmarks"]
            print(f"face:      each vertex keeps its reference landmark: {', '.join(map(str, lm[:8]))}"
                  f"{', ...' if len(lm) > 8 else ''}")
        if "reference_box" in info:
            print("box:       where a user's box sits, model units: x {:.3f} y {:.3f} w {:.3f} h {:.3f}".format(
                *info["reference_box"]))
        if "morph_std" in info:
            print("morphs:    training spread of c_j / c_1: " + ", ".join(f"{v:.4f}" for v in info["morph_std"][1:]))
    else:
        print(f"model:     M2 (Toyama & Blake 2002), K = {info['K']} {info['exemplar_kind']} exemplars, "
              f"metric {info['metric']}, kernel {info['kernel']} (eq. {10 if info['kernel'] == 'moments' else 11})")
        if "chamfer" in info:
            c = info["chamfer"]
            print(f"chamfer:   profile {c['profile']}, g0 {c['g0']:g}, upsample {c['upsample']}; points per "
                  f"exemplar: {_fmt_stats(info['points_per_exemplar'], '.0f')}")
            if "appearance" in info:
                a = info["appearance"]
                print(f"appearance: orientation-channel patches {a['grid'][0]}x{a['grid'][1]}x{a['channels']}; "
                      f"d'_k median {a['d']['median']:.3g}, sigma'_k median {a['sigma']['median']:.3g}")
        else:
            extra = f", shuffle radius {info['shuffle_radius']}" if "shuffle_radius" in info else ""
            print(f"patches:   {info['patch_shape'][0]}x{info['patch_shape'][1]} (rows x cols){extra}")
        print(f"ref size:  {info['ref_size'][0]:.1f} x {info['ref_size'][1]:.1f} (w x h, item units at s = 1)")
        print(f"d_k:       {_fmt_stats(info['d'])}")
        print("           rounded: " + ", ".join(f"{v}: {c}" for v, c in info["d_histogram"].items()))
        print(f"sigma_k:   {_fmt_stats(info['sigma'])}")
        pi = info["pi"]
        print(f"pi_k:      max {pi['max']:.3f}  min {pi['min']:.3f}  effective K (exp entropy) {pi['effective_K']:.1f}")
        mk = info["markov"]
        print(f"markov:    mean diagonal {mk['diagonal_mean']:.3f}; cells above 1.5/K: "
              f"{100 * mk['cells_above_prior_fraction']:.1f}% ({mk['mean_cells_above_prior_per_row']:.1f} per row); "
              f"mean row entropy {mk['row_entropy_mean_nats']:.2f} nats")
        ar = info["ar"]
        print("AR(1):     beta_t - m = A (beta_{t-1} - m) + B w,  beta = (ux, uy, theta, log s)")
        print("           diag A  = " + "  ".join(f"{ar['A'][i][i]:.3f}" for i in range(4)))
        print("           mean m  = " + "  ".join(f"{v:.3g}" for v in ar["mean"]))
        print("           noise std (sqrt diag BB^T) = " + "  ".join(f"{v:.3g}" for v in ar["noise_std"]))
        fr = [f for f in info["exemplar_frame"] if f >= 0]
        if fr:
            print(f"exemplars: from training frames {min(fr)}..{max(fr)}")
    for k, v in meta.items():
        print(f"meta {k}: {v}")
