"""The online model of the face (:class:`.online_guard.OnlineFace`) as snapshot fields, and back, bit for bit.

A process that snapshots G-flow's posterior (the pipeline's filter stage) stores the model as two fields
(:func:`.state_fields.state_fields`): ``online``, every array of the filter (the running average it is solved
from, the detection filter, the first frame's anchor, DSST's scale filter) as one flat float64 vector (complex
arrays with their real and imaginary parts interleaved; :func:`gflow_core.dcf.state.model_arrays`, as the
default tracker's snapshot stores its model), and ``online_values``, the parts' names and shapes and
the model's plain values (the first box's size, where it last placed the face, its log scale, its distance
distributions, the frames learnt from, the periods placed away from the experts). The window's geometry is not
stored: it is made again from the first box's size and the filter's settings, as the default tracker's snapshot
does (:func:`gflow_core.dcf.state.from_arrays`). No I/O.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..dcf import model as tm
from ..dcf.state import model_arrays, model_of_arrays
from ..visibility import ChiSquare
from .online_guard import OnlineFace, OnlineParams

__all__ = ["face_fields", "face_of_fields"]


def _chi(d: ChiSquare) -> list[float]:
    return [float(d.m1), float(d.m2), int(d.n)]


def face_fields(face: OnlineFace) -> tuple[np.ndarray, dict[str, Any]]:
    """``face`` as (``online``, ``online_values``): (N,) float64, every array of the filter flattened in
    turn, and the plain values naming them (module docstring). :func:`face_of_fields` inverts it bit for bit."""
    parts = model_arrays(face.model)
    flat = [a.ravel() for a in parts.values()]
    m = face.model
    values = {"parts": [[k, [int(v) for v in a.shape]] for k, a in parts.items()],
              "size0": [float(v) for v in face.geom.size0], "centre": [float(v) for v in face.centre],
              "log_s": float(face.log_s), "target": _chi(face.target), "clutter": _chi(face.clutter),
              "learnt": int(face.learnt), "apart": float(face.apart), "colour_mode": m.colour_mode,
              "scale_model": None if m.scale is None else [int(v) for v in m.scale.model]}
    return np.concatenate(flat) if flat else np.zeros(0), values


def _split(flat: np.ndarray, parts: list) -> dict[str, np.ndarray]:
    """The float64 arrays of ``flat`` (N,) by the ``parts`` [name, shape] of :func:`face_fields` (copies)."""
    out: dict[str, np.ndarray] = {}
    at = 0
    for part in parts:
        if not isinstance(part, (list, tuple)) or len(part) != 2:
            raise ValueError(f"online model: part {part!r} is not [name, shape]")
        name, shape = part
        shape = tuple(int(v) for v in shape)
        n = int(np.prod(shape, dtype=np.int64))
        if at + n > flat.size:
            raise ValueError(f"online model: part {name!r} of shape {shape} runs past the {flat.size} stored values")
        out[str(name)] = np.array(flat[at:at + n], dtype=np.float64).reshape(shape)
        at += n
    if at != flat.size:
        raise ValueError(f"online model: {flat.size - at} stored values left over after its parts")
    return out


def face_of_fields(flat: np.ndarray, values: Mapping[str, Any], p: OnlineParams) -> OnlineFace:
    """The model of :func:`face_fields`' ``flat`` (N,) float64 and ``values`` with the settings ``p`` (its
    window made again from the first box's size). Raises ValueError naming what does not fit."""
    try:
        a = _split(np.asarray(flat, dtype=np.float64).ravel(), list(values["parts"]))
        size0 = (float(values["size0"][0]), float(values["size0"][1]))
        geom = tm.geometry(size0, p.dcf)
        try:
            model = model_of_arrays(a, values["colour_mode"], values["scale_model"], geom)
        except ValueError as e:
            raise ValueError(f"online model: {e}") from None
        t, c = values["target"], values["clutter"]
        return OnlineFace(geom, model, (float(values["centre"][0]), float(values["centre"][1])),
                          float(values["log_s"]), ChiSquare(float(t[0]), float(t[1]), int(t[2])),
                          ChiSquare(float(c[0]), float(c[1]), int(c[2])), int(values["learnt"]), float(values["apart"]))
    except (KeyError, IndexError, TypeError) as e:
        raise ValueError(f"online model: missing or malformed field ({type(e).__name__}: {e})") from None
