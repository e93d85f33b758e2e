"""A stage that breaks its contract with the runner fails when a runner takes it, not on its
first message: ``prepare_ports`` without ``prepare()``."""

from __future__ import annotations

import pytest

from stages.base import Params, Stage, StageContext
from gflow_msgs.messages import Frame

from pipeline.runtime.stage_host import StageHost


class _NoPrepare(Stage[Params]):
    kind = "test.no_prepare"
    Params = Params
    inputs = {"frames": Frame}
    outputs = {"frames": Frame}

    def step(self, seq, inputs):
        return [("frames", self.prepared("frames", inputs["frames"]))]


class _Prepares(_NoPrepare):
    def prepare(self, port, msg):
        return msg


def _host(stage: Stage) -> StageHost:
    return StageHost(stage, {"frames": "gflow/t/frames"}, {"frames": "gflow/t/out"}, "gflow/t/errors",
                     lambda *a: None)


def test_prepare_ports_without_prepare_is_refused_when_the_runner_takes_the_stage():
    bad = _NoPrepare(Params(), StageContext("s", "t"))
    bad.prepare_ports = frozenset({"frames"})
    with pytest.raises(TypeError, match=r"lists prepare_ports \['frames'\] but does not implement prepare"):
        _host(bad)
    good = _Prepares(Params(), StageContext("s", "t"))
    good.prepare_ports = frozenset({"frames"})
    assert _host(good).ahead
    plain = _NoPrepare(Params(), StageContext("s", "t"))  # no prepare_ports: nothing to implement
    assert not _host(plain).ahead
