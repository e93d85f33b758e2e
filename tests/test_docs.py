"""The README and the pages of docs/ work as written.

Every page (README.md, CHANGELOG.md, docs/*.md, bench/README.md, recordings/README.md) is read
the way a user reads it, and:

* its code runs, in document order, in a scratch folder of its own: every ```python block (the
  blocks of a page share one namespace) and every shell line whose gflow command names only
  what gflow ships (the synthetic scene, the built-in graphs, the files the page's earlier
  lines made). A line ending in ``&`` runs in the background until the page is done (the lines
  after it may wait for the pipeline it starts); a command that serves until Ctrl-C (``gflow
  view``, ``gflow router``, ``gflow hz`` without ``--duration``, ``gflow replay --loop 0``) runs
  until it says it is ready, then gets SIGINT and must exit 0;
* a gflow line that needs what is not here is parsed by gflow's own argument parser, so a
  misspelt or renamed option still fails: the evaluation video (``../shared/data``), your own
  files (written in capitals: ``VIDEO.mp4``, ``RUN.mcap``, ``tcp/ROUTER:7447``), other hosts (an
  address that is not loopback), or a block marked ``<!-- not run: REASON -->``;
* every graph in a ```yaml block is validated as ``gflow run`` validates it;
* every relative link and #anchor resolves, every repository path named in backticks exists,
  the parameter tables of docs/trackers.md give the shipped graphs' values, and the README
  stays a short manual;
* a gflow command written in a sentence names options its command has, and every table of
  measured figures on the user's pages says just above it what command made it (or that no
  command of this version reproduces it).
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import re
import shlex
import signal
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

import cli_fork

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md")),
         ROOT / "bench" / "README.md", ROOT / "recordings" / "README.md"]
SHELL = {"bash", "sh", "shell", "console"}

# What a gflow line may name that is not here; such a line is parsed, not run.
NEEDS = [
    (re.compile(r"\.\./shared/data|\$GFLOW_DATA"), "the evaluation data in ../shared/data"),
    (re.compile(r"(?<![\w.])(?!127\.0\.0\.1\b)\d{1,3}(?:\.\d{1,3}){3}\b|\bexample\.(?:org|com)\b"),
     "another host"),
    (re.compile(r"\b[A-Z][A-Z0-9_]*[A-Z0-9]\b(?!=)"), "your own files (names in capitals)"),
]
# Commands that serve until Ctrl-C, and what each prints once it is ready.
# (what it prints once it is ready, its exit status after Ctrl-C)
SERVES = {"view": ("Foxglove: open", 0), "router": ("listening on", 0), "hz": ("average rate", 0),
          "replay": ("replaying", 0)}
TIMEOUT = 180  # s, per line: the slowest documented line takes a few seconds


# ---------------------------------------------------------------------------------------------
# Reading the pages


@dataclass
class Block:
    page: Path
    line: int  # 1-based line of the block's first line of code
    lang: str
    text: str
    not_run: str = ""  # the reason given by a <!-- not run: REASON --> marker

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of a Markdown page, in order (also when indented in a list)."""
    out: list[Block] = []
    lines = page.read_text().splitlines()
    i = 0
    marker = ""
    while i < len(lines):
        m = re.match(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)", lines[i])
        note = re.match(r"^\s*<!--\s*not run:\s*(.+?)\s*-->", lines[i])
        if note:
            marker = note.group(1)
        elif m:
            indent, fence, lang = m.groups()
            body = []
            i += 1
            start = i + 1
            while i < len(lines) and not lines[i].strip().startswith(fence):
                body.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i].lstrip())
                i += 1
            out.append(Block(page, start, lang.lower(), "\n".join(body) + "\n", marker))
            marker = ""
        elif lines[i].strip():
            marker = ""
        i += 1
    return out


def shell_lines(block: Block) -> list[tuple[int, str]]:
    """(line number, command) of each command of a shell block: continuations joined, prompts
    and comment-only lines dropped."""
    out: list[tuple[int, str]] = []
    pending, first = "", 0
    for n, raw in enumerate(block.text.splitlines(), start=block.line):
        line = re.sub(r"^\$ ", "", raw.strip()) if not pending else raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if not pending:
            first = n
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        out.append((first, pending + line))
        pending = ""
    return out


