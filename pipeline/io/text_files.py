"""Reading the text files a user names: graphs, security and router configurations, password and user lists.

A file that is not UTF-8 text (a recording, a picture or a key given for one, or text saved in another encoding) is
refused in one line naming the file, what it was given as and where its first byte that is not text is; before, the
decoder's own words ("'utf-8' codec can't decode byte 0x80 in position 128") were all a user saw, with no file named.
Imports nothing of gflow.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

__all__ = ["read_text"]


def read_text(path: str | os.PathLike, what: str, error: Callable[[str], Exception] = ValueError) -> str:
    """The text of ``path``, read as UTF-8 (a leading byte-order mark, as some editors write, dropped).

    Parameters
    ----------
    path : the file.
    what : what the file was given as, in the message ("graph file", "password file").
    error : makes the exception raised for a file that is not UTF-8 text from its one-line message (the caller's
        kind of error: a GraphError, a SecurityError...).

    Raises
    ------
    OSError
        The file cannot be read (missing, a folder, no permission), as :meth:`Path.read_text` raises it.
    ``error(message)``
        The file is not UTF-8 text; the message names the file and the offset of its first byte that is not.
    """
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise error(f"{p}: not a {what} (UTF-8 text): byte {e.object[e.start]:#04x} at offset {e.start} is not "
                    f"text") from None
