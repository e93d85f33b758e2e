"""Stage kinds by name, as graph files refer to them."""

from __future__ import annotations

from .base import Stage
from .particle_filter import FilterStage
from .particle_proposal import ProposalStage
from .preprocess import PreprocessStage
from .source import SourceStage

__all__ = ["STAGES", "get_stage_class"]

STAGES: dict[str, type[Stage]] = {
    cls.kind: cls for cls in (SourceStage, PreprocessStage, ProposalStage, FilterStage)
}


def get_stage_class(kind: str) -> type[Stage]:
    try:
        return STAGES[kind]
    except KeyError:
        raise KeyError(f"unknown stage kind {kind!r}; known kinds: {', '.join(sorted(STAGES))}") from None