def segments(line: str) -> list[str]:
    """The commands of a shell line split at ``&&``, ``||``, ``;`` and ``|`` (outside quotes)."""
    lex = shlex.shlex(line, posix=True, punctuation_chars=";&|")
    lex.whitespace_split = True
    lex.commenters = "#"
    out, cur = [], []
    for tok in lex:
        if tok and set(tok) <= set(";&|"):
            if cur:
                out.append(cur)
            cur = []
        else:
            cur.append(tok)
    if cur:
        out.append(cur)
    return [shlex.join(c) for c in out]


def in_background(line: str) -> str:
    """The command of a line that ends with ``&`` (a comment after it allowed), else ''."""
    lex = shlex.shlex(line, posix=True, punctuation_chars=";&|")
    lex.whitespace_split = True
    lex.commenters = "#"
    words = list(lex)
    return shlex.join(words[:-1]) if len(words) > 1 and words[-1] == "&" else ""


def gflow_args(segment: str) -> list[str] | None:
    """The arguments of a gflow command (after env assignments and the command name), or None."""
    words = shlex.split(segment, comments=True)
    while words and re.match(r"^[A-Z_][A-Z0-9_]*=", words[0]):
        words = words[1:]
    # the shell's redirections are not the command's arguments: '> out.json', '2>&1', '>log'
    kept: list[str] = []
    for w in words:
        if kept and re.fullmatch(r"\d?>>?|<", kept[-1]):
            kept.pop()
        elif not re.fullmatch(r"\d?>&\d|\d?>>?[^\s>&]\S*|<\S+", w):
            kept.append(w)
    words = kept[:-1] if kept and re.fullmatch(r"\d?>>?|<", kept[-1]) else kept
    if words[:1] == ["gflow"]:
        return words[1:]
    if len(words) >= 3 and words[0].endswith("python") and words[1] == "-m" and words[2] in (
            "pipeline.cli", "pipeline.cli.main"):
        return words[3:]
    return None


def one_command(line: str) -> list[str] | None:
    """``gflow ARGS``'s ARGS when the line is that one command and uses nothing of the shell's (no pipe,
    redirection, variable, wildcard or second command; a trailing comment is fine), else None."""
    code = line.split(" #")[0]
    if re.search(r"[|&;<>$*?`(){}\\[\]~'\"\\]", code):
        return None
    words = code.split()
    return words[1:] if words[:1] == ["gflow"] else None


def installs_this_project(segment: str) -> bool:
    words = shlex.split(segment)
    if words[:2] == ["python", "-m"]:
        words = words[2:]
    return words[:2] == ["pip", "install"] and words[-1] in (".", ".[test]") and words[2:-1] in ([], ["-e"])


def files(line: str) -> set[str]:
    """The words of a shell line that look like file names (``run.mcap``, ``out/``)."""
    words = shlex.split(line.split(" #")[0], comments=True)
    return {w for w in words if not w.startswith("-") and re.fullmatch(r"[\w./-]+\.[a-z][a-z0-9]{1,4}|[\w.-]+/", w)}


def needs(line: str) -> str:
    """Why a gflow line cannot run here ('' if it can)."""
    code = line.split(" #")[0]
    for rx, what in NEEDS:
        if rx.search(code):
            return what
    return ""


def serves_until_stopped(args: list[str]) -> tuple[str, int] | None:
    """For a command that runs until Ctrl-C: what it prints once it is ready and its exit status
    after Ctrl-C (None for a command that ends by itself)."""
    cmd = args[0] if args else ""
    if cmd in ("view", "router", "hz") and "--duration" not in args:
        return SERVES[cmd]
    if cmd == "replay" and "--loop" in args and args[args.index("--loop") + 1:][:1] == ["0"]:
        return SERVES[cmd]
    return None


@functools.lru_cache(maxsize=1)
def whole_parser():
    """gflow's parser of every command, built once (building it takes about 0.15 s, and the pages give
    dozens of lines that are parsed, not run); parsing leaves it as it was."""
    from pipeline.cli.main import build_parser

    return build_parser()


