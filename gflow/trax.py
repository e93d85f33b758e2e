"""``python -m gflow.trax`` (``gflow trax``): any gflow tracker as a TraX server, for the VOT toolkit.

TraX (the Visual Tracking eXchange protocol, Čehovin 2017) is how the VOT toolkit and other
evaluation harnesses run a tracker: a process that reads requests on stdin and answers on stdout.
This server speaks it through the ``vot-trax`` package (``trax.server.Server``; install it with
``pip install 'gflow[vot]'``) and tracks with :class:`gflow.Tracker`, so it runs no stage
process and gives, for one seed, the boxes of ``gflow track --inline --seed SEED`` bit for bit.

The session, request by request:

* ``hello`` (the server's): regions ``rectangle`` and ``polygon``; images ``path``, ``memory``
  and ``buffer``; the ``color`` channel; one object per session.
* ``initialize``: a new ``Tracker(name, seed, **params)`` is started on the image from the
  region's box: a rectangle as it is, a polygon as its bounding box ``(min x, min y, max x - min
  x, max y - min y)`` (the toolkit's own conversion). Each ``initialize`` is a new track whose
  frames count from 0, as a sequence given to ``gflow track`` does: the toolkit's
  re-initialisation after a failure (its supervised experiment) is one more ``initialize``.
  The region's numbers are read as the client wrote them (TraX writes 4 decimals).
* ``frame``: the next image; the answer is the estimate's box with the properties
  ``confidence`` (in [0, 1]), ``state`` (``tracked``, ``occluded``, ``lost``) and ``phase``.
  The toolkit keeps every property beside its trajectory (``confidence`` is the one its
  long-term analyses read).
* ``quit``: the server ends, status 0.

A first image that carries no information (uniform) cannot start a track; as ``gflow track``
does, the server then answers with the given box (confidence 0, state ``lost``) and starts the
track on the first usable image after it, from the same box.

A request the server cannot serve (an image that is missing or cannot be decoded, a region
that is not a rectangle or a polygon, a box outside the image, a frame before any
``initialize``, an image of another size) is answered with TraX's error: a ``quit`` whose reason
names what was wrong (the client raises it as ``TraxException``). The server then prints that
reason as one line on stderr and exits with status 1. Nothing is written to stdout but the
protocol (``print`` goes to stderr while the server runs).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from typing import IO, Any, Callable, Mapping

import numpy as np

from gflow_core.tracker import Box, Estimate

from pipeline.cli.commands.trax import INSTALL_HINT

from .errors import GflowError, UnusableFrameError
from .tracker import Tracker

__all__ = ["RequestError", "box_of_region", "frame_of_image", "TraxSession", "serve", "main", "INSTALL_HINT"]

class RequestError(Exception):
    """A request the server cannot serve; its message is the reason of the TraX ``quit`` it gets."""


def _decimals(v: float) -> float:
    """A TraX number as the client wrote it (the protocol writes ``%.4f``; the library hands it
    over as a C float)."""
    return float(f"{v:.4f}")


def box_of_region(region: Any) -> Box:
    """``(x, y, w, h)`` of a TraX region: a rectangle's own numbers, a polygon's bounding box.

    Raises
    ------
    RequestError
        Another kind of region (a mask, a special code), a polygon of fewer than three points,
        or numbers that are not finite.
    """
    kind = getattr(region, "type", None)
    if kind == "rectangle":
        x, y, w, h = (_decimals(v) for v in region.bounds())
    elif kind == "polygon":
        pts = [region.get(i) for i in range(region.size())]
        if len(pts) < 3:
            raise RequestError(f"a polygon region needs at least 3 points, got {len(pts)}")
        xs = [_decimals(p[0]) for p in pts]
        ys = [_decimals(p[1]) for p in pts]
        # the bounding box: (min x, min y, max x - min x, max y - min y), in the client's 4 decimals
        x, y, w, h = min(xs), min(ys), _decimals(max(xs) - min(xs)), _decimals(max(ys) - min(ys))
    else:
        raise RequestError(f"region of type {kind or type(region).__name__}: this tracker takes a rectangle or a "
                           "polygon (its bounding box)")
    if not all(math.isfinite(v) for v in (x, y, w, h)):
        raise RequestError("region has NaN or inf")
    if w <= 0 or h <= 0:
        raise RequestError(f"region has no area (w={w:g}, h={h:g})")
    return x, y, w, h


def _decode(data: np.ndarray, what: str) -> np.ndarray:
    """An encoded image (JPEG, PNG, ...) as the source stage decodes a folder's frames: 3-channel
    BGR, whatever the file holds (``pipeline/io/frame_readers.py``)."""
    import cv2

    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if img is None:
        raise RequestError(f"{what} is not a decodable image ({data.size} bytes)")
    return img


def frame_of_image(images: Mapping[str, Any]) -> np.ndarray:
    """The colour image of a request as ``(H, W, 3)`` BGR uint8, as ``gflow track`` reads frames.

    A ``path`` is read and decoded as an image folder's frames are; a ``memory`` image (the
    protocol's RGB or 8-bit grey) is turned into BGR; a ``buffer`` (an encoded JPEG or PNG) is
    decoded.

    Raises
    ------
    RequestError
        No colour image, a file that is missing or cannot be decoded, a 16-bit image.
    """
    import cv2

    img = images.get("color") if images else None
    if img is None:
        raise RequestError("the request has no colour image")
    kind = img.type()
    if kind == "path":
        path = img.path()
        try:
            data = np.fromfile(path, dtype=np.uint8)
        except OSError as e:
            raise RequestError(f"cannot read image {path}: {e.strerror or e}") from None
        return _decode(data, path)
    if kind == "buffer":
        return _decode(np.frombuffer(img.buffer(), dtype=np.uint8), "the image buffer")
    if kind == "memory":
        arr = np.asarray(img.array())
        if arr.dtype != np.uint8:
            raise RequestError(f"memory image of {arr.dtype}: this tracker takes 8-bit RGB or grey images")
        if arr.ndim == 3 and arr.shape[2] == 1:
            return cv2.cvtColor(arr[:, :, 0], cv2.COLOR_GRAY2BGR)
        return cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
    raise RequestError(f"image of type {kind}: this tracker takes a path, a memory image or an encoded buffer")


#: a tracker made for each ``initialize``: () -> Tracker
TrackerFactory = Callable[[], Tracker]


class TraxSession:
    """The tracking half of the server, one request at a time, free of the protocol library (so it
    can be driven directly).

    Parameters
    ----------
    make : () -> Tracker
        A new tracker for each ``initialize`` (``Tracker(name, seed, **params)``).
    out : text file, optional
        Where to write the boxes served as ``gflow track --out`` writes them
        (``frame,x,y,w,h,confidence,state``), a row as each is answered; a row's frame is the
        image's index in the session (0: the first ``initialize``'s).
    """

    def __init__(self, make: TrackerFactory, out: IO[str] | None = None) -> None:
        self.make = make
        self.tracker: Tracker | None = None
        self.pending: Box | None = None  # the box of an initialize whose image could not start a track
        self.images = 0  # images received in the session
        self._t = 0  # index of the current image in its track (0: the initialize's)
        self._out = csv.writer(out, lineterminator="\n") if out is not None else None  # as gflow track's CSV
        self._file = out
        if self._out is not None:
            self._out.writerow(["frame", "x", "y", "w", "h", "confidence", "state"])

    def initialize(self, image: np.ndarray, box: Box) -> tuple[Box, dict[str, str]]:
        """Start a new track on ``image`` from ``box``; the answer's box and properties."""
        self.tracker, self.pending, self._t = self.make(), None, 0
        return self._start(image, box)

    def frame(self, image: np.ndarray) -> tuple[Box, dict[str, str]]:
        """Track into the next image; the answer's box and properties."""
        if self.tracker is None:
            raise RequestError("a frame before any initialize: send initialize with the target's region first")
        self._t += 1
        if self.pending is not None:
            return self._start(image, self.pending)
        try:
            est = self.tracker.update(image)
        except GflowError as e:
            raise RequestError(str(e)) from None
        return self._answer(est)

    def _start(self, image: np.ndarray, box: Box) -> tuple[Box, dict[str, str]]:
        assert self.tracker is not None
        try:
            est = self.tracker.init(image, box, frame_index=self._t)
        except UnusableFrameError:
            # as gflow track: the track starts on the first usable image, from the same box
            self.pending = box
            self.images += 1
            return box, {"confidence": "0", "state": "lost", "phase": "waiting"}
        except GflowError as e:
            raise RequestError(str(e)) from None
        self.pending = None
        return self._answer(est)

    def _answer(self, est: Estimate) -> tuple[Box, dict[str, str]]:
        if self._out is not None:
            self._out.writerow([self.images, *(f"{v:.2f}" for v in est.box), f"{est.confidence:.3f}",
                                est.target_state])
            assert self._file is not None
            self._file.flush()
        self.images += 1
        return est.box, {"confidence": repr(float(est.confidence)), "state": est.target_state, "phase": est.phase}


