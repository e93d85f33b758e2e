"""The ``gflow`` command line. Each command lives in ``pipeline/cli/commands/``.

    gflow demo                         synthetic scene through the multi-process pipeline
    gflow track SOURCE --init X,Y,W,H  track one target through an image folder or video
    gflow eval --gt GT.csv --pred P.csv
    gflow run GRAPH.yaml               any graph, as processes over zenoh (or --inline)
    gflow info FILE.mcap               what a recording holds
    gflow replay FILE.mcap             republish a recording on zenoh
    gflow frame SOURCE N OUT.png       a frame with a pixel grid, to read --init off
    gflow ps | topics | echo TOPIC | hz TOPIC | pub TOPIC TYPE JSON   a live pipeline
    gflow view                         a live pipeline in Foxglove (ws://127.0.0.1:8765)
    gflow router ROUTER.yaml           a zenoh router: TLS, logins, access control (docs/security.md)
"""

from __future__ import annotations

import os
import sys


def _interrupted_at_start(signum: int, frame: object) -> None:
    """Ctrl-C while ``gflow`` is still starting (importing its modules, parsing its options): nothing has
    begun, so there is nothing to close; one line and exit status 130, as a command interrupted later says
    it (:func:`main`), not a ``KeyboardInterrupt`` traceback from inside an import. :func:`main` gives
    SIGINT back to Python before the command's work starts (:func:`_take_sigint_back`)."""
    word = next((a for a in sys.argv[1:] if not a.startswith("-")), "")
    os.write(2, f"gflow{' ' + word if word else ''}: interrupted\n".encode())
    os._exit(130)


if sys.argv and os.path.basename(sys.argv[0]) == "gflow":  # the command, not a module importing this one
    import signal

    # first of all, before the zygote's fork (which takes Python's handler back in the zygote:
    # pipeline/runtime/zygote.py) and every import below; SIGINT ignored (nohup ... &) is left as it is
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _interrupted_at_start)

from pipeline.runtime.instruction_sets import check_setting, hold  # noqa: E402

hold()  # before numpy, OpenCV or OpenBLAS loads here or in a stage: the same bits on every machine

from pipeline.runtime.zygote import start_early  # noqa: E402

if sys.argv and sys.argv[0].endswith(("gflow", "pipeline/cli/__main__.py", "pipeline/cli/main.py")):
    # first, before the imports below: a command that starts stage processes forks their zygote
    # now, which imports what they share while this process goes on (pipeline/runtime/zygote.py)
    start_early(sys.argv[1:])
    # then a UDP source's port, so a sender started with the command loses nothing (pipeline/io/udp_relay.py)
    from pipeline.io.udp_relay import bind_early

    bind_early(sys.argv[1:])


import argparse  # noqa: E402
import re  # noqa: E402
from typing import NoReturn  # noqa: E402

from pipeline.cli.commands import command_module, command_modules  # noqa: E402
from pipeline.cli.commands.common import CliError, start_work, work_started  # noqa: E402
from pipeline.io import damage_notes  # noqa: E402
from pipeline.runtime.trace import mark  # noqa: E402

__all__ = ["main", "build_parser"]


class _Version(argparse.Action):
    """``--version``: gflow, Python, the libraries that decide the figures and the OS
    (:func:`pipeline.runtime.versions.version_text`), looked up only when asked (reading the
    installed packages' metadata took ~45 ms of CPU at every start of ``gflow``)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show program's version number and exit"):
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from pipeline.runtime.versions import version_text

        print(version_text())
        parser.exit()


class _Parser(argparse.ArgumentParser):
    """argparse, with a usage mistake reported in one line (the usage is one --help away)."""

    commands: dict[str, argparse.ArgumentParser]

    def error(self, message: str) -> NoReturn:
        m = re.fullmatch(r"argument (--[\w-]+)(?:/-\w)?: expected one argument", message)
        if m:  # argparse takes a value such as -5,50,20,30 for an option, and says nothing of why
            message += f" (a value that starts with '-' is written {m.group(1)}=VALUE, e.g. {m.group(1)}=-5,...)"
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def command_word(argv: list[str]) -> str | None:
    """The command ``gflow ARGV`` names: its first word that is not an option (gflow's own options,
    ``-v``, ``--version``, ``-h``, take no value), or None (also after ``-h`` or ``--version``,
    which answer for every command)."""
    for a in argv:
        if a in ("-h", "--help", "--version"):
            return None
        if not a.startswith("-"):
            return a
    return None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``gflow`` parser: with every command, or, given ``command`` (a command's name), with that
    command's module alone (what ``gflow COMMAND ...`` parses the same; a name that is no command
    gets every command, so the error lists them)."""
    ap = _Parser(
        prog="gflow",
        description="gflow: a streaming dataflow tracker for video. Every stage is its own process, "
                    "stages talk over Eclipse Zenoh, and every message is recorded to MCAP.",
        epilog="Run 'gflow COMMAND --help' for the options of one command. Docs: README.md.")
    ap.add_argument("--version", action=_Version)
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    one = command_module(command) if command else None
    for mod in [one] if one is not None else command_modules():
        mod.register(sub)
    ap.commands = dict(sub.choices)  # each command's own parser, to report its mistakes (parse)
    return ap