def parse_error(args: list[str]) -> str:
    """What gflow's argument parser says about ``gflow ARGS`` ('' if it parses)."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            whole_parser().parse_args(args)
    except SystemExit as e:
        if e.code not in (0, None):
            return err.getvalue().strip() or f"exit {e.code}"
    return ""


# ---------------------------------------------------------------------------------------------
# Running a page


class PageRun:
    """Runs one page's code in order, in a scratch folder, with ``gflow`` the repository's code."""

    def __init__(self, page: Path, tmp: Path, monkeypatch):
        self.page, self.tmp = page, tmp
        self.namespace: dict = {"__name__": "__docs__"}
        self.background: list[tuple[str, subprocess.Popen, io.TextIOBase]] = []
        self.failures: list[str] = []
        self.not_made: set[str] = set()  # files named by lines that were not run
        self.notes: list[str] = []  # lines that could not be tried here, through no fault of the page
        bin_dir = tmp / ".bin"
        bin_dir.mkdir()
        shim = bin_dir / "gflow"
        shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m pipeline.cli "$@"\n')
        shim.chmod(0o755)
        self.env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
                        PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
        monkeypatch.chdir(tmp)
        monkeypatch.syspath_prepend(str(ROOT))

    def made_elsewhere(self, line: str) -> str:
        """Why a line cannot run: it reads a file that a line not run here would have made."""
        missing = sorted(files(line) & self.not_made)
        return f"{missing[0]} comes from a line not run here" if missing else ""

    def fail(self, where: str, line: str, what: str) -> None:
        self.failures.append(f"{where}: {line}\n    {what.strip()[-1500:]}")

    def python(self, block: Block) -> None:
        try:
            exec(compile(block.text, block.where, "exec"), self.namespace)
        except Exception as e:  # the failure names the page and line (the compile filename)
            import traceback

            self.fail(block.where, "```python block", "".join(traceback.format_exception(e)[-6:]))

    def shell(self, block: Block) -> None:
        for n, line in shell_lines(block):
            where = f"{block.page.relative_to(ROOT)}:{n}"
            segs = segments(line)
            run = [s for s in segs if not installs_this_project(s)]
            cmds = [gflow_args(s) for s in run]
            if not any(c is not None for c in cmds):
                continue  # pip, the test suite itself, openssl, sudo ...: not gflow's to run
            reason = block.not_run or needs(line) or self.made_elsewhere(line)
            # besides gflow, a runnable line may only feed it (printf 'n\nq\n' | gflow step ...)
            plain = all(c is not None or re.match(r"^(printf|echo|cat|sleep) ", s) for c, s in zip(cmds, run))
            if reason or not plain:
                for c in cmds:  # not runnable here: gflow must at least accept the arguments
                    if c is not None and "--help" not in c and (err := parse_error(c)):
                        self.fail(where, line, err)
                self.not_made |= {w for w in files(line) if not (self.tmp / w).exists() and not (ROOT / w).exists()}
                continue
            # 'pip install -e . && gflow demo': the test environment is that install already
            self.execute(where, " && ".join(run) if len(run) < len(segs) else line, cmds)

    def execute(self, where: str, line: str, cmds: list) -> None:
        gflows = [c for c in cmds if c is not None]
        first, last = gflows[0], gflows[-1]
        background = in_background(line)
        if background:
            log = open(self.tmp / f".background-{len(self.background)}.log", "w+")
            p = subprocess.Popen(["bash", "-c", "exec " + background], env=self.env, cwd=self.tmp,
                                 stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            self.background.append((where, p, log))
            self.wait_announced(where, line, p)
            return
        serves = serves_until_stopped(first)
        if serves:
            self.serve(where, line, *serves)
            return
        try:
            alone = one_command(line)
            if alone is not None:
                # one gflow command and nothing of the shell's: forked as the command would start (tests/cli_fork.py)
                r = cli_fork.run(alone, self.tmp, self.env, timeout=TIMEOUT)
            else:
                r = subprocess.run(["bash", "-o", "pipefail", "-c", line], env=self.env, cwd=self.tmp,
                                   capture_output=True, text=True, timeout=TIMEOUT, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            self.fail(where, line, f"still running after {TIMEOUT} s")
            return
        ok = {0, 1} if last[:1] == ["diff"] else {0}  # diff exits 1 when the recordings differ, as documented
        if r.returncode not in ok:
            self.fail(where, line, f"exit {r.returncode}\n{r.stdout[-700:]}\n{r.stderr[-700:]}")

    def wait_announced(self, where: str, line: str, p: subprocess.Popen) -> None:
        """Wait until the pipeline a background line starts is announced (the live tools find it)."""
        from pipeline.runtime.running import running

        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and p.poll() is None:
            if any(info.get("pid") == p.pid for info in running()):
                return
            time.sleep(0.1)
        self.fail(where, line, f"the pipeline was not announced (exit {p.poll()})")

    def serve(self, where: str, line: str, ready: str, status: int) -> None:
        """Run a command that serves until Ctrl-C: wait for its ready line, then SIGINT, and
        check its exit status. A port another program holds is noted, not failed."""
        import queue
        import threading

        # PYTHONFAULTHANDLER: a process that does not stop prints where each thread waits on SIGABRT.
        # SIGINT back to its default in the child: a shell running the tests in the background ignores
        # it, its children inherit that, and a command started so would never see the Ctrl-C sent below.
        p = subprocess.Popen(["bash", "-c", "exec " + line], env=dict(self.env, PYTHONFAULTHANDLER="1"), cwd=self.tmp,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        lines: queue.Queue = queue.Queue()

        def read() -> None:
            for out in p.stdout:  # type: ignore[union-attr]
                lines.put(out)
            lines.put(None)  # the end of its output

        threading.Thread(target=read, daemon=True).start()
        seen: list[str] = []
        try:
            deadline = time.monotonic() + 60
            while not any(ready in s for s in seen):
                try:
                    s = lines.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    s = None
                if s is None:
                    if re.search(r"address already in use", "".join(seen), re.I):
                        self.notes.append(f"{where}: {line}: its port is taken on this machine")
                    else:
                        self.fail(where, line, f"never said {ready!r} (exit {p.poll()}):\n{''.join(seen)}")
                    return
                seen.append(s)
            os.killpg(p.pid, signal.SIGINT)
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGABRT)  # its threads' stacks: what it waits on
                try:
                    while (s := lines.get(timeout=10)) is not None:
                        seen.append(s)
                except queue.Empty:
                    pass
                self.fail(where, line, f"still running 30 s after Ctrl-C\n{''.join(seen)}")
                return
            if p.returncode != status:
                self.fail(where, line, f"exit {p.returncode} after Ctrl-C\n{''.join(seen)}")
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()

    def finish(self) -> None:
        for where, p, log in self.background:
            try:
                p.wait(timeout=120)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
                self.fail(where, "(background line)", "still running when the page was done")
            log.seek(0)
            if p.returncode != 0:
                self.fail(where, "(background line)", f"exit {p.returncode}\n{log.read()[-700:]}")
            log.close()


def pages_with_code() -> list[Path]:
    return [p for p in PAGES if any(b.lang in SHELL | {"python"} for b in blocks(p))]


@pytest.mark.parametrize("page", pages_with_code(), ids=lambda p: str(p.relative_to(ROOT)))
@pytest.mark.timeout(900)  # a page runs many commands (debugging.md: over ten, 67 s at load 12); each line has TIMEOUT
def test_page_code_runs(page: Path, tmp_path, monkeypatch):
    run = PageRun(page, tmp_path, monkeypatch)
    try:
        for b in blocks(page):
            if b.lang == "python" and not b.not_run:
                run.python(b)
            elif b.lang in SHELL:
                run.shell(b)
    finally:
        run.finish()
    for note in run.notes:
        warnings.warn(note)
    assert not run.failures, "documented code that does not work as written:\n" + "\n".join(run.failures)


def test_pages_run_something():
    """The collector finds the code it should: a silent collector would pass every page."""
    ran = {str(p.relative_to(ROOT)): [ln for b in blocks(p) if b.lang in SHELL for _, ln in shell_lines(b)
                                      if gflow_args(segments(ln)[-1]) is not None and not needs(ln)
                                      and not b.not_run]
           for p in PAGES}
    assert "gflow demo" in [s for ln in ran["README.md"] for s in segments(ln)]
    assert len(ran["docs/debugging.md"]) >= 10
    assert any(b.lang == "python" for p in PAGES for b in blocks(p))


# ---------------------------------------------------------------------------------------------
# Graphs, links, paths, parameters


def test_yaml_graphs_are_valid():
    from pipeline.runtime.graph import parse_graph

    n = 0
    for page in PAGES:
        for b in blocks(page):
            if b.lang not in ("yaml", "yml"):
                continue
            if re.search(r"^\s*\.\.\.\s*$", b.text, re.M):
                continue  # an excerpt, with a part left out
            doc = yaml.safe_load(b.text)  # every YAML block parses
            if isinstance(doc, dict) and "stages" in doc:
                parse_graph(b.text, filename=b.where)
                n += 1
    assert n >= 1


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    out: set[str] = set()
    in_code = False
    for line in page.read_text().splitlines():
        if re.match(r"^\s*(`{3,}|~{3,})", line):
            in_code = not in_code
        m = re.match(r"^#{1,6}\s+(.*)$", line)
        if m and not in_code:
            base = slug(m.group(1))
            s, i = base, 1
            while s in out:
                s, i = f"{base}-{i}", i + 1
            out.add(s)
    return out


def test_links_resolve():
    bad = []
    for page in PAGES:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"^[a-z]+:", target):
                continue  # http(s), mailto
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                bad.append(f"{page.relative_to(ROOT)}: {target}: no such file")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                bad.append(f"{page.relative_to(ROOT)}: {target}: no heading with that anchor in {dest.name}")
    assert not bad, "\n".join(bad)


def test_named_paths_exist():
    """A path of the repository named in backticks (`pipeline/runtime/node.py`) exists (the
    changelog names the old paths of what moved)."""
    bad = []
    rx = re.compile(r"`((?:pipeline|stages|gflow_core|tests|bench|docs|\.ci)/[\w./-]*?)(?:::\w+)?`")
    for page in (p for p in PAGES if p.name != "CHANGELOG.md"):
        for m in rx.finditer(page.read_text()):
            p = m.group(1).rstrip("/.")
            if not (ROOT / p).exists():
                bad.append(f"{page.relative_to(ROOT)}: {p}")
    assert not bad, "named but missing:\n" + "\n".join(bad)


def test_parameter_tables_match_the_shipped_graphs():
    from pipeline.runtime.graph import load_graph

    page = ROOT / "docs" / "trackers.md"
    checked, bad, graph = 0, [], None
    for line in page.read_text().splitlines():
        head = re.match(r"^\|\s*parameter \(graph (\w+)\)", line)
        if head:
            graph = load_graph(head.group(1))
            continue
        if not line.startswith("|"):
            graph = None
        if graph is None:
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        name = re.fullmatch(r"`(\w+)\.(\w+)`", cells[0])
        if not name:
            continue
        stage, param = name.groups()  # tracker.PARAM: the graph's tracker block
        params = (graph.tracker.params if stage == "tracker" and graph.tracker is not None
                  else graph.stages[stage].params if stage in graph.stages else {})
        if param not in params:
            bad.append(f"{graph.name}: {stage}.{param} is not a parameter")
            continue
        literal = re.fullmatch(r"`([^`]*)`", cells[1])
        if literal:
            want, have = yaml.safe_load(literal.group(1)), params[param]
            have = list(have) if isinstance(have, tuple) else have
            numeric = isinstance(have, (int, float, list)) and not isinstance(have, bool)
            if (want != pytest.approx(have)) if numeric else (want != have):
                bad.append(f"{graph.name}: {stage}.{param} is {have!r}, the table says {want!r}")
            checked += 1
    assert not bad, "\n".join(bad)
    assert checked >= 30


# ---------------------------------------------------------------------------------------------
# The README is a user's manual


def test_readme_is_a_short_manual():
    text = (ROOT / "README.md").read_text()
    lines = text.splitlines()
    assert len(lines) < 300, f"README.md has {len(lines)} lines; move details to docs/"
    head = "\n".join(lines[:120]).lower()
    for what in ("## install", "gflow demo", "## track your own video", "## which tracker"):
        assert what in head, f"{what!r} is not in the README's first 120 lines"
    found = [(n, ln) for n, ln in enumerate(lines, 1)
             if re.search(r"\b(issues?|rounds?|helpers?|sessions?)\b|\bthis (branch|merge)\b", ln, re.I)]
    assert not found, f"the README speaks of how it was built: {found}"


def test_no_page_speaks_of_how_it_was_built():
    rx = re.compile(r"\bissue \d+|\b(this|last|next|earlier) rounds?\b|\bhelper'?s? (run|session)\b", re.I)
    found = [f"{p.relative_to(ROOT)}:{n}: {ln.strip()}" for p in PAGES
             for n, ln in enumerate(p.read_text().splitlines(), 1) if rx.search(ln)]
    assert not found, "\n".join(found)


def test_the_two_commands_are_what_ci_runs():
    """The README's first command installs and runs the demo; its second installs and runs the
    tests, which is what .ci/run does."""
    code = [b for b in blocks(ROOT / "README.md") if b.lang in SHELL]
    assert shell_lines(code[0])[0][1] == "pip install -e . && gflow demo"
    assert shell_lines(code[1])[0][1] == "pip install -e '.[test]' && python -m pytest -n 2 --dist loadfile"
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^python -m pip install -e '\.\[test\]'", ci, re.M)
    assert re.search(r"^python -m pytest -n 2 --dist loadfile$", ci, re.M)


def test_benchmark_commands_exist():
    """Each `python bench/X.py --option` the pages give names a benchmark that has those options."""
    bad = []
    for page in PAGES:
        for cmd in re.findall(r"python (bench/\w+\.py)((?: --?[\w-]+(?: [^`|\s-][^`|\s]*)?)*)", page.read_text()):
            script, opts = ROOT / cmd[0], [t for t in cmd[1].split() if t.startswith("-")]
            if not script.exists():
                bad.append(f"{page.relative_to(ROOT)}: {cmd[0]} does not exist")
                continue
            src = script.read_text()
            bad += [f"{page.relative_to(ROOT)}: {cmd[0]} has no option {o}" for o in opts
                    if o not in ("-h", "--help") and f'"{o}"' not in src]
    assert not bad, "\n".join(bad)


# ---------------------------------------------------------------------------------------------
# Figures and the commands beside them


def prose(text: str) -> str:
    """A page's text with its fenced code blocks blanked (their lines kept, so line numbers hold)."""
    return re.sub(r"^\s*(`{3,}|~{3,}).*?^\s*\1", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.S | re.M)