def serve(make: TrackerFactory, out: IO[str] | None = None, name: str = "gflow") -> int:
    """Serve TraX on stdin / stdout (or the socket the client names in ``TRAX_SOCKET``) until the
    client quits. Returns the exit status: 0 after ``quit``, 1 after an error (told to the client
    as the reason of a ``quit``, and printed on stderr in one line)."""
    from trax import Image, Region, TraxException, TraxStatus
    from trax.region import Rectangle
    from trax.server import Server

    session = TraxSession(make, out)
    server = Server([Region.RECTANGLE, Region.POLYGON], [Image.PATH, Image.MEMORY, Image.BUFFER],
                    tracker_name=name, tracker_description="gflow (Python API, no stage processes)",
                    tracker_family="gflow")
    while True:
        try:
            request = server.wait()
        except TraxException as e:
            # a malformed message (the library has answered it with quit) or the client gone
            why = str(e).removeprefix("Exception when waiting for command: ")
            _say(f"the client's request could not be read ({why}): the session ends")
            return 1
        if request.type == TraxStatus.QUIT:
            server.quit()
            return 0
        try:
            image = frame_of_image(request.image)
            if request.type == TraxStatus.INITIALIZE:
                if len(request.objects) != 1:
                    raise RequestError(f"initialize with {len(request.objects)} objects: this tracker follows one")
                box, props = session.initialize(image, box_of_region(request.objects[0][0]))
            elif request.objects:
                raise RequestError("a frame with new objects: this tracker follows one; send initialize instead")
            else:
                box, props = session.frame(image)
        except RequestError as e:
            return _refuse(server, str(e))
        except Exception as e:  # noqa: BLE001 - a bug: the client is told, the user gets one line
            return _refuse(server, f"internal error: {type(e).__name__}: {e} (a bug in gflow)")
        server.status([(Rectangle.create(*box), props)])


