"""Recording files are never overwritten.

* A default recording name carries the time and the run id (``recordings/track-20250101-120000-3f9c2a.mcap``),
  and a suffix (``-2``, ``-3``...) when that name is taken: two runs started in the same second
  get two files (:func:`unique_path`).
* The recorder creates its file exclusively (``O_EXCL``, :func:`create_new`): should two writers
  still be given one name, the second one fails with a one-line error instead of destroying the
  first one's file.
* ``--record FILE`` naming a file that exists is refused before the run starts (:func:`refuse_existing`).
* A file written in one go from another (``gflow recover``) is written under a hidden temporary name
  beside its own (:func:`create_beside`) and moved there once complete (:func:`move_new`): a failure
  midway (a full disk) leaves no partial file under the name asked for.

A folder of recordings grows by a few hundred KB a frame (raw frames are most of it):
:func:`folder_recordings` lists its recordings (each with its segment files) newest first, which
``gflow clean`` and the size warning after a run (:func:`size_warning`, above
``GFLOW_RECORDINGS_WARN_MB``, default 2000) use.
"""

from __future__ import annotations

import os
import re
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Callable, TextIO

from pipeline.io.path_errors import PathMistake

__all__ = ["RecordingExists", "OutputExists", "unique_path", "create_new", "create_beside", "move_new", "write_beside", "write_text_new", "save_figure_new",
           "refuse_existing",
           "StoredRecording", "folder_recordings", "size_warning", "warn_mb", "WARN_MB"]

#: the size of a recordings folder above which a run warns (MB), unless GFLOW_RECORDINGS_WARN_MB says
WARN_MB = 2000.0


class RecordingExists(FileExistsError):
    """A recording would overwrite a file that exists."""


class OutputExists(RecordingExists, PathMistake):
    """The output the user named exists, found before any work (:func:`refuse_existing`): a mistake in the
    command, where a file that appears under the name while it is written (:func:`create_new`,
    :func:`move_new`) is a run that failed."""


def _taken(p: Path) -> bool:
    """A path that names a file, or the first segment of one (``NAME.part1.mcap``)."""
    return p.exists() or p.with_name(f"{p.stem}.part1{p.suffix}").exists()


def unique_path(path: str | os.PathLike) -> Path:
    """``path`` itself when free, else ``STEM-2.SUFFIX``, ``STEM-3.SUFFIX``... the first one free."""
    p = Path(path)
    n = 2
    out = p
    while _taken(out):
        out = p.with_name(f"{p.stem}-{n}{p.suffix}")
        n += 1
    return out


def refuse_existing(path: str | os.PathLike, what: str = "--record") -> None:
    """An :class:`OutputExists` when ``path`` exists: a recording never replaces a file."""
    p = Path(path)
    if _taken(p) and not p.is_dir():
        raise OutputExists(f"{what} {path} exists; a recording never overwrites a file: give a new name "
                              f"or remove it first")


def create_new(path: str | os.PathLike) -> IO[bytes]:
    """Open ``path`` for writing, created here and now (``O_EXCL``): a file that exists is an error."""
    try:
        return open(path, "xb")
    except FileExistsError:
        raise RecordingExists(f"{path} exists (another run writing the same file?); a recording never "
                              f"overwrites a file") from None


def create_beside(path: str | os.PathLike, suffix: str = "") -> tuple[IO[bytes], Path]:
    """A new file in ``path``'s folder under a hidden temporary name (``.NAME.XXXXXXXX.tmp``: not taken for
    a recording), and that name: written there, it is moved to ``path`` by :func:`move_new` once complete,
    or removed by the caller on failure. Created as ``open(path, "wb")`` would create ``path`` (the umask's
    permissions, not a temporary file's 0600). ``suffix`` ends the name (``.tmp.mp4``), for a writer that
    takes the file's kind from its name."""
    p = Path(path)
    while True:
        tmp = p.with_name(f".{p.name}.{secrets.token_hex(4)}.tmp{suffix}")
        try:
            return os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "wb"), tmp
        except FileExistsError:  # a name drawn twice: draw another
            continue