def unknown_options(command: str) -> list[str]:
    """What is wrong with the command and options of ``gflow WORDS`` named in prose: a command gflow
    does not have, or an option its command does not take. Values and placeholders are not judged
    (the code blocks' lines are parsed whole by test_page_code_runs)."""
    import argparse

    def commands(parser) -> dict:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        return subs[0].choices if subs else {}

    words = command.split()[1:]
    parser = whole_parser()
    while words and commands(parser) and re.fullmatch(r"[a-z][\w-]*", words[0]):
        if words[0] not in commands(parser):
            return [f"no command {words[0]!r}"]
        parser, words = commands(parser)[words[0]], words[1:]
    # a group named without its command (`gflow learn --out`): an option of any of its commands
    known = set(parser._option_string_actions).union(*(c._option_string_actions for c in commands(parser).values()))
    return [w for w in (w.split("=")[0] for w in words if re.match(r"^--?[A-Za-z]", w)) if w not in known]


def test_commands_in_prose_name_options_that_exist():
    """A `gflow COMMAND --option ...` written in a sentence (as the figures' commands are) names a
    command gflow has and options that command takes: a renamed option fails here, as it does in
    a code block."""
    assert unknown_options("gflow benchmark ../shared/data --seeds 1-3 --inline") == []
    assert unknown_options("gflow benchmark DATA --seed-list 1") == ["--seed-list"]  # the check can fail
    assert unknown_options("gflow learn m3 X") == ["no command 'm3'"]
    bad, n = [], 0
    for page in (p for p in PAGES if p.name != "CHANGELOG.md"):
        text = prose(page.read_text())
        for m in re.finditer(r"`(gflow [^`]+)`", text):
            cmd = " ".join(m.group(1).split())
            if re.match(r"gflow [a-z-]+:", cmd):
                continue  # a message gflow prints ("gflow trax: error: ..."), not a command
            n += 1
            for what in unknown_options(cmd):
                bad.append(f"{page.relative_to(ROOT)}:{text[:m.start()].count(chr(10)) + 1}: {cmd}: {what}")
    assert not bad, "\n".join(bad)
    assert n >= 100


