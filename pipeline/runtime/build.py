"""Build stage objects from a plan: convert parameters, load resources named in them."""

from __future__ import annotations

from typing import Any

import msgspec

from stages.base import Stage, StageContext
from stages.registry import get_stage_class

from pipeline.runtime.graph import GraphError, Plan, StagePlan

__all__ = ["make_stage", "apply_defaults"]


def load_resources(plan: Plan, sp: StagePlan) -> dict[str, Any]:
    """Files a stage's parameters name (a learned model), loaded here so stages never open files."""
    res: dict[str, Any] = {}
    model = plan.stage_params(sp.name).get("model")  # a stage's own, or its tracker block's (G-flow)
    if model:
        from pipeline.io.modelfile import load_model, model_path  # imported lazily: only trackers with models

        res["model"] = load_model(model_path(model, plan.base_dir))  # a file, or a built-in model's name
    return res


def frame_period_ns(plan: Plan) -> float:
    """The nominal frame period of a source whose frames carry host capture stamps (a live
    source or a recording of one: ``1e9 / fps``), else 0 (media time: see stages/time_step.py)."""
    from stages.source import SourceParams

    src = next((s for s in plan.stages.values() if s.is_source()), None)
    if src is None:
        return 0.0
    p = msgspec.convert(src.params, SourceParams)
    return 1e9 / p.fps if p.host_clock else 0.0


def make_stage(plan: Plan, name: str) -> Stage:
    sp = plan.stages[name]
    cls = get_stage_class(sp.kind)
    params = msgspec.convert(plan.stage_params(name), cls.Params)
    return cls(params, StageContext(name=name, stream=plan.seed_stream, resources=load_resources(plan, sp),
                                    frame_period_ns=frame_period_ns(plan)))


def check_stages(plan: Plan, names) -> None:
    """Build each stage of ``names`` (not the source, not the recorder) once, here, so a stage that
    cannot start (a filter without its initial box, a missing model) is a :class:`GraphError`
    naming it before any process starts or any recording is made. Building a stage is cheap: its
    parameters and resources, no frame."""
    for name in names:
        sp = plan.stages[name]
        if sp.kind == "recorder" or sp.is_source():
            continue
        try:
            make_stage(plan, name)
        except (ValueError, TypeError, KeyError, OSError, msgspec.ValidationError) as e:
            msg = " ".join(str(e).split())
            hint = (f" (on the command line: --set {name}.init=[X,Y,W,H])"
                    if "init:" in msg and "set init" in msg else "")
            raise GraphError(f"stage {name!r} ({sp.kind}) cannot start: {msg}{hint}") from None


def apply_defaults(plan: Plan) -> Plan:
    """Fill what can be known from the graph itself: on a synthetic source, a filter with no
    initial box starts from the scene's ground-truth box at the first frame, and the edge
    thresholds are calibrated on that box."""
    from gflow_core.synthetic import SyntheticScene

    src = next((s for s in plan.stages.values() if s.is_source()), None)
    if src is None or src.params.get("kind") != "synthetic":
        return plan
    p = src.params
    scene = SyntheticScene(width=p["width"], height=p["height"], n_frames=p["frames"], seed=p["scene_seed"],
                           noise=p["noise"])
    box = list(scene.truth_box(p["start"]))
    for s in plan.stages.values():
        if "init" in s.params and s.params.get("init") is None:
            s.params["init"] = box
        if "calibrate_box" in s.params and s.params.get("calibrate_box") is None:
            s.params["calibrate_box"] = box
    return plan
