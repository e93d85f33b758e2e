"""Re-execute stages from a recording, bit for bit (``gflow rerun``).

A stage's outputs depend only on its configuration, its seed and the ordered inputs it
consumed. The recording holds all three: the resolved plan as metadata, and every input
payload as it travelled. So one stage can be fed its recorded inputs in the recorded
order and its new outputs compared with the recorded ones byte for byte, or, with new
parameters, written to a new recording to diff against the old one.

Inputs given up as late: a live stage that waited ``late_s`` for a frame's input while the
stream went on stepped that frame without it (and dropped the input when it came). Its
``late_input`` report names the topics it gave up (``ErrorReport.topic``); the re-run skips
those inputs of that frame and steps it as soon as it waits for nothing else, so a run that
gave inputs up re-runs bit for bit too. (Recordings made before reports named their topics
re-run with every input.)

Seeking: a stage with ``snapshot_every: N`` publishes its state every N frames on
``gflow/<stream>/_snapshot/<stage>``. ``--from SEQ`` restores the nearest snapshot before
SEQ and feeds only the inputs after it; the outputs must equal those of a full re-run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from gflow_msgs.messages import EndOfStream, ErrorReport, MessageError, Snapshot, decode
from stages.registry import STAGES

from pipeline.runtime.build import make_stage
from pipeline.recording.compare import FieldDiff, first_field_diff
from pipeline.runtime.graph import GraphError, Plan, validate_params
from pipeline.runtime.run_metadata import CONFIG, GRAPH, run_metadata
from pipeline.runtime.live_plan import recorded_source
from pipeline.runtime.stage_host import StageHost
from pipeline.io.mcap_io import Record, iter_records, read_metadata
from pipeline.io.recorder import McapRecorder, peek_type
from pipeline.io.frame_readers import open_reader

__all__ = ["recorded_plan", "rerun_stage", "rerun_graph", "check_outputs", "stage_frames", "RerunResult", "Mismatch"]


@dataclass(frozen=True)
class Mismatch:
    """The first place where a re-run and the recording disagree."""

    topic: str
    seq: int
    kind: str  # "differs", "missing" (recorded, not re-made), "extra" (re-made, not recorded)
    field: FieldDiff | None = None

    def describe(self) -> str:
        where = f"{self.topic} seq {self.seq}"
        if self.kind == "differs" and self.field is not None:
            return f"{where}: field {self.field.path} differs: {self.field.detail}"
        if self.kind == "missing":
            return f"{where}: recorded, but the re-run did not produce it"
        return f"{where}: produced by the re-run, but not in the recording"


@dataclass
class RerunResult:
    stage: str
    outputs: list[tuple[str, int, bytes]]
    start_after: int
    seconds: float
    steps: int
    inputs: list[Record] = field(default_factory=list)
    restored_from: int | None = None
    note: str = ""


def recorded_plan(path: str | Path) -> Plan:
    """The plan (graph, parameters, wiring) a recording was made with."""
    md = read_metadata(path)
    if CONFIG not in md:
        from pipeline.io.mcap_io import damage_cause, torn_cause

        torn = torn_cause(path)  # cut before its metadata: gflow's, but torn, which "not written by gflow" hides
        if not torn:  # or damaged where its metadata is: the first record read says so (without a warning line)
            next(iter_records(path, on_truncated=lambda _text: None), None)
        damage = "" if torn else damage_cause(path)
        raise GraphError(f"{path} holds no gflow.config metadata: {torn}" if torn else
                         f"no gflow.config metadata can be read: {damage}" if damage else
                         f"{path} has no gflow.config metadata: it was not written by gflow's recorder")
    return Plan.from_metadata(md.get(GRAPH, {}), md[CONFIG])


def apply_sets(plan: Plan, stage: str, sets: dict[str, object]) -> None:
    """Override parameters of one stage, validated like a graph file. A parameter of the plan's
    tracker block (``tracker.PARAM`` or the bare name) changes the block, which every stage of the
    tracker takes; in a plan recorded before the block (each stage of the tracker holds its own copy
    of the values), ``tracker`` sets every stage's copy, as a graph without a block does."""
    from pipeline.runtime.tracker_block import TRACKER_KEY, own_fields, stage_tracker

    where = f"--set for stage {stage!r}"
    if stage == TRACKER_KEY:
        where = " ".join(f"--set tracker.{k}={v}" for k, v in sets.items()) or "--set tracker.NAME"
        if plan.tracker is None:
            copies = [n for n, s in plan.stages.items() if s.kind in STAGES and stage_tracker(STAGES[s.kind].Params)]
            if not copies:
                raise GraphError("--set tracker.NAME: the recording runs no stage of a tracker")
            for name in copies:
                apply_sets(plan, name, sets)
            return
        stage = next((n for n, s in plan.stages.items() if plan.stage_params(n) is not s.params), "")
        if not stage:
            raise GraphError("--set tracker.NAME: the recording runs no stage of its tracker")
    sp = plan.stages[stage]
    params = validate_params(sp.kind, {**plan.stage_params(stage), **sets}, where)
    cls = stage_tracker(STAGES[sp.kind].Params) if sp.kind in STAGES else None
    if plan.tracker is not None and cls is not None:
        plan.tracker.params = {k: params[k] for k in plan.tracker.params}
        params = own_fields(params, cls)
    sp.params = params


