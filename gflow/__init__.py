"""gflow's Python API: track one object through frames you hand it, or through any source.

>>> from gflow import Tracker, track
>>> t = Tracker("gflow", seed=1)            # doctest: +SKIP
>>> est = t.init(frame, (x, y, w, h))       # doctest: +SKIP
>>> est = t.update(next_frame)              # doctest: +SKIP
>>> for est in track("video.mp4", init=(x, y, w, h), tracker="appearance"):  # doctest: +SKIP
...     print(est.frame, est.box, est.confidence, est.target_state)

Frames are numpy arrays as OpenCV gives them (``(H, W, 3)`` BGR or ``(H, W)`` grey, uint8). Each
estimate carries the box ``(x, y, w, h)``, the ``confidence``, the ``target_state`` (tracked,
occluded, lost), the ``phase`` (init, track, coast) and the tracker's ``extras``. With the same
seed the boxes are those of ``gflow track --seed SEED`` bit for bit. Errors are ``GflowError``
(a ``ValueError``) or ``UnknownParameter`` (a ``TypeError``), with ``gflow track``'s messages.
See ``docs/python-api.md``.
"""

import sys as _sys
import warnings as _warnings

from pipeline.runtime.instruction_sets import cpu_flags as _cpu_flags
from pipeline.runtime.instruction_sets import hold as _hold

# numpy, OpenCV and OpenBLAS held to the instruction sets of x86-64-v3 before they load, as in every
# gflow command, so the API's boxes are the commands' bit for bit on any machine
# (pipeline/runtime/instruction_sets.py); too late for a numpy imported already
_numpy_first = "numpy" in _sys.modules
if _hold() and _numpy_first and "avx512f" in _cpu_flags():
    _warnings.warn("numpy was imported before gflow on this machine with AVX-512: its kernels may differ in the "
                   "last bits from those of gflow's commands; import gflow first for the same boxes",
                   RuntimeWarning, stacklevel=2)

from gflow_core.tracker import Estimate  # noqa: E402

from .errors import GflowError, UnknownParameter, UnusableFrameError  # noqa: E402
from .track import track  # noqa: E402
from .tracker import Tracker, trackers  # noqa: E402


def __getattr__(name: str) -> object:
    """``gflow.TRACKERS``: the names of the registered trackers, the built-in ones and those other
    packages register (entry-point group ``gflow.trackers``), read from the registry each time."""
    if name == "TRACKERS":
        return trackers()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["Tracker", "track", "Estimate", "GflowError", "UnusableFrameError", "UnknownParameter", "TRACKERS"]
