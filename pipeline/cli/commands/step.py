"""``gflow step FILE.mcap --stage NAME``: step a stage through a recording, one frame at a time."""

from __future__ import annotations

import json
import sys

ORDER = 53

HELP = """commands:
  n, <enter>   next frame                 j SEQ   jump to frame SEQ
  s            the stage's state summary  o       the last outputs, in full
  h            this help                  q       quit"""


def _show(view, out, outputs: set[str] | None = None) -> None:
    print(f"--- frame {view.seq} " + "-" * 50, file=out)
    print("inputs:", file=out)
    for p, d in view.inputs.items():
        print(f"  {p:10s} {d}", file=out)
    print("outputs:", file=out)
    for p, d in view.outputs:
        if outputs is None or p in outputs:
            print(f"  {p:10s} {d}", file=out)
    for e in view.errors:
        print(f"  error    {e}", file=out)
    print("state:   " + json.dumps(view.summary, default=str), file=out)


def _stepper(args):
    """The :class:`~pipeline.recording.stepper.Stepper` of ``args.stage`` through ``args.file``, refused when the
    recording holds none of the stage's inputs (a torn file says where it ends, so the cut is not taken for what
    the run recorded) or lacks one of their topics (``--record-topics``, a Foxglove copy: every frame would join
    nothing, and stepping said "end of the recording" at the first step, exit 0)."""
    from pipeline.recording.stepper import Stepper

    from pipeline.cli.commands.common import CliError
    from pipeline.cli.commands.rerun import _cannot_check
    from pipeline.io.mcap_io import damage_cause, torn_cause

    st = Stepper(args.file, args.stage)  # a torn file cut before its metadata is said so here
    if not st.records:
        torn = damage_cause(args.file) or torn_cause(args.file)
        raise CliError(f"{args.file} holds no input of stage {args.stage} to step through" + (f": {torn}" if torn else ""))
    produced = {t for s in st.plan.stages.values() for t in s.outputs.values()}
    _cannot_check(args.file, st.plan, set(st.sp.inputs.values()) & produced, set(), f"stage {args.stage}", "step")
    return st


def cmd_step(args) -> int:
    from pipeline.cli.commands.common import CliError, warn_if_torn

    st = _stepper(args)
    out = sys.stdout
    shown = None
    if args.topics:  # the outputs to show, as typed (estimate, gflow/demo/estimate, patterns)
        from pipeline.cli.commands.common import chosen_topics

        chosen = chosen_topics(args.topics, st.sp.outputs.values(), where=f"stage {args.stage}'s outputs")
        shown = {t.rsplit("/", 1)[-1] for t in chosen}
    how = ""
    if args.start:
        try:
            how = st.jump(args.start)
        except ValueError as e:  # before the prompt: a mistyped --start is the first thing to say
            raise CliError(f"--start: {e}") from None
    warn_if_torn(args.file)  # after the checks, whose errors say it themselves: stepped only up to where it ends
    interactive = sys.stdin.isatty()
    print(f"stepping {args.stage} ({st.sp.kind}) through {args.file}: {len(st.records)} input messages, "
          f"snapshots at {sorted(st.snapshots) or 'none'}", file=out)
    print(HELP, file=out)
    if args.start:
        print(f"jumped to frame {args.start} {how}", file=out)
    last = None
    n = 0  # the line of standard input read last (a script's)

    def mistake(text: str) -> None:
        """A command that could not be carried out (a jump that could not be made, a command not known): at the
        terminal, say it and read the next command; from a script, stop with it (exit 2), as the commands after
        it would show and step other frames than it meant."""
        if interactive:
            print(text, file=out)
        else:
            out.flush()
            raise CliError(f"standard input line {n}: {text}")

    while True:
        n += 1
        if interactive:
            try:
                line = input("step> ").strip()
            except EOFError:
                break
        else:
            line = sys.stdin.readline()
            if not line:
                break
            line = line.strip()
            print(f"step> {line}", file=out)
        cmd, _, arg = line.partition(" ")
        if cmd in ("", "n", "next"):
            last = st.next()
            if last is None:
                print("end of the recording", file=out)
            else:
                _show(last, out, shown)
        elif cmd in ("j", "jump"):
            try:
                seq = int(arg)
            except ValueError:
                mistake(f"{line!r}: usage: j SEQ")
                continue
            try:
                print(f"jumped {st.jump(seq)}", file=out)
            except ValueError as e:
                mistake(str(e))
                continue
            last = st.next()
            if last is not None:
                _show(last, out, shown)
        elif cmd in ("s", "state"):
            print(json.dumps(st.stage.summary(), indent=1, default=str), file=out)
        elif cmd in ("o", "outputs"):
            from pipeline.recording.plain import describe

            for topic, seq, data in st.outputs[-len(last.outputs):] if last else []:
                if shown is not None and topic.rsplit("/", 1)[-1] not in shown:
                    continue
                print(f"{topic} seq {seq}: {describe(data, full=True)}", file=out)
        elif cmd in ("h", "help", "?"):
            print(HELP, file=out)
        elif cmd in ("q", "quit", "exit"):
            break
        else:
            mistake(f"unknown command {cmd!r}; h for help")
    return 0


def register(sub) -> None:
    from pipeline.cli.commands.common import whole_number

    p = sub.add_parser("step", help="step a stage through a recording, one frame at a time (interactive)",
                       description="Rebuilds a stage with its recorded configuration and feeds it its recorded "
                                   "inputs one frame at a time, printing the inputs it joined, its outputs and its "
                                   "state summary. Commands are read from the terminal (or from standard input).\n\n"
                                   + HELP, formatter_class=__import__("argparse").RawDescriptionHelpFormatter)
    p.add_argument("file", help="MCAP recording made by gflow")
    p.add_argument("--stage", required=True, help="stage to step (e.g. filter)")
    p.add_argument("--start", type=whole_number, help="jump to this frame first")
    p.add_argument("--topics", nargs="+", metavar="TOPIC",
                   help="show only these outputs: the name in the stream (estimate), the full name with or without "
                        "the run id, or a shell pattern")
    p.set_defaults(func=cmd_step)
