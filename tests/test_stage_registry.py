"""The stage registry (stages/registry.py): its table of stage modules names every stage class the
``stages`` package defines, and every registered tracker's kinds resolve to its stages."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import stages
from gflow_core.registry import trackers
from stages.base import Stage
from stages.registry import MODULES, STAGES, get_stage_class


def _declared() -> dict[str, str]:
    """{kind: module} of every concrete stage class with a ``kind`` of its own in the package."""
    found: dict[str, str] = {}
    for info in pkgutil.iter_modules(stages.__path__):
        mod = importlib.import_module(f"stages.{info.name}")
        for cls in vars(mod).values():
            if (isinstance(cls, type) and issubclass(cls, Stage) and cls.__module__ == mod.__name__
                    and not inspect.isabstract(cls) and "kind" in cls.__dict__):
                assert cls.kind not in found, f"kind {cls.kind!r} in stages.{found.get(cls.kind)} and {mod.__name__}"
                found[cls.kind] = info.name
    return found


def test_the_table_names_every_stage_module_and_nothing_else():
    assert _declared() == MODULES


def test_every_registered_tracker_has_its_two_stages():
    for spec in trackers().values():
        for kind in (spec.proposal_kind, spec.filter_kind):
            assert kind in STAGES, f"tracker {spec.name}: no stage of kind {kind}"
            cls = get_stage_class(kind)
            assert cls.kind == kind and get_stage_class(kind) is cls
    # a tracker with box stages and no module of its own: the generic stages made from its spec
    assert get_stage_class("dcf.filter").__module__ == "stages.spec_box"
    assert get_stage_class("appearance.filter").__module__ == "stages.appearance_filter"