def _options(parser: argparse.ArgumentParser) -> list[str]:
    """The long options ``parser`` takes (``--out``, ``--frames``...)."""
    return [o for a in parser._actions for o in a.option_strings if o.startswith("--")]


def parse(ap: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """``ap.parse_args(argv)``, but an argument no option takes is reported by the command's own parser
    (argparse reports it as the top-level ``gflow``'s, whose --help does not list the command's options),
    with the command's closest option when one is close."""
    import difflib

    args, extra = ap.parse_known_args(argv)
    parser = getattr(ap, "commands", {}).get(getattr(args, "command", None) or "", ap)
    if extra:
        message = f"unrecognized arguments: {' '.join(extra)}"
        word = next((e.split("=", 1)[0][2:] for e in extra if e.startswith("--")), None)
        positional = [a.dest for a in parser._actions if not a.option_strings]
        names = {o[2:]: o for o in _options(parser)}
        close = difflib.get_close_matches(word, list(names), n=1, cutoff=0.75) if word else []
        if word and word.replace("-", "_") in positional:
            message += f" ({word} is given by its place, without --{word}: see the usage)"
        elif close:
            message += f" (did you mean {names[close[0]]}?)"
        parser.error(message)
    parser, tokens = _command_parser(parser, sys.argv[1:] if argv is None else argv)
    _refuse_repeated(parser, tokens)
    _refuse_empty(parser, args)
    return args


def _command_parser(parser: argparse.ArgumentParser, argv: list[str]) -> tuple[argparse.ArgumentParser, list[str]]:
    """The parser of the command ``argv`` names, a command's own command included (learn m2, export vot), and the
    words of ``argv`` after its name."""
    tokens = list(argv)
    word = command_word(tokens)
    tokens = tokens[tokens.index(word) + 1:] if word in tokens else tokens
    while True:
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        name = next((t for t in tokens if not t.startswith("-") and sub is not None and t in sub.choices), None)
        if sub is None or name is None:
            return parser, tokens
        parser, tokens = sub.choices[name], tokens[tokens.index(name) + 1:]


def _refuse_empty(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """An argument given as '' (an unset shell variable: ``--out "$OUT"``): argparse takes it, and the command read
    it as not given (``--record ''``: the default recording; ``--topics ''``: every topic) or as the current folder
    (``gflow render run.mcap ''`` drew into it); refused naming the option. A live tool's topic says it itself."""
    for a in parser._actions:
        v = getattr(args, a.dest, None) if a.dest not in (argparse.SUPPRESS, "help", "topic") else None
        values = v if isinstance(v, list) else [v]
        if any(isinstance(x, str) and not x.strip() for x in values):
            shown = a.metavar if isinstance(a.metavar, str) else a.dest  # a tuple metavar names several values
            name = max(a.option_strings, key=len) if a.option_strings else shown.upper()
            parser.error(f"argument {name}: empty ({next(x for x in values if isinstance(x, str))!r}): give a "
                         f"non-empty name or value")


def _refuse_repeated(parser: argparse.ArgumentParser, tokens: list[str]) -> None:
    """An option of one value given twice (``gflow eval --pred a.csv --pred b.csv``): argparse keeps the last one
    without a word, so the command would run on a value the user may not have meant; refused naming the option.
    Options that add up (``--set``, ``--connect``) and flags are left alone. ``tokens``: the words after the
    command's name."""
    given: dict[str, list[str]] = {}
    for t in tokens:
        if t == "--":
            break
        action = _option_action(parser, t.split("=", 1)[0]) if t.startswith("-") else None
        if isinstance(action, argparse._StoreAction):
            given.setdefault(action.dest, []).append(t.split("=", 1)[0])
    twice = next((names for names in given.values() if len(names) > 1), None)
    if twice:
        parser.error(f"{twice[0]} given {len(twice)} times; give it once (the last one would be used without a word)")


def _option_action(parser: argparse.ArgumentParser, name: str) -> argparse.Action | None:
    """The action of option ``name`` as argparse reads it: exactly, or a long option's unambiguous prefix."""
    found = parser._option_string_actions.get(name)
    if found is not None or not name.startswith("--"):
        return found
    close = {a for o, a in parser._option_string_actions.items() if o.startswith(name)}
    return close.pop() if len(close) == 1 else None


def command_prog(ap: argparse.ArgumentParser, args: argparse.Namespace, argv: list[str] | None) -> str:
    """The name the command's errors are said under: its parser's ``prog``, a command's own command included
    (``gflow learn m2``, ``gflow export vot``), as argparse says a usage mistake of it; so that a command's
    every error starts alike, whether argparse or the command found it."""
    parser = getattr(ap, "commands", {}).get(getattr(args, "command", None) or "", ap)
    return _command_parser(parser, sys.argv[1:] if argv is None else argv)[0].prog


def _take_sigint_back() -> None:
    """Ctrl-C (SIGINT) stops every command, however it was started. A background job of a
    non-interactive shell (``nohup gflow replay ... &``) inherits SIGINT ignored; the launcher and
    ``gflow router`` take it regardless (:class:`pipeline.runtime.signals.StopSignals`), and so
    the tools that stop on ``KeyboardInterrupt`` (replay, echo, hz, view, step, benchmark...) get
    Python's own handler back. SIGHUP, which ``nohup`` ignores on purpose, is left as it is."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGINT) in (signal.SIG_IGN, _interrupted_at_start):
        signal.signal(signal.SIGINT, signal.default_int_handler)


def _mistakes() -> tuple[type[BaseException], ...]:
    """The errors that are a mistake in the command whenever they are raised (exit status 2): a request
    that cannot run, a graph's mistake, a path named that is refused before any work (missing, a folder
    given for a file, an output that exists: :mod:`pipeline.io.path_errors`), a zenoh session that cannot
    open, a security option that cannot be used. The classes of the modules the command never imported
    are left out (no such error can have been raised), so that naming them costs no import."""
    out: list[type[BaseException]] = [CliError]
    for module, name in (("pipeline.runtime.graph", "GraphError"), ("pipeline.runtime.transport", "SessionError"),
                         ("pipeline.io.path_errors", "PathMistake"), ("pipeline.runtime.security", "SecurityError")):
        if module in sys.modules:
            out.append(getattr(sys.modules[module], name))
    return tuple(out)


def _user_errors() -> tuple[type[BaseException], ...]:
    """The errors said in one line as ``error:``: the :func:`_mistakes` (exit status 2), and a bad value (a
    ValueError): a mistake in the command (exit status 2) when raised before the command's work began, the
    work failing (exit status 1) after (:func:`pipeline.cli.commands.common.start_work`: gflow track once
    its plan is checked, gflow learn once its training frames are read, gflow benchmark once every run is
    planned). Any other OSError is the system failing during the work (exit status 1, :func:`main`)."""
    return (*_mistakes(), ValueError)


def main(argv: list[str] | None = None) -> int:
    ap = build_parser(command_word(sys.argv[1:] if argv is None else argv))
    args = parse(ap, argv)
    mark("cli parsed")
    import logging  # here: --help and a usage mistake, said by parse, need no logging (nor its traceback, linecache...)

    logging.basicConfig(level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)],
                        format="%(levelname)s %(name)s: %(message)s")
    if args.command is None:
        ap.print_help()
        return 2
    prog = command_prog(ap, args, argv)
    start_work(False)  # main may run several commands in one process (the tests do)
    damage_notes.defer()  # damage inside a recording: said once, by the command's last line or after it
    try:
        _take_sigint_back()  # from here on a Ctrl-C is a KeyboardInterrupt the command may clean up after
        check_setting()  # GFLOW_SIMD mistyped: said before any work (the kernels were held meanwhile)
        rc = int(args.func(args) or 0)
    except _user_errors() as e:
        msg = " ".join(str(e).split())  # one line, whatever the library wrote
        return _last_word(f"{prog}: error: {msg}",
                          1 if work_started() and not isinstance(e, _mistakes()) else 2)
    except BrokenPipeError:  # the reader of the output has gone (gflow info r.mcap | head): not an error to report
        damage_notes.flush()
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # so the exit's flush of stdout is quiet
        return 141  # as a shell reports a command ended by SIGPIPE
    except OSError as e:  # the system failed during the work (a full disk, a write refused): name it, exit 1
        where = f"{e.filename}: " if e.filename else ""
        return _last_word(f"{prog}: error: {where}{e.strerror or e}", 1)
    except KeyboardInterrupt:
        return _last_word(f"{prog}: interrupted", 130)
    except RuntimeError as e:  # a run that could not start or went wrong (e.g. a stage never came up)
        return _last_word(f"{prog}: error: {' '.join(str(e).split())}", 1)
    except Exception as e:  # a bug: one line for the user, the traceback with -vv
        if args.verbose >= 2:
            damage_notes.flush()
            raise
        return _last_word(f"{prog}: internal error: {type(e).__name__}: "
                                f"{' '.join(str(e).split())} (a bug in gflow; run with -vv for the traceback)", 1)
    damage_notes.flush()
    return rc


def _last_word(line: str, rc: int) -> int:
    """Print the command's last ``line`` on stderr, after the damage warnings it does not already hold
    (:mod:`pipeline.io.damage_notes`); return ``rc``."""
    damage_notes.flush(line)
    print(line, file=sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())
