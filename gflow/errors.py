"""The API's exceptions: ``ValueError`` / ``TypeError`` subclasses whose one-line messages are those
``gflow track`` prints for the same mistake."""

from __future__ import annotations

from gflow_core.params import UnknownParameter

__all__ = ["GflowError", "UnusableFrameError", "UnknownParameter"]


class GflowError(ValueError):
    """A mistake in what the tracker was given (a box, a frame, a source, a parameter value)."""


class UnusableFrameError(GflowError):
    """A frame that carries no information for the tracker (uniform, say): it cannot start a track
    (:meth:`gflow.Tracker.init`); :meth:`gflow.Tracker.update` coasts over it instead."""
