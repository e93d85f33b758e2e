"""Recording files are never overwritten.

* A default recording name carries the time and the run id (``recordings/track-20250101-120000-3f9c2a.mcap``),
  and a suffix (``-2``, ``-3``...) when that name is taken: two runs started in the same second
  get two files (:func:`unique_path`).
* The recorder creates its file exclusively (``O_EXCL``, :func:`create_new`): should two writers
  still be given one name, the second one fails with a one-line error instead of destroying the
  first one's file.
* ``--record FILE`` naming a file that exists is refused before the run starts (:func:`refuse_existing`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO

__all__ = ["RecordingExists", "unique_path", "create_new", "refuse_existing"]


class RecordingExists(FileExistsError):
    """A recording would overwrite a file that exists."""


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
    """A :class:`RecordingExists` when ``path`` exists: a recording never replaces a file."""
    p = Path(path)
    if _taken(p) and not p.is_dir():
        raise RecordingExists(f"{what} {path} exists; a recording never overwrites a file: give a new name "
                              f"or remove it first")


def create_new(path: str | os.PathLike) -> IO[bytes]:
    """Open ``path`` for writing, created here and now (``O_EXCL``): a file that exists is an error."""
    try:
        return open(path, "xb")
    except FileExistsError:
        raise RecordingExists(f"{path} exists (another run writing the same file?); a recording never "
                              f"overwrites a file") from None