# The pages whose tables of measured figures each say, just above, what made them (the development
# pages give their commands in the running text between tables and are not held to it).
FIGURE_PAGES = ["README.md", "docs/accuracy.md", "docs/stress.md", "docs/recovery.md", "docs/trackers.md",
                "docs/live.md", "docs/deployment.md", "docs/vot.md", "docs/own_tracker.md", "docs/python-api.md",
                "docs/architecture.md", "docs/security.md"]
# a cell that is a figure: 0.875, 13 ms, 360 / 382, 0.98 (417 / 440), 1.35 / 1.41 / 1.40, 0.47-0.50
FIGURE = re.compile(r"[-+]?\d[\d.,]*(?:-\d[\d.,]*)?(?: ?(?:ms|px|s|MB|%))?(?: ?/ ?\d[\d.,]*(?:-\d[\d.,]*)?(?: ?(?:ms|px|s|MB|%))?)*"
                    r"(?: \([^)]*\))?")
MADE_BY = re.compile(r"`[^`]*(?:gflow [a-z]|python bench/|bench/\w+\.py|pytest)[^`]*`|\bno command\b"
                     r"|^\s*(?:\$ )?\S*(?:gflow [a-z]|python (?:bench/|-m pytest))", re.M)  # inline, or a code block's line


