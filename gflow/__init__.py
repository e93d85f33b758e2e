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

from gflow_core.tracker import Estimate

from .errors import GflowError, UnknownParameter, UnusableFrameError
from .track import track
from .tracker import Tracker, trackers


def __getattr__(name: str) -> object:
    """``gflow.TRACKERS``: the names of the registered trackers, the built-in ones and those other
    packages register (entry-point group ``gflow.trackers``), read from the registry each time."""
    if name == "TRACKERS":
        return trackers()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["Tracker", "track", "Estimate", "GflowError", "UnusableFrameError", "UnknownParameter", "TRACKERS"]
