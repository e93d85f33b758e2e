"""What a graph with a live source needs before it runs.

* **Timed proposals.** A proposal stage that draws the particles of frame t + 1 from the
  posterior of frame t must know when frame t + 1 was taken to scale its motion noise
  (a live source skips frames). Stages whose parameters have ``timed`` (``particle.proposal``)
  are switched to it and fed the source's frames too; they join frame t + 1 with the posterior
  of t (``input_offsets``). File sources keep the graph as it is, so their runs keep their bits.
* **Skipped frames in the recording.** With ``skipped`` among the recorder's topics
  (``--record-topics '*,skipped'``), the source sends the frames it skips on that topic.
"""

from __future__ import annotations

import msgspec

from stages.registry import get_stage_class
from stages.source import SourceParams

from pipeline.runtime.graph import RECORDER_KIND, Plan
from pipeline.runtime.transport import topic_key

__all__ = ["prepare_live", "live_source", "recorded_source", "listen_early", "SKIPPED_TOPIC"]

#: the topic name (after gflow/STREAM/) of the frames a live source skips
SKIPPED_TOPIC = "skipped"


def live_source(plan: Plan) -> SourceParams | None:
    """The parameters of the plan's source when its frames carry host capture stamps, else None."""
    src = next((s for s in plan.stages.values() if s.is_source()), None)
    if src is None:
        return None
    p = msgspec.convert(src.params, SourceParams)
    return p if p.host_clock else None


def prepare_live(plan: Plan) -> Plan:
    """Wire timed proposals and the skipped-frames topic for a live source (see the module
    docstring); a plan without one is returned unchanged."""
    if live_source(plan) is None:
        return plan
    src = next(s for s in plan.stages.values() if s.is_source())
    frames = src.outputs["frames"]
    for sp in plan.stages.values():
        if sp.kind == RECORDER_KIND or sp.is_source():
            continue
        fields = {f.name for f in msgspec.structs.fields(get_stage_class(sp.kind).Params)}
        if "timed" in fields and "frames" not in sp.inputs:
            sp.params["timed"] = True
            sp.inputs["frames"] = frames
    rec = plan.recorder()
    if rec is not None and SKIPPED_TOPIC in (rec.params.get("topics") or ()):
        src.params["keep_skipped"] = True
        src.outputs.setdefault(SKIPPED_TOPIC, topic_key(plan.stream, SKIPPED_TOPIC))
    return plan


def listen_early(plan: Plan, local: set[str] | None = None, say=None) -> list:
    """Bind a UDP source's port now, before any stage starts, and have the source read it through
    the relay (:mod:`pipeline.io.udp_relay`): a sender that starts first loses nothing, and the
    first frame the tracker gets, the one ``--init`` describes, is the first one sent. Only a
    source that runs here (``local``: the stages this process starts; None: all). ``say(line)``
    is told that the port is bound and, later, when the first data came. Returns the relays, to
    close after the run; a port that cannot be bound is left to the source (which says why)."""
    from pipeline.io.udp_relay import relay_for, relayed_udp

    p = live_source(plan)
    src = next((n for n, s in plan.stages.items() if s.is_source()), None)
    if p is None or p.kind != "live" or src is None or (local is not None and src not in local):
        return []
    if relayed_udp(p.path) is None:
        return []
    try:
        relay = relay_for(p.path)
    except OSError:
        return []
    plan.stages[src].params["relay"] = relay.relay_url
    if say is not None:
        say(f"listening on {p.path}: bound before the pipeline starts, so what is sent from now on is kept")
    relay.tell_first(say)
    return [relay]


def recorded_source(params: dict, path: str) -> dict:
    """Source parameters that read a recording's frames instead of the source it was made from
    (``gflow rerun``). The frames of a live source keep their recorded host stamps and what the
    source said about each (``clock: host``), so the stages see exactly what they saw."""
    p = msgspec.convert(params, SourceParams)
    out = dict(params, kind="mcap", path=path, realtime=False)
    if p.host_clock:
        out.update(clock="host", start=0)
    return out
