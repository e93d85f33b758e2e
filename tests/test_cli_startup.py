"""``gflow COMMAND`` builds the parser of that command alone: it imports the module that registers
it (:data:`pipeline.cli.commands.COMMANDS`), not every command's, and parses its arguments as the
parser of every command does."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from pipeline.cli.commands import COMMANDS, command_modules
from pipeline.cli.main import build_parser, command_word


def test_the_table_names_the_module_that_registers_each_command():
    registered = {}
    for mod in command_modules():
        sub = argparse.ArgumentParser().add_subparsers()
        mod.register(sub)
        registered.update({name: mod.__name__.rsplit(".", 1)[1] for name in sub.choices})
    assert COMMANDS == registered


@pytest.mark.parametrize("argv", [
    ["track", "frames/", "--init", "1,2,3,4", "--tracker", "chamfer", "--stop", "60", "--out", "b.csv", "-q"],
    ["-v", "demo", "--frames", "20", "--inline"],
    ["-vv", "rerun", "run.mcap", "--stage", "filter", "--set", "lam=0.8", "--check"],
    ["info", "run.mcap", "--json"],
    ["hz", "gflow/demo/frames", "--duration", "2"],
    ["benchmark", "data", "--trackers", "dcf", "--opencv", "none", "--inline", "--seed", "1"],
])
def test_the_one_command_parser_parses_as_the_whole_one(argv):
    assert command_word(argv) == next(a for a in argv if not a.startswith("-"))
    assert build_parser(command_word(argv)).parse_args(argv) == build_parser().parse_args(argv)


@pytest.mark.parametrize("argv", [["--help", "track"], ["-h"], ["--version", "info"], ["-v"], []])
def test_the_whole_parser_answers_what_is_asked_of_every_command(argv):
    assert command_word(argv) is None  # gflow --help lists every command, whatever follows


def test_a_command_imports_its_own_module_only(tmp_path):
    code = ("import sys\nfrom pipeline.cli.main import main\n"
            f"rc = main(['verify', {str(tmp_path / 'none.mcap')!r}])\n"
            "print(rc, sorted(m for m in sys.modules if m.startswith('pipeline.cli.commands.')))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.stdout.split(None, 1) == ["1", "['pipeline.cli.commands.common', 'pipeline.cli.commands.verify']\n"], \
        r.stdout + r.stderr
    assert "none.mcap" in r.stderr


def test_a_mistyped_command_is_refused_naming_every_command():
    r = subprocess.run([sys.executable, "-m", "pipeline.cli.main", "trak", "x"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "invalid choice: 'trak'" in r.stderr
    assert all(f"'{name}'" in r.stderr for name in COMMANDS)