def move_new(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Move the complete file ``tmp`` (:func:`create_beside`) to ``path`` in one step, never over a file there:
    a hard link, which fails on an existing ``path`` (:class:`RecordingExists`, ``tmp`` removed), then the
    temporary name removed; on a file system without hard links, a rename after a last look."""
    appeared = (f"{path} appeared while it was being written; a recording never overwrites a file: give a new "
                f"name or remove it first")
    try:
        os.link(tmp, path)
    except FileExistsError:
        os.unlink(tmp)
        raise RecordingExists(appeared) from None
    except OSError:  # no hard links here (some network and FAT file systems)
        if os.path.lexists(path):
            os.unlink(tmp)
            raise RecordingExists(appeared) from None
        os.rename(tmp, path)
        return
    os.unlink(tmp)



def write_beside(path: str | os.PathLike, write: Callable[[IO[bytes]], None], replace: bool = False) -> None:
    """A file at ``path`` written by ``write(f)`` (``f`` binary) under a hidden temporary name beside it and moved
    there once complete (:func:`create_beside`): never over a file (:func:`move_new`), or with ``replace`` over
    one in one step (``os.replace``). A write that fails midway (a full disk: an OSError naming ``path``) leaves
    no part of the file behind."""
    f, tmp = create_beside(path)
    try:
        with f:
            write(f)
    except OSError as e:
        f.close()  # closed by the with, unless its last flush failed
        tmp.unlink(missing_ok=True)
        raise OSError(e.errno, e.strerror, str(path)) from None
    except BaseException:
        f.close()
        tmp.unlink(missing_ok=True)
        raise
    if replace:
        os.replace(tmp, path)
    else:
        move_new(tmp, path)


def write_text_new(path: str | os.PathLike, write: Callable[[TextIO], None]) -> None:
    """A text file (UTF-8) at ``path`` written by ``write(f)``, as :func:`write_beside` writes one: never over a
    file, and a failed write leaves nothing."""
    import io

    def text(raw: IO[bytes]) -> None:
        buf = io.StringIO(newline="")  # the rows in memory first (a CSV of boxes or points), then one write
        write(buf)
        raw.write(buf.getvalue().encode("utf-8"))

    write_beside(path, text)


_SEGMENT = re.compile(r"^(?P<stem>.+)\.part\d+$")


@dataclass
class StoredRecording:
    """One recording of a folder: its file, its segment files, their bytes and its time."""

    path: Path
    files: list[Path] = field(default_factory=list)
    bytes: int = 0
    mtime: float = 0.0


def folder_recordings(folder: str | os.PathLike) -> list[StoredRecording]:
    """The recordings (``*.mcap``, each with its ``NAME.partN.mcap`` segments and a recorder's
    ``.NAME.mcap.reserve`` left behind) of ``folder``, newest first."""
    d = Path(folder)
    if not d.is_dir():
        return []
    by_stem: dict[str, StoredRecording] = {}
    files = sorted(d.glob("*.mcap"))
    for f in files:  # first the recordings themselves, then their segments
        if _SEGMENT.match(f.stem) is None:
            by_stem[f.stem] = StoredRecording(f)
    for f in files:
        m = _SEGMENT.match(f.stem)
        rec = by_stem.get(m["stem"] if m else f.stem)
        if rec is None:  # a segment whose first file is gone: a recording of its own
            rec = by_stem[f.stem] = StoredRecording(f)
        rec.files.append(f)
    for rec in by_stem.values():
        reserve = rec.path.with_name(f".{rec.path.name}.reserve")
        if reserve.exists():
            rec.files.append(reserve)
        for f in rec.files:
            try:
                st = f.stat()
            except OSError:
                continue
            rec.bytes += st.st_size
            rec.mtime = max(rec.mtime, st.st_mtime)
    return sorted(by_stem.values(), key=lambda r: (r.mtime, r.path.name), reverse=True)


def warn_mb() -> float:
    """``GFLOW_RECORDINGS_WARN_MB`` (MB; 0 turns the warning off), else :data:`WARN_MB`."""
    text = os.environ.get("GFLOW_RECORDINGS_WARN_MB", "").strip()
    if not text:
        return WARN_MB
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not v >= 0:
        raise ValueError(f"GFLOW_RECORDINGS_WARN_MB must be a number of MB >= 0, got {text!r}")
    return v


def size_warning(folder: str | os.PathLike) -> str:
    """A line to tell the user when the recordings of ``folder`` hold more than :func:`warn_mb`
    ("" when they do not)."""
    limit = warn_mb()
    if limit <= 0:
        return ""
    recs = folder_recordings(folder)
    total = sum(r.bytes for r in recs)
    if total <= limit * 1e6:
        return ""
    keep, size = 0, 0
    for r in recs:  # the newest that fit under the limit (at least one)
        if keep and size + r.bytes > limit * 1e6:
            break
        keep, size = keep + 1, size + r.bytes
    return (f"note: {folder} holds {total / 1e6:.0f} MB in {len(recs)} recordings, more than "
            f"GFLOW_RECORDINGS_WARN_MB={limit:g}; `gflow clean {folder} --keep {keep} --dry-run` says what removing "
            f"all but the newest {keep} would free")


def save_figure_new(fig: Any, path: str | os.PathLike, dpi: int) -> None:
    """A matplotlib figure saved as ``path``'s kind (.png, .svg, .pdf), as :func:`write_beside` writes a file:
    never over a file, and a save that fails or is interrupted midway leaves nothing under ``path``."""
    kind = Path(path).suffix[1:].lower() or "png"
    write_beside(path, lambda f: fig.savefig(f, format=kind, dpi=dpi))
