"""A path the user named that cannot be what it is named for, found when gflow checks it, before the
work it is for: nothing there (:class:`MissingPath`), a folder where a file is wanted
(:class:`FolderForFile`), or a file where a new one is to be written
(:class:`pipeline.io.recording_files.OutputExists`). Each is also the OSError of its case
(FileNotFoundError, IsADirectoryError, FileExistsError), so a caller that catches that goes on
catching it. :func:`dangling_link` says why an output named by a symbolic link to nothing is refused.

``gflow`` reports a :class:`PathMistake` as a mistake in the command (exit status 2). Any other
OSError is the system failing while the work is done (a full disk, a permission refused while
writing, a read failing midway, a file that vanished): a run that failed (exit status 1). Imports
nothing.
"""

from __future__ import annotations

__all__ = ["PathMistake", "MissingPath", "FolderForFile", "dangling_link"]


class PathMistake(OSError):
    """A path the user named, refused in one line naming it, before any work is done with it."""


class MissingPath(PathMistake, FileNotFoundError):
    """Nothing there (or, for a folder of images, none in it)."""


class FolderForFile(PathMistake, IsADirectoryError):
    """A folder, where a file is wanted: "X is a folder, not a recording file"."""


def dangling_link(path: str, what: str) -> str:
    """Why the output ``what`` (``--out``, ``OUT``...) named ``path`` cannot be written when ``path`` is a
    symbolic link to nothing, else "". Such a link is no file to write over, yet a new file cannot be made
    under its name (the system says only 'File exists'), and writing through it would put the output
    wherever the link points; it is refused in one line naming it and its target, as an output that exists is."""
    import os

    if not os.path.islink(path) or os.path.exists(path):
        return ""
    return (f"{what} {path} is a dangling symbolic link (to {os.readlink(path)}, which does not exist); gflow does "
            f"not write through it: remove it or give another name")
