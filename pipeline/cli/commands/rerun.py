"""``gflow rerun``: re-execute a stage (or the whole graph) from a recording, and check it."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.cli.commands.common import CliError, whole_number

if TYPE_CHECKING:  # the recording's modules are imported where used: the command's options and --help need none
    from pipeline.runtime.graph import Plan

ORDER = 52


def _stage_sets(items: list[str] | None, stage: str) -> dict[str, object]:
    """{param: value} of ``--set`` for a re-run of ``stage``: ``PARAM=V``, ``STAGE.PARAM=V`` or
    ``tracker.PARAM=V``; a value named for another stage is an error (it would set ``stage``'s)."""
    import yaml

    out: dict[str, object] = {}
    for it in items or []:
        if "=" not in it:
            raise CliError(f"--set expects key=value, got {it!r}")
        k, v = it.split("=", 1)
        owner, _, name = k.rpartition(".")
        if owner not in ("", stage, "tracker"):
            raise CliError(f"--set {k}: --stage {stage} re-runs {stage} alone; set its parameters ({stage}.{name} "
                           f"or {name}), or re-run --stage {owner} or --graph")
        out[name] = yaml.safe_load(v)
    return out


def _refuse_unknown_stages(args: argparse.Namespace, plan: Plan) -> None:
    """A ``--set STAGE.PARAM=V`` of a whole-graph re-run naming a stage the recording does not have, refused naming
    the option and the stages there are (it said "--set names stage 'nosuch', which the recording does not have")."""
    from pipeline.cli.commands.common import sets_as_given

    for how, (stage, _, _) in sets_as_given(args.set).items():
        if stage not in plan.stages and stage != "tracker":
            raise CliError(f"{how}: {args.file} has no stage {stage!r} (its stages: {', '.join(plan.stages)})")


def _versions_note(path: str) -> str:
    """'' when the recording was made with the versions this re-run runs with (or does not say which), else
    which differ and what that means for the check."""
    from pipeline.io.mcap_io import read_metadata
    from pipeline.runtime.run_metadata import VERSIONS, versions_differ

    differ = versions_differ(read_metadata(path).get(VERSIONS))
    if not differ:
        return ""
    return (f"recorded with other versions than these ({', '.join(differ)}): another release or kind of machine "
            "rounds the last bits of floating point otherwise, and the trackers carry those into their outputs, "
            "so a difference need not be a fault")


def _report(mismatches, compared: int, label: str, *notes: str) -> int:
    for note in notes:
        if note:
            print(f"{label}: {note}")
    if not mismatches:
        print(f"{label}: {compared} outputs compared, all identical bit for bit")
        return 0
    first = mismatches[0]
    print(f"{label}: {len(mismatches)} of {compared} outputs differ; first difference at frame {first.seq}:")
    print(f"  {first.describe()}")
    for m in mismatches[1:6]:
        print(f"  then {m.describe()}")
    if len(mismatches) > 6:
        print(f"  ... and {len(mismatches) - 6} more (gflow diff shows them all)")
    return 1


def _cannot_check(path: str, plan, needs: set[str], compares: set[str], what: str, verb: str = "re-run") -> None:
    """A :class:`CliError` saying what cannot be re-run or checked and why: the recording lacks
    topics the re-run is fed (``needs``: it would step nothing) or every topic it is compared with
    (``compares``); ``--record-topics`` chose what was kept. ``verb``: what is done with it (``gflow step``:
    ``step``)."""
    from pipeline.io.mcap_io import recorded_topics, torn_cause

    have = set(recorded_topics(path))
    missing = sorted(needs - have)
    rec = plan.recorder()
    kept = list(rec.params.get("topics") or ["*"]) if rec is not None else ["*"]
    why = f" (it was recorded with --record-topics {','.join(kept)})" if "*" not in kept else ""
    torn = torn_cause(path) if missing else ""
    if torn:  # not what was recorded, but what a torn file lets be read: said as every command says it
        it = "it is" if len(missing) == 1 else "they are"
        raise CliError(f"cannot {verb} {what}: {', '.join(missing)}: {it} not in what can be read of {path}: {torn}")
    if missing:
        it = "it is" if len(missing) == 1 else "they are"
        raise CliError(f"cannot {verb} {what}: {', '.join(missing)}: {it} not in {path}{why}, and a {verb} is fed "
                       f"what was recorded; record every topic (or these too) to {'check' if verb == 're-run' else verb} "
                       f"{what}")
    if compares and not compares & have:
        raise CliError(f"cannot check {what}: none of its outputs ({', '.join(sorted(compares))}) is in {path}{why}, "
                       f"so there is nothing to compare with")


def _chosen(args, outputs: set[str]) -> set[str]:
    """The outputs ``--topics`` names (as typed: estimate, gflow/demo/estimate, patterns), or all."""
    if not args.topics:
        return outputs
    from pipeline.cli.commands.common import chosen_topics

    return set(chosen_topics(args.topics, outputs, where="the re-run's outputs"))


def _check_from(path: str, plan, stage: str, from_seq: int) -> None:
    """Refuse a ``--from`` frame the recording holds nothing of for ``stage`` to step (one line naming the frames
    it holds: :func:`pipeline.recording.rerun.stage_frames`, not a frame its inputs run ahead to)."""
    from pipeline.io.mcap_io import iter_records
    from pipeline.recording.rerun import stage_frames

    sp = plan.stages[stage]
    topics = set(sp.inputs.values()) or set(sp.outputs.values())
    frames = stage_frames(plan, stage, iter_records(path, topics=sorted(topics)))
    if not frames:
        from pipeline.io.mcap_io import torn_cause

        torn = torn_cause(path)
        raise CliError(f"{path} holds no input of the stage to re-run" + (f": {torn}" if torn else ""))
    if not frames[0] <= from_seq <= frames[-1]:
        raise CliError(f"--from {from_seq}: {path} holds frames {frames[0]}..{frames[-1]} for stage {stage}")


def cmd_rerun(args) -> int:
    if not Path(args.file).is_file():  # said before the re-run's imports (the stages, the recording's readers)
        raise CliError(f"{args.file} is a folder, not a recording file (give an .mcap file)" if Path(args.file).is_dir()
                       else f"recording not found: {args.file}")
    from pipeline.recording.rerun import (check_outputs, ends_note, recorded_outputs, recorded_plan, rerun_graph, rerun_stage,
                         write_rerun)

    from pipeline.cli.commands.common import check_outputs as check_output_paths, parse_sets, warn_if_torn

    check_output_paths(out=args.out)
    if args.out:  # a recording never overwrites a file
        from pipeline.io.recording_files import refuse_existing

        refuse_existing(args.out, "--out")
    if args.graph:
        if args.from_seq is not None:
            raise CliError("--from works with --stage (a whole-graph re-run starts at the first frame)")
        sets = parse_sets(args.set)
        plan0 = recorded_plan(args.file)
        _refuse_unknown_stages(args, plan0)
        _cannot_check(args.file, plan0, {t for s in plan0.stages.values() if s.is_source() for t in s.outputs.values()},
                      set(), "the graph")
        # before the re-run: a name that fits no output is the first thing to say (not after a recording is written)
        topics = _chosen(args, {t for s in plan0.stages.values() for t in s.outputs.values()})
        warn_if_torn(args.file)  # re-run only up to where it ends: said before any verdict (a check's error says it)
        from pipeline.io.recording_files import unique_path

        out = args.out or str(unique_path(str(Path(args.file).with_suffix("")) + "-rerun.mcap"))
        t0 = time.perf_counter()
        plan, res = rerun_graph(args.file, out, sets)
        if res.interrupted:  # the frames so far are no re-run to check (every later output was "not produced")
            print(f"gflow rerun: interrupted after {res.frames} frames: nothing compared; the re-run so far: {out}",
                  file=sys.stderr)
            return 130
        print(f"re-ran the whole graph from the recorded frames: {res.frames} frames in {time.perf_counter() - t0:.2f} s; "
              f"new recording: {out}")
        from pipeline.io.mcap_io import iter_records

        new = [(r.topic, r.seq, r.data) for r in iter_records(out, topics=sorted(topics)) if r.type != "ErrorReport"]
        old = recorded_outputs(args.file, topics)
        bad = check_outputs(old, new)
        rc = _report(bad, len(old), "graph", ends_note(old), _versions_note(args.file)) or _damaged(args.file, "graph")
        return rc if args.check else 0
    if not args.stage:
        raise CliError("say which stage to re-run with --stage NAME, or --graph for all of them")
    stage_sets = _stage_sets(args.set, args.stage)
    plan = recorded_plan(args.file)
    if args.stage in plan.stages:  # an unknown stage: rerun_stage names the graph's
        sp = plan.stages[args.stage]
        produced = {t for s in plan.stages.values() for t in s.outputs.values()}
        _cannot_check(args.file, plan, set(sp.inputs.values()) & produced, set(sp.outputs.values()),
                      f"stage {args.stage}")
        topics = set(sp.outputs.values()) | ({plan.snapshot_topic(args.stage)} if sp.snapshot_every else set())
        topics = _chosen(args, topics)  # before the re-run: a name that fits no output is the first thing to say
        if args.from_seq is not None:
            _check_from(args.file, plan, args.stage, args.from_seq)
        warn_if_torn(args.file)  # re-run only up to where it ends: said before any verdict (a check's error says it)
    res = rerun_stage(args.file, args.stage, stage_sets, args.from_seq)
    if not res.inputs and not res.steps and args.from_seq is None:  # "0 of 0 outputs" is no check of it
        from pipeline.io.mcap_io import damage_cause, torn_cause

        why = damage_cause(args.file) or torn_cause(args.file)
        raise CliError(f"{args.file} holds no input of stage {args.stage} to re-run" + (f": {why}" if why else ""))
    if res.note:
        print(f"note: {res.note}", file=sys.stderr)
    fps = res.steps / res.seconds if res.seconds > 0 else float("inf")
    start = f" from the snapshot at frame {res.restored_from}" if res.restored_from is not None else (
        f" from frame {res.start_after + 1}" if res.start_after >= 0 else "")
    print(f"re-ran {args.stage}{start}: {res.steps} steps in {res.seconds:.3f} s ({fps:.1f} steps/s)")
    if args.out:
        if stage_sets:
            from pipeline.recording.rerun import apply_sets

            apply_sets(plan, args.stage, stage_sets)
        write_rerun(args.file, args.out, plan, res, stage_sets)
        print(f"new recording: {args.out} (compare with: gflow diff {args.file} {args.out})")
    old = recorded_outputs(args.file, topics, res.start_after)
    # error reports are diagnostics, left out on both sides: a live stage's report of a frame it
    # stepped without a late input is in the recording, and the re-run makes it again (its text
    # names the live wait in seconds)
    new = [o for o in res.outputs if o[0] != plan.error_topic and o[0] in topics]
    bad = check_outputs(old, new, res.start_after)
    rc = _report(bad, len(old), args.stage, ends_note(old), _versions_note(args.file)) or _damaged(args.file, args.stage)
    return rc if (args.check or not stage_sets) and rc else 0


def _damaged(path: str, label: str) -> int:
    """1 (and the line saying why) when ``path`` was found damaged while re-run and compared: its outputs
    after the damage were neither re-run nor compared, so "all identical" is not a check of the run."""
    from pipeline.io.mcap_io import damage_cause, damage_told

    why = damage_cause(path)
    if not why:
        return 0
    damage_told(why)  # said here: not warned again when the command ends
    print(f"{label}: compared only up to the damage, so not a check of the whole run: {why}")
    return 1


def register(sub) -> None:
    p = sub.add_parser(
        "rerun", help="re-execute a stage (or the graph) from a recording and check it bit for bit",
        description="Feeds one stage the inputs it consumed in the recording, in the recorded order, with its "
                    "recorded configuration and seed, and compares its outputs with the recorded ones. With "
                    "--set, runs with new parameters (write them with --out and compare with gflow diff).",
        epilog="examples:\n  gflow rerun run.mcap --stage filter --check\n"
               "  gflow rerun run.mcap --stage filter --from 60 --check\n"
               "  gflow rerun run.mcap --stage filter --set seed=3 --out seed3.mcap\n"
               "  gflow rerun run.mcap --graph --check",
        formatter_class=__import__("argparse").RawDescriptionHelpFormatter)
    p.add_argument("file", help="MCAP recording made by gflow")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--stage", help="stage to re-run (e.g. filter)")
    g.add_argument("--graph", action="store_true", help="re-run every stage inline from the recorded source frames")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="new parameter (STAGE.KEY=VALUE with --graph), e.g. seed=3")
    p.add_argument("--from", dest="from_seq", type=whole_number, metavar="SEQ",
                   help="start from the nearest snapshot before frame SEQ")
    p.add_argument("--out", metavar="NEW.mcap", help="write the re-run to a new recording")
    p.add_argument("--check", action="store_true", help="exit 1 at any difference from the recorded outputs")
    p.add_argument("--topics", nargs="+", metavar="TOPIC",
                   help="compare only these outputs: the name in the stream (estimate), the full name with or "
                        "without the run id, or a shell pattern")
    p.set_defaults(func=cmd_rerun)
