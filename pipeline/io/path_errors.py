"""A path the user named that cannot be what it is named for, found when gflow checks it, before the
work it is for: nothing there (:class:`MissingPath`), a folder where a file is wanted
(:class:`FolderForFile`), or a file where a new one is to be written
(:class:`pipeline.io.recording_files.OutputExists`). Each is also the OSError of its case
(FileNotFoundError, IsADirectoryError, FileExistsError), so a caller that catches that goes on
catching it.

``gflow`` reports a :class:`PathMistake` as a mistake in the command (exit status 2). Any other
OSError is the system failing while the work is done (a full disk, a permission refused while
writing, a read failing midway, a file that vanished): a run that failed (exit status 1). Imports
nothing.
"""

from __future__ import annotations

__all__ = ["PathMistake", "MissingPath", "FolderForFile"]


class PathMistake(OSError):
    """A path the user named, refused in one line naming it, before any work is done with it."""


class MissingPath(PathMistake, FileNotFoundError):
    """Nothing there (or, for a folder of images, none in it)."""


class FolderForFile(PathMistake, IsADirectoryError):
    """A folder, where a file is wanted: "X is a folder, not a recording file"."""