def tables_without_a_command(text: str) -> list[tuple[int, str]]:
    """(line, header) of each table of measured figures (three or more cells such as 0.875, 13 ms or
    360 / 382) outside the ``<!-- figures: NAME -->`` blocks (which bench/make_tables.py writes with
    their command) whose lead -- the lines above it, up to a heading or another table and at most 25 -- neither gives a
    command (`gflow ...`, `python bench/...`, `pytest ...`) nor says that no command reproduces it."""
    lines, raw = prose(text).splitlines(), text.splitlines()
    out: list[tuple[int, str]] = []
    in_block, i = False, 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("<!-- figures:"):
            in_block = True
        elif line.startswith("<!-- end figures:"):
            in_block = False
        if not (line.startswith("|") and i + 1 < len(lines) and re.fullmatch(r"\|[-| :]+\|", lines[i + 1].strip())):
            i += 1
            continue
        end = i + 2
        while end < len(lines) and lines[end].startswith("|"):
            end += 1
        cells = [c for row in lines[i + 2:end] for c in row.strip().strip("|").split("|")]
        settings = re.match(r"\|\s*parameter\b", line)  # the trackers' parameter tables: settings, not figures
        if not in_block and not settings and sum(bool(FIGURE.fullmatch(c)) and bool(re.search(r"[./a-z%]", c))
                                             for c in (c.strip().strip("*`") for c in cells)) >= 3:  # not a count alone
            lead: list[str] = []
            k = i - 1
            while k >= 0 and len(lead) < 25 and not lines[k].startswith(("#", "|")):
                lead.append(raw[k])
                k -= 1
            if not MADE_BY.search("\n".join(reversed(lead))):
                out.append((i + 1, line.strip()[:80]))
        i = end
    return out


def test_every_table_of_figures_says_what_made_it():
    table = "| a | b |\n|---|---|\n| 0.875 | 0.910 |\n| 1.18 | 0.77 |\n"
    assert tables_without_a_command("## Scores\n\nMeasured on a quiet day:\n\n" + table) == [(5, "| a | b |")]
    assert tables_without_a_command("Measured by `gflow benchmark DATA --seed 1`:\n\n" + table) == []
    bad = [f"{name}:{n}: {head}" for name in FIGURE_PAGES
           for n, head in tables_without_a_command((ROOT / name).read_text())]
    assert not bad, ("a table of figures whose lead gives no command that prints them (give it, or say that "
                     "no command of this version reproduces them):\n" + "\n".join(bad))
