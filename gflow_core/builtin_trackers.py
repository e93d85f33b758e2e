"""The specs (:class:`gflow_core.spec.TrackerSpec`) of the trackers gflow ships: dcf (its spec
beside it, :mod:`gflow_core.dcf.spec`, with what the box stages need), appearance (beside it too,
:mod:`gflow_core.appearance.spec`), chamfer, m2 and gflow. Each references the tracker's existing modules; a tracker's modules are imported when it
is used, not when the registry is read.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

from .appearance.spec import SPEC as APPEARANCE
from .contour.params import ChamferParams, M2Params
from .dcf.spec import SPEC as DCF
from .m2.edge_settings import LEARN_EDGES
from .m2.patch_params import PatchParams
from .gflow.params import GFlowParams
from .params import make
from .spec import Loader, TrackerSpec
from .tracker import TrackingFilter

__all__ = ["BUILTIN", "CHAMFER", "M2", "m2_setup", "gflow_setup", "m2_model"]


def _chamfer() -> TrackingFilter[Any, Any, Any, Any]:
    from .contour.protocol import CHAMFER

    return CHAMFER


def _m2() -> TrackingFilter[Any, Any, Any, Any]:
    from .m2.protocol import M2

    return M2


def _gflow() -> TrackingFilter[Any, Any, Any, Any]:
    from .gflow.tracker import TRACKER

    return TRACKER


def m2_model(model: Any, load: Loader) -> tuple[Any, dict[str, Any]]:
    """(the M2 model, its file's meta) of the ``model`` keyword: a file, an ``M2Model``, or the pair
    already loaded."""
    from .m2.model import M2Model

    if isinstance(model, M2Model):
        return model, {}
    if isinstance(model, tuple) and len(model) == 2 and isinstance(model[0], M2Model):
        return model[0], dict(model[1])
    if not model:
        raise ValueError("tracker m2 needs model=MODEL.npz (learn one with `gflow learn m2`)")
    obj, meta, _ = load(str(model))
    if not isinstance(obj, M2Model):
        raise ValueError(f"{model} holds a {type(obj).__name__}, not an M2 model")
    return obj, dict(meta)


def m2_setup(spec: TrackerSpec, keywords: Mapping[str, Any], load: Loader) -> tuple[Any, dict[str, Any]]:
    """The M2 tracker's parameters and resources: ``model`` is a model file of ``gflow learn m2`` or an
    ``M2Model``, and the model's kind settles which filter runs (:mod:`gflow_core.m2.protocol`), as
    ``gflow track --tracker m2`` picks graph ``m2`` or ``m2_patch``.

    * contour exemplars: :class:`~gflow_core.contour.params.M2Params`; the edges are read with the
      settings the model was learned with (its profile and g0, its file's Canny thresholds and blur,
      :func:`~gflow_core.contour.protocol.m2_edge_params`), as ``gflow track`` sets the preprocess stage;
      the keyword ``match_resolution`` (default False) reads them at the model's resolution, as
      ``--set preprocess.match_resolution=true`` does;
    * patch exemplars: :class:`~gflow_core.m2.patch_protocol.PatchParams`, the patch cut as the
      model's training patches were (:func:`~gflow_core.m2.patch_protocol.patch_setup`).
    """
    kw = dict(keywords)
    given = kw.pop("model", None)
    model, meta = m2_model(given, load)
    if model.kind == "patch":
        from .m2.patch_protocol import patch_setup

        return patch_setup(model, meta, kw)
    from .contour.protocol import m2_edge_params

    # match_resolution: an edge setting (the preprocess stage's in a graph), given here among the keywords
    try:
        edges = m2_edge_params(model, meta)
    except ValueError as e:  # the file's metadata: named with the file, as the other errors of a model file are
        raise ValueError(f"{given}: {e}" if isinstance(given, (str, os.PathLike)) else str(e)) from None
    edges = dataclasses.replace(edges, match_resolution=bool(kw.pop("match_resolution", False)))
    return make(M2Params, kw), {"model": model, "edges": edges}


def gflow_setup(spec: TrackerSpec, keywords: Mapping[str, Any], load: Loader) -> tuple[Any, dict[str, Any]]:
    """G-flow's parameters and resources, as ``gflow track --tracker gflow`` makes them: ``model`` is
    ``face`` (the default), ``ellipsoid`` (the generic head with its settings,
    :data:`gflow_core.gflow.ELLIPSOID`), a model file, or a :class:`MorphableModel`."""
    from .gflow import ELLIPSOID, MorphableModel

    kw = dict(keywords)
    model = kw.pop("model", GFlowParams().model)
    resources: dict[str, Any] = {}
    if isinstance(model, MorphableModel):
        resources["model"] = model
        return make(GFlowParams, kw, model="(in memory)"), resources
    if model == "ellipsoid":
        return make(GFlowParams, dict(ELLIPSOID, **kw)), resources
    p = make(GFlowParams, kw, model=str(model))
    if p.model:
        obj, _, ref = load(p.model)
        if not isinstance(obj, MorphableModel):
            raise ValueError(f"{ref} holds a {type(obj).__name__}; tracker gflow needs a morphable model file "
                             f"(kind 'morphable')")
        resources["model"] = obj
        if ref != p.model:
            p = make(GFlowParams, kw, model=ref)
    return p, resources


_ORIGIN = __name__

#: the chamfer tracker (K = 1 exemplar learnt from the first frame; graph ``chamfer``)
CHAMFER = TrackerSpec("chamfer", ChamferParams, _chamfer, graph="chamfer", cli="pipeline.cli.trackers.chamfer",
                      stages={"chamfer.proposal": "stages.particle_proposal", "chamfer.filter": "stages.particle_filter"},
                      origin=_ORIGIN)
#: M2 with a learned model. Its graph's preprocess reads edges with the settings models are learned with by
#: default (gflow track and the Python API read a model's own from its file); a patch model's parameters are
#: PatchParams (graph m2_patch)
M2 = TrackerSpec("m2", M2Params, _m2, setup=m2_setup, graph="m2", cli="pipeline.cli.trackers.m2",
                 model_option="--model", model_required=True, preprocess=dataclasses.asdict(LEARN_EDGES),
                 variants=(PatchParams,), origin=_ORIGIN,
                 stages={"m2.proposal": "stages.particle_proposal", "m2.filter": "stages.particle_filter",
                         "patch.filter": "stages.patch_filter"})

#: the trackers gflow ships
BUILTIN: tuple[TrackerSpec, ...] = (
    APPEARANCE,
    CHAMFER,
    DCF,
    TrackerSpec("gflow", GFlowParams, _gflow, setup=gflow_setup, graph="gflow", cli="pipeline.cli.trackers.gflow",
                model_option="--model", origin=_ORIGIN,
                stages={"gflow.proposal": "stages.gflow_proposal", "gflow.filter": "stages.gflow_filter"}),
    M2,
)
