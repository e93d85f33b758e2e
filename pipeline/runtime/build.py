"""Build stage objects from a plan: convert parameters, load resources named in them."""

from __future__ import annotations

from typing import Any

import msgspec

from stages.base import Stage, StageContext
from stages.registry import get_stage_class

from pipeline.runtime.graph import GraphError, Plan, StagePlan

__all__ = ["make_stage", "apply_defaults", "needs_initial_box", "missing_initial_box"]


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


def needs_initial_box(cls: type[Stage]) -> bool:
    """Whether a stage of class ``cls`` cannot track without its initial box ``init``: a G-flow
    stage (the model is placed in it), a box filter that says so (``needs_init``; a patch model's
    may crop the whole frame) and a box proposal whose random walk is relative to the box's size
    (one that overrides ``_clouds`` draws without it)."""
    import sys

    gflow, box = sys.modules.get("stages.gflow_common"), sys.modules.get("stages.box_tracker")  # loaded with cls
    if gflow is not None and issubclass(cls, gflow.GFlowStage):
        return True
    if box is not None and issubclass(cls, box.BoxFilterStage):
        return bool(getattr(cls, "needs_init"))
    if box is not None and issubclass(cls, box.BoxProposalStage):
        return getattr(cls, "_clouds") is box.BoxProposalStage._clouds
    return False


def missing_initial_box(plan: Plan, names) -> str | None:
    """The one message for stages of ``names`` that need an initial box and have none (None: all
    have theirs), naming every such stage and how to give the box."""
    names = set(names)
    lacking = [n for n in plan.stages if n in names and not (plan.stages[n].kind == "recorder" or plan.stages[n].is_source())
               and plan.stage_params(n).get("init") is None and needs_initial_box(get_stage_class(plan.stages[n].kind))]
    if not lacking:
        return None
    which = " and ".join(f"{n!r} ({plan.stages[n].kind})" for n in lacking)
    sets = " ".join(f"--set {n}.init=[X,Y,W,H]" for n in lacking)
    return (f"stage{'s' if len(lacking) > 1 else ''} {which} need{'' if len(lacking) > 1 else 's'} an initial box: "
            f"set init: [x, y, w, h] in the graph (on the command line: {sets}; gflow track: --init X,Y,W,H)")


def check_stages(plan: Plan, names) -> None:
    """Build each stage of ``names`` (not the source, not the recorder) once, here, so a stage that
    cannot start (a filter without its initial box, a missing model) is a :class:`GraphError`
    naming it before any process starts or any recording is made. Building a stage is cheap: its
    parameters and resources, no frame. Stages without the initial box they need are named
    together first, in one line (:func:`missing_initial_box`)."""
    lacking = missing_initial_box(plan, names)
    if lacking:
        raise GraphError(lacking)
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
