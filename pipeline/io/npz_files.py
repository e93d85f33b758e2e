"""Reading ``.npz`` archives a user names (model files, landmark files, AVLetters files) in one place: every array
read at once, no pickle ever loaded (``allow_pickle=False``), and every way the file can be other than an archive
of plain arrays (empty, a single ``.npy`` array, text, cut short, damaged inside, compressed by a method zipfile does
not read, pickled arrays) a one-line ValueError naming the file and what it was given as.
"""

from __future__ import annotations

import io
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

__all__ = ["npz_problem", "read_npz"]

#: what reading a damaged archive raises: zipfile's own errors, and a header whose method a damaged byte changed
#: (NotImplementedError: a compression it does not read); a member flagged encrypted (RuntimeError) is taken apart,
#: and an OSError is said as what it is (the disk, or an offset sent past the file), not called damage
_DAMAGE = (zipfile.BadZipFile, zlib.error, EOFError, KeyError, io.UnsupportedOperation, NotImplementedError)


def npz_problem(path: str | os.PathLike) -> str:
    """What a file named for an ``.npz`` archive is instead, from its first bytes ("an empty file", "a single .npy
    array", "not a zip archive"), or "" when it starts as a zip archive does (it may still be cut short or damaged
    further on, which reading it finds)."""
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic == b"PK\x03\x04":
        return ""
    return "an empty file" if not magic else ("a single .npy array" if magic.startswith(b"\x93NUM") else
                                              "not a zip archive")


def read_npz(path: str | os.PathLike, what: str) -> dict[str, np.ndarray]:
    """Every array of the archive ``path``, read now (a truncated or damaged member fails here, not later).

    Parameters
    ----------
    path : an existing file.
    what : what the file was given as, in messages ("model file", "landmark file").

    Raises
    ------
    ValueError
        Not an archive, a damaged one, or one holding pickled (object) arrays; the message names the file.
    """
    p = Path(path)
    problem = npz_problem(p)
    if problem:
        raise ValueError(f"{p}: not a {what} (.npz archive): it is {problem}")
    try:
        with np.load(p, allow_pickle=False) as npz:
            return {k: np.asarray(npz[k]) for k in npz.files}
    except ValueError as e:
        if "allow_pickle" in str(e) or "Object arrays" in str(e) or "pickled" in str(e):
            raise ValueError(f"{p}: holds pickled (object) arrays, which are not accepted in {what}s") from None
        raise ValueError(f"{p}: not a readable {what} (corrupt or truncated npz: {e})") from None
    except _DAMAGE as e:
        raise ValueError(f"{p}: not a readable {what} (corrupt or truncated npz: {type(e).__name__}: {e})") from None
    except RuntimeError as e:  # zipfile's only RuntimeError on reading: a member flagged encrypted
        if "encrypted" not in str(e):
            raise
        raise ValueError(f"{p}: not a readable {what} (corrupt or truncated npz: {e})") from None
    except OSError as e:  # the disk, or a damaged offset sent past the file: the file named, not called damaged
        raise OSError(e.errno, f"{p}: cannot read the {what}: {e.strerror or e}") from None
