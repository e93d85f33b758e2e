"""Stage values given on the command line checked against a graph's tracker block, in the words
of the options that gave them (``--set tracker.nope=1``, ``--set filter.particles=300``).

A parameter of the graph's tracker is set once, as ``tracker.PARAM``
(:mod:`pipeline.runtime.tracker_block`); naming it for one stage would make the stages disagree,
so it is refused with a line that names ``tracker.PARAM``.
"""

from __future__ import annotations

from typing import Any

from stages.registry import STAGES

from pipeline.runtime.graph import RECORDER_KIND, Plan
from pipeline.runtime.tracker_block import TRACKER_KEY, block_class, block_values, stage_tracker

__all__ = ["check_tracker_values"]


def _is_tracker_stage(plan: Plan, stage: str) -> bool:
    sp = plan.stages.get(stage)
    return sp is not None and sp.kind != RECORDER_KIND and stage_tracker(STAGES[sp.kind].Params) is not None


def check_tracker_values(plan: Plan, given: dict[str, tuple[str, str, Any]], others: dict[str, dict] | None) -> str:
    """Why ``given`` ({how it was given: (stage, parameter, value)}) cannot apply to ``plan``'s tracker
    block, in one line ('' when it can): a stage's value of a tracker parameter, a ``tracker.PARAM``
    the tracker does not have or refuses, or ``tracker.PARAM`` for a graph with no tracker at all."""
    block = plan.tracker
    mine = {how: (param, value) for how, (stage, param, value) in given.items() if stage == TRACKER_KEY}
    if block is None:
        if mine and not any(_is_tracker_stage(plan, s) for s in plan.stages):
            return f"{' '.join(mine)}: the graph {plan.name!r} runs no tracker whose parameters tracker.NAME could set"
        return ""
    for how, (stage, param, value) in given.items():
        if stage != TRACKER_KEY and param in block.params and _is_tracker_stage(plan, stage):
            return (f"{how}: {param} is a parameter of tracker {block.name}, set once for all its stages: "
                    f"--set tracker.{param}=VALUE")
    if not mine:
        return ""
    cls = block_class(block)
    values = {**block.params, **(others or {}).get(TRACKER_KEY, {}), **{p: v for p, v in mine.values()}}
    try:
        block_values(cls, values)
    except ValueError as e:
        alone = [how for how, (p, v) in mine.items() if _refused(cls, {**block.params, p: v})]
        return f"{' '.join(alone or mine)}: {e}"
    return ""


def _refused(cls: type, values: dict[str, Any]) -> bool:
    try:
        block_values(cls, values)
    except ValueError:
        return True
    return False