def late_give_ups(path: str | Path, error_topic: str, stage: str) -> dict[int, frozenset[str]]:
    """{frame: the input topics ``stage`` gave up for it as late} from its ``late_input`` reports."""
    out: dict[int, frozenset[str]] = {}
    for r in iter_records(path, topics=[error_topic]):
        try:
            m = decode(r.data)
        except (MessageError, ValueError):
            continue
        if isinstance(m, ErrorReport) and m.stage == stage and m.kind == "late_input" and m.topic:
            out[m.header.seq] = out.get(m.header.seq, frozenset()) | frozenset(m.topic.split(","))
    return out


def _replay_give_ups(host: StageHost, late: dict[int, frozenset[str]]) -> None:
    """Step a frame the live stage stepped without inputs it gave up, once it waits for nothing else."""
    j = host.join
    while (w := j.waiting(host.stage.required)) is not None and w[1] and w[0] in late and w[0] > j.force_below:
        if not {host.topics_in[p] for p in w[1]} <= late[w[0]]:
            return
        host.give_up(w[0])


def _snapshot_before(path: str | Path, topic: str, seq: int) -> Snapshot | None:
    best = None
    for r in iter_records(path, topics=[topic]):
        if r.seq < seq:
            m = decode(r.data)
            if isinstance(m, Snapshot) and (best is None or m.header.seq > best.header.seq):
                best = m
    return best


