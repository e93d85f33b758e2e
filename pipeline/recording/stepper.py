"""Step one stage through a recording frame by frame (``gflow step``).

The stage is rebuilt with its recorded configuration and fed its recorded inputs; after
each step the stepper shows the inputs the stage joined, the outputs it produced and its
``summary()``. Jumping to a frame restores the nearest snapshot before it when the
recording has one, and otherwise replays from the start (quickly: nothing is printed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gflow_msgs.messages import Snapshot, decode

from pipeline.runtime.build import make_stage
from pipeline.runtime.graph import GraphError
from pipeline.runtime.stage_host import StageHost
from pipeline.recording.plain import describe
from pipeline.io.mcap_io import Record, iter_records
from pipeline.recording.rerun import recorded_plan, stage_frames

__all__ = ["Stepper", "StepView"]


@dataclass
class StepView:
    seq: int
    inputs: dict[str, str]
    outputs: list[tuple[str, str]]
    summary: dict[str, Any]
    errors: list[str] = field(default_factory=list)


class Stepper:
    def __init__(self, path: str | Path, stage: str) -> None:
        self.path = str(path)
        self.plan = recorded_plan(path)
        if stage not in self.plan.stages:
            raise GraphError(f"the recording has no stage {stage!r} (stages: {', '.join(self.plan.stages)})")
        self.name = stage
        self.sp = self.plan.stages[stage]
        if self.sp.kind == "recorder" or self.sp.is_source():
            raise GraphError(f"stage {stage!r} has no recorded inputs to step through")
        wanted = set(self.sp.inputs.values())
        self.records: list[Record] = [r for r in iter_records(path) if r.topic in wanted]
        snap_topic = self.plan.snapshot_topic(stage)
        self.snapshots: dict[int, bytes] = {}
        for r in iter_records(path, topics=[snap_topic]):
            m = decode(r.data)
            if isinstance(m, Snapshot):
                self.snapshots[m.header.seq] = m.data
        self.reset()

    def reset(self, snapshot_seq: int | None = None) -> None:
        self.outputs: list[tuple[str, int, bytes]] = []
        self.errors: list[str] = []
        self.stage = make_stage(self.plan, self.name)

        def collect(topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
            if topic == self.plan.error_topic:
                self.errors.append(describe(payload))
            else:
                self.outputs.append((topic, seq, payload))

        self.host = StageHost(self.stage, self.sp.inputs, self.sp.outputs, self.plan.error_topic, collect)
        self.pos = 0
        self.last_inputs: dict[str, Any] = {}
        # inputs of the frames a restored snapshot holds (after the port's offset) are not fed
        # again (the stage consumed them before the snapshot: fed, each would be an old_seq rejection)
        self.skip_to = snapshot_seq if snapshot_seq is not None else -1
        if snapshot_seq is not None:
            self.stage.restore(self.snapshots[snapshot_seq])
            self.host.join.done_below = snapshot_seq
        # remember what each step joined, to show it
        orig = self.stage.step

        def spy(seq, inputs):
            self.last_inputs = dict(inputs)
            self.last_seq = seq
            return orig(seq, inputs)

        setattr(self.stage, "step", spy)  # over the method, on this stepper's stage only
        self.last_seq = snapshot_seq if snapshot_seq is not None else -1

    @property
    def done(self) -> bool:
        return self.pos >= len(self.records) or self.host.closed

    def next(self) -> StepView | None:
        """Feed inputs until the stage completes one step; None at the end of the recording."""
        before = self.host.stats.steps
        n_out, n_err = len(self.outputs), len(self.errors)
        while self.host.stats.steps == before and self.pos < len(self.records):
            r = self.records[self.pos]
            self.pos += 1
            if self.skip_to < 0 or r.type == "EndOfStream" or self.host.frame_of(r.topic, r.seq) > self.skip_to:
                self.host.deliver(r.topic, r.data)
        if self.host.stats.steps == before:
            return None
        ins = {p: ("(missing)" if m is None else describe(_encode(m))) for p, m in self.last_inputs.items()}
        outs = [(t.rsplit("/", 1)[-1], describe(d)) for t, _, d in self.outputs[n_out:]]
        return StepView(self.last_seq, ins, outs, self.stage.summary(), self.errors[n_err:])

    def jump(self, seq: int) -> str:
        """Position the stage so that the next step is frame ``seq`` (or the first one after it).

        A frame outside the recorded inputs' range is a ValueError naming the range."""
        frames = stage_frames(self.plan, self.name, self.records)  # not a frame its inputs run ahead to
        if not frames or not frames[0] <= seq <= frames[-1]:
            held = f"frames {frames[0]}..{frames[-1]}" if frames else "no frame"
            raise ValueError(f"no frame {seq} to jump to: {self.path} holds {held} for stage {self.name}")
        usable = [s for s in self.snapshots if s < seq]
        how = "from the start"
        if usable:
            self.reset(max(usable))
            how = f"from the snapshot at frame {max(usable)}"
        elif self.last_seq >= seq or seq <= 0:
            self.reset()
        else:
            how = f"from frame {self.last_seq + 1}"
        while not self.done and self.last_seq < seq - 1:
            if self.next() is None:
                break
        return how


def _encode(msg) -> bytes:
    from gflow_msgs.messages import encode

    return encode(msg)