def _refuse(server: Any, reason: str) -> int:
    reason = " ".join(reason.split())
    try:
        server.quit(reason=reason)
    except Exception:  # noqa: BLE001 - the client may be gone already; the reason is still printed
        pass
    _say(reason)
    return 1


def _say(line: str) -> None:
    print(f"gflow trax: error: {line}", file=sys.__stderr__, flush=True)


def tracker_factory(name: str | None, seed: int, params: Mapping[str, Any]) -> tuple[str, TrackerFactory]:
    """The tracker's name (``None``: the API's default tracker) and ``() -> Tracker(name, seed,
    **params)``, after making one to check the name and parameters (raises ``GflowError`` /
    ``UnknownParameter`` with ``gflow track``'s one-line messages)."""
    name = (Tracker(name, seed, **params) if name else Tracker(seed=seed, **params)).name
    return name, lambda: Tracker(name, seed, **params)


def main(argv: list[str] | None = None) -> int:
    """``python -m gflow.trax [--tracker NAME] [--seed N] [--model FILE] [--set NAME=VALUE]... [--out CSV]``."""
    from gflow_core.params import UnknownParameter

    from pipeline.cli.commands.common import CliError
    from pipeline.cli.commands.trax import add_trax_args, tracker_params

    ap = argparse.ArgumentParser(prog="python -m gflow.trax", description=(__doc__ or "").splitlines()[0])
    add_trax_args(ap)
    args = ap.parse_args(argv)
    try:
        import trax  # noqa: F401 - the protocol library, an optional dependency
    except ImportError:
        _say(f"the TraX library (package vot-trax) is not installed: {INSTALL_HINT}")
        return 2
    try:
        name, make = tracker_factory(args.tracker, args.seed, tracker_params(args))
        out = open(args.out, "w", newline="") if args.out else None
    except (CliError, GflowError, UnknownParameter) as e:
        _say(" ".join(str(e).split()))
        return 2
    except OSError as e:
        _say(f"--out {args.out}: {e.strerror or e}")
        return 2
    stdout, sys.stdout = sys.stdout, sys.stderr  # stdout carries the protocol alone
    try:
        return serve(make, out, name=f"gflow-{name}")
    except KeyboardInterrupt:
        _say("interrupted")
        return 130
    finally:
        sys.stdout = stdout
        if out is not None:
            out.close()


if __name__ == "__main__":
    sys.exit(main())
