"""The stage registry (stages/registry.py): its table of generic stage modules and the modules the
trackers' specs name (``TrackerSpec.stages``) together name every stage class the ``stages`` package
defines, and every registered tracker's kinds resolve to its stages."""

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
                assert cls.kind not in found, f"kind {cls.kind!r} in {found.get(cls.kind)} and {mod.__name__}"
                found[cls.kind] = mod.__name__
    return found


def test_the_table_and_the_specs_name_every_stage_module_and_nothing_else():
    named = dict(MODULES)
    for spec in trackers().values():
        assert not set(spec.stages) & set(named), f"tracker {spec.name} names a kind named elsewhere"
        named.update(spec.stages)
    assert _declared() == named
    assert set(MODULES) == {"source", "preprocess", "render", "particle.proposal", "particle.filter"}


def test_every_registered_tracker_has_its_two_stages():
    for spec in trackers().values():
        for kind in (spec.proposal_kind, spec.filter_kind):
            assert kind in STAGES, f"tracker {spec.name}: no stage of kind {kind}"
            cls = get_stage_class(kind)
            assert cls.kind == kind and get_stage_class(kind) is cls
    # a tracker with box stages and no module of its own: the generic stages made from its spec
    for kind in ("dcf.filter", "appearance.filter", "appearance.proposal"):
        assert get_stage_class(kind).__module__ == "stages.spec_box"


def test_a_spec_names_a_stage_module_of_its_own(tmp_path, monkeypatch):
    """A tracker of another package may name the module of its own stage class: the registry imports
    it when the kind is asked for, and a module without that kind's class is said in one line."""
    import pytest

    from gflow_core import registry
    from gflow_core.builtin_trackers import CHAMFER
    from gflow_core.spec import SpecError, TrackerSpec

    (tmp_path / "own_stages.py").write_text(
        "from stages.particle_filter import ChamferFilterStage\n\n"
        "class OwnFilterStage(ChamferFilterStage):\n    kind = 'own.filter'\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    own = TrackerSpec("own", CHAMFER.params, CHAMFER.tracker, graph="chamfer",
                      stages={"own.filter": "own_stages", "own.proposal": "stages.particle_proposal"})
    monkeypatch.setattr(registry, "trackers", lambda: {"own": own})
    fresh = type(STAGES)()
    assert "own.filter" in fresh and "dcf.filter" not in fresh
    assert fresh["own.filter"].__name__ == "OwnFilterStage"
    with pytest.raises(RuntimeError, match="own.proposal.*stages.particle_proposal defines no stage class"):
        fresh["own.proposal"]
    with pytest.raises(SpecError, match="tracker bad: stages must map stage kinds to dotted module names"):
        TrackerSpec("bad", CHAMFER.params, CHAMFER.tracker, graph="chamfer", stages={"bad.filter": "no such"})
