"""The error of a request that cannot run: a module that imports nothing, so that the ``gflow``
command can name it at start-up without importing the application layer."""

from __future__ import annotations

__all__ = ["RequestError"]


class RequestError(Exception):
    """A request that cannot run, said in one line naming what is wrong (``gflow``: exit status 2)."""
