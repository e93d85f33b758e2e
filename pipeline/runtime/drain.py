"""Nothing lost at the end: a stage that has finished keeps its zenoh session open until what
it sent has arrived.

A stage's last messages (its last outputs and the end of stream on each output) may still sit
in zenoh's queues, or be retransmitted on a lossy link, when the stage finishes; closing the
session then loses them (seen with 1% packet loss: the last 7-15 frames and the end of stream
never reached the other hosts). So before it exits, a finished stage waits until

* every stage that consumes one of its outputs has finished too (heartbeat state ``draining``,
  ``done`` or ``stopped``: it has seen the end of its inputs) or is gone (liveliness token), and
* the recorder, when it keeps one of its outputs, has recorded the end of stream of each kept
  output (its heartbeat's ``ended`` topics) or is gone. This holds for drop topics too: their
  end of stream is sent with BLOCK behind the data (:mod:`pipeline.runtime.transport`), so once
  it is recorded, whatever of the data zenoh did not drop under load is recorded as well,

for at most ``GFLOW_DRAIN_S`` seconds (default 30).
"""

from __future__ import annotations

from pipeline.runtime.graph import Plan, recorded_topic_filter

__all__ = ["FINISHED", "consumers_of", "recorder_needs"]

#: heartbeat states of a stage that needs no more input
FINISHED = ("draining", "done", "stopped")


def consumers_of(plan: Plan, name: str) -> set[str]:
    """The stages (not the recorder) with an input fed by one of ``name``'s outputs."""
    outs = set(plan.stages[name].outputs.values())
    return {n for n, s in plan.stages.items()
            if n != name and s.kind != "recorder" and outs & set(s.inputs.values())}


def recorder_needs(plan: Plan, eos_topics: list[str]) -> tuple[str | None, set[str]]:
    """(the recorder's name, which of ``eos_topics`` it keeps): the ends of stream it must record
    before the stage that sends them may exit (drop topics included: their end of stream is
    never dropped)."""
    rec = plan.recorder()
    if rec is None:
        return None, set()
    keep = recorded_topic_filter(rec.params, plan.stream)
    return rec.name, {t for t in eos_topics if keep(t)}