def rerun_stage(path: str | Path, stage: str, sets: dict[str, object] | None = None, from_seq: int | None = None,
                progress: Callable[[int], None] | None = None) -> RerunResult:
    """Feed one stage the inputs it consumed in the recording and collect its outputs.

    Parameters
    ----------
    path : the recording.
    stage : stage name in the recorded graph.
    sets : parameter overrides (none: the recorded configuration and seed).
    from_seq : start from the nearest snapshot before this frame.
    """
    plan = recorded_plan(path)
    if stage not in plan.stages:
        raise GraphError(f"the recording has no stage {stage!r} (stages: {', '.join(plan.stages)})")
    sp = plan.stages[stage]
    if sp.kind == "recorder":
        raise GraphError("the recorder has no outputs to re-run")
    if sets:
        apply_sets(plan, stage, sets)
    outputs: list[tuple[str, int, bytes]] = []
    snap_topic = plan.snapshot_topic(stage)

    def collect(topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        outputs.append((topic, seq, payload))

    st = make_stage(plan, stage)
    host = StageHost(st, sp.inputs, sp.outputs, plan.error_topic, collect, sp.snapshot_every, snap_topic)
    start_after = -1
    restored = None
    note = ""
    if from_seq is not None and from_seq > 0:
        probe = st.snapshot()
        if probe is None and not hasattr(st, "emit"):
            start_after = from_seq - 1  # a stateless stage can start anywhere
        else:
            snap = _snapshot_before(path, snap_topic, from_seq)
            if snap is None:
                note = f"no snapshot of {stage} before frame {from_seq}; re-running from the start"
            else:
                st.restore(snap.data)
                start_after = restored = snap.header.seq
        host.join.done_below = start_after
    t0 = time.perf_counter()
    consumed: list[Record] = []
    if sp.is_source():
        from stages.source import SourceParams, SourceStage
        import msgspec

        assert isinstance(st, SourceStage)  # the one stage class of kind "source"

        params = msgspec.convert(sp.params, SourceParams)
        if params.kind == "live":  # the stream is gone: its frames are in the recording
            params = msgspec.convert(recorded_source(sp.params, str(Path(path).resolve())), SourceParams)
        for raw in open_reader(params, plan.base_dir):
            if raw.index <= start_after:
                continue
            host._emit(st.emit(raw))
            host._flush_reports()
            host.stats.steps += 1
        host.close("end")
    else:
        wanted = set(sp.inputs.values())
        late = late_give_ups(path, plan.error_topic, stage)
        for r in iter_records(path):
            if r.topic in wanted:
                if r.topic in late.get(r.seq, ()) and r.type != "EndOfStream":
                    continue  # the live stage gave it up as late (it came after its frame was stepped)
                consumed.append(r)
                if restored is not None and r.type != "EndOfStream" and host.frame_of(r.topic, r.seq) <= restored:
                    continue  # consumed before the snapshot (as the stage's own port offset puts it)
                host.deliver(r.topic, r.data)
                if late:
                    _replay_give_ups(host, late)
                if progress is not None:
                    progress(host.stats.steps)
        host.close("end")
    return RerunResult(stage=stage, outputs=outputs, start_after=start_after, seconds=time.perf_counter() - t0,
                       steps=host.stats.steps, inputs=consumed, restored_from=restored, note=note)


def stage_frames(plan: Plan, stage: str, records: Iterable[Record]) -> list[int]:
    """The frames a recording holds for ``stage`` to step, ascending, from its ``records`` (any of its topics):
    the frames the messages of its driver ports join (after each port's ``input_offsets``; ends of stream and
    error reports left out). Every input counted alike gave one frame more than the recording holds: a
    proposal stage sends the proposals of frame t + 1 once frame t is tracked, so its last ones are for a frame
    never recorded. A stage without inputs (a source): the frames of its outputs."""
    sp = plan.stages[stage]
    cls = STAGES[sp.kind]
    drivers = frozenset(sp.inputs) if cls.drivers is None else cls.drivers
    offsets = {t: cls.input_offsets.get(p, 0) for p, t in sp.inputs.items() if p in drivers} or \
        {t: cls.input_offsets.get(p, 0) for p, t in sp.inputs.items()} or dict.fromkeys(sp.outputs.values(), 0)
    return sorted({r.seq + offsets[r.topic] for r in records
                   if r.topic in offsets and r.type not in ("EndOfStream", "ErrorReport")})


def recorded_outputs(path: str | Path, topics: set[str], start_after: int = -1) -> list[tuple[str, int, bytes]]:
    return [(r.topic, r.seq, r.data) for r in iter_records(path, topics=sorted(topics))
            if r.seq > start_after and r.type != "ErrorReport"]


def _eos(data: bytes) -> EndOfStream | None:
    if peek_type(data) != "EndOfStream":
        return None
    try:
        m = decode(data)
    except MessageError:
        return None
    return m if isinstance(m, EndOfStream) else None


def recording_ends(recorded: list[tuple[str, int, bytes]]) -> dict[str, int]:
    """The last frame each output topic has in the recording, for a recording that ends early
    (interrupted, or torn by a killed recorder): {topic: last seq}. Empty when the outputs ran to
    a normal end of stream."""
    last: dict[str, int] = {}
    reasons: set[str] = set()
    for topic, seq, data in recorded:
        eos = _eos(data)
        if eos is not None:
            reasons.add(eos.reason)
            continue
        last[topic] = max(last.get(topic, -1), seq)
    if reasons == {"end"}:  # the stage's outputs ran to their end (topics with no end of stream, like snapshots, too)
        return {}
    return last


def check_outputs(recorded: list[tuple[str, int, bytes]], rerun: list[tuple[str, int, bytes]],
                  start_after: int = -1) -> list[Mismatch]:
    """Compare outputs per (topic, seq, occurrence). Returns mismatches in recorded order.

    Only the frames the recording has are compared: where it ends early (an interrupted run, a
    torn file), what the re-run produced after its last frame is not a difference, and nor is
    the end of stream (whose reason and position record when the run was stopped)."""
    ends = recording_ends(recorded)

    def keep(topic: str, seq: int, data: bytes) -> bool:
        if topic in ends and (seq > ends[topic] or _eos(data) is not None):
            return False
        return True

    recorded = [r for r in recorded if keep(*r)]
    rerun = [r for r in rerun if keep(*r)]

    def index(items: list[tuple[str, int, bytes]]
              ) -> tuple[dict[tuple[str, int, int], bytes], list[tuple[str, int, int]]]:
        out: dict[tuple[str, int, int], bytes] = {}
        order: list[tuple[str, int, int]] = []
        count: dict[tuple[str, int], int] = {}
        for topic, seq, data in items:
            if seq <= start_after:
                continue
            k = (topic, seq)
            n = count.get(k, 0)
            count[k] = n + 1
            out[(topic, seq, n)] = data
            order.append((topic, seq, n))
        return out, order

    rec, rec_order = index(recorded)
    new, new_order = index(rerun)
    bad: list[Mismatch] = []
    for key in rec_order:
        if key not in new:
            bad.append(Mismatch(key[0], key[1], "missing"))
        elif new[key] != rec[key]:
            bad.append(Mismatch(key[0], key[1], "differs", first_field_diff(rec[key], new[key])))
    for key in new_order:
        if key not in rec:
            bad.append(Mismatch(key[0], key[1], "extra"))
    return bad


def ends_note(recorded: list[tuple[str, int, bytes]]) -> str:
    """'' for a recording that ran to its end, else where it ends (for the check's report)."""
    ends = recording_ends(recorded)
    if not ends:
        return ""
    return ("the recording ends early (interrupted or torn): compared up to frame "
            + ", ".join(f"{s} on {t.split('/', 2)[-1]}" for t, s in sorted(ends.items())))


def write_rerun(path_in: str | Path, path_out: str | Path, plan: Plan, result: RerunResult, sets: dict) -> None:
    """A new recording with the stage's inputs (as recorded) and its new outputs, for `gflow diff`."""
    md = read_metadata(path_in)
    # the versions are this process's, which computed the new outputs
    meta = run_metadata(plan, md.get(GRAPH, {}), **{"gflow.rerun": {
        "from": str(path_in), "stage": result.stage, "set": ", ".join(f"{k}={v}" for k, v in sets.items())}})
    now = time.time_ns()
    with McapRecorder(path_out, metadata=meta) as rec:
        for r in result.inputs:
            rec.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, log_ns=r.log_ns)
        for i, (topic, seq, data) in enumerate(result.outputs):
            rec.write(topic, data, seq, log_ns=now + i)


def rerun_graph(path: str | Path, out: str | Path, sets: dict[str, dict] | None = None):
    """Re-run every stage inline from the recorded source frames; returns (plan, InlineResult)."""
    from pipeline.runtime.inline import run_inline

    plan = recorded_plan(path)
    for stage, kv in (sets or {}).items():
        if stage not in plan.stages and stage != "tracker":
            raise GraphError(f"--set names stage {stage!r}, which the recording does not have")
        apply_sets(plan, stage, kv)
    src = next(s for s in plan.stages.values() if s.is_source())
    src.params = validate_params("source", recorded_source(src.params, str(Path(path).resolve())), "recorded source")
    md = run_metadata(plan, read_metadata(path).get(GRAPH, {}))
    return plan, run_inline(plan, recording=str(out), metadata=md)
