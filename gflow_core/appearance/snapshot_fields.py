"""The appearance tracker's state (:class:`.filter.AppearanceState`) as the flat fields of its filter
stage's snapshot (version 4, ``gflow_msgs.snapshots.AppearanceFilterSnapshot``): the exemplars, the
particles and the colour histograms as arrays, the rest as numbers and tuples; and back.

The names are the snapshot's: a field is never renamed (recordings hold them).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..visibility import ChiSquare
from .filter import AppearanceState

__all__ = ["fields_of", "state_of"]


def _moments(c: ChiSquare) -> tuple[float, float, int]:
    return (c.m1, c.m2, c.n)


def fields_of(st: AppearanceState) -> dict[str, Any]:
    """The snapshot fields of a state: anchor, recent, slow (th, tw, 4) float32, particles (N, 3)
    float64, colour0 and colour (N_BINS,) float64 or None as arrays; size0, res, centre, log_s,
    velocity, hidden_run, back and the moments (m1, m2, n) of target, clutter, ctarget, cclutter."""
    return dict(
        size0=(float(st.size0[0]), float(st.size0[1])), res=(int(st.res[0]), int(st.res[1])), anchor=st.anchor,
        recent=st.recent, slow=st.slow, particles=st.particles, centre=(float(st.centre[0]), float(st.centre[1])),
        log_s=float(st.log_s), velocity=(float(st.velocity[0]), float(st.velocity[1])),
        target=_moments(st.target), clutter=_moments(st.clutter), hidden_run=int(st.hidden_run), back=float(st.back),
        colour0=st.colour0, colour=st.colour, ctarget=_moments(st.ctarget), cclutter=_moments(st.cclutter))


def _copy(fields: Mapping[str, Any], name: str) -> np.ndarray:
    """A writable copy of the array ``name`` (the tracker updates its exemplars in place)."""
    a = fields[name]
    if a is None:
        raise ValueError(f"the snapshot has no {name}")
    return np.array(a)


def state_of(fields: Mapping[str, Any]) -> AppearanceState:
    """The state of :func:`fields_of`'s fields (arrays as ndarrays). ``ValueError`` or ``KeyError``
    for a field missing."""
    colour0, colour = fields["colour0"], fields["colour"]
    return AppearanceState(
        size0=np.array(fields["size0"]), res=(fields["res"][0], fields["res"][1]), anchor=_copy(fields, "anchor"),
        recent=_copy(fields, "recent"), particles=_copy(fields, "particles"), centre=np.array(fields["centre"]),
        log_s=fields["log_s"], velocity=np.array(fields["velocity"]), slow=_copy(fields, "slow"),
        target=ChiSquare(*fields["target"]), clutter=ChiSquare(*fields["clutter"]), hidden_run=fields["hidden_run"],
        back=fields["back"], colour0=None if colour0 is None else np.array(colour0),
        colour=None if colour is None else np.array(colour), ctarget=ChiSquare(*fields["ctarget"]),
        cclutter=ChiSquare(*fields["cclutter"]))
