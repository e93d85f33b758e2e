"""Where the warning of damage inside a recording goes (:func:`pipeline.io.mcap_io._say_damage`).

A reader that meets a record that fails with more of the file after it warns once per file, at once, in a
log line. The ``gflow`` command instead keeps the warning until the command ends (:func:`defer`), and then
says it only when the command's last word did not already (:func:`flush`): a command that fails because
of the damage names it in its error, and a command that made something of the part before it names it in
the line saying so, so the damage is said in one line, not twice. Imports nothing but logging.
"""

from __future__ import annotations

import logging

__all__ = ["defer", "deferred", "keep", "told", "flush"]

_pending: list[str] | None = None


def defer() -> None:
    """Keep the damage warnings from now on, until :func:`flush` (``gflow``: for the command's run)."""
    global _pending
    _pending = []


def deferred() -> bool:
    """Whether the warnings are kept for :func:`flush` rather than logged at once."""
    return _pending is not None


def keep(text: str) -> None:
    """A damage warning: kept when deferred, else logged at once."""
    if _pending is None:
        logging.getLogger("gflow.recording").warning("%s", text)
    elif text not in _pending:
        _pending.append(text)


def told(text: str) -> None:
    """``text`` was said by the command itself (in a line of its own words): not to be warned again."""
    if _pending is not None and text in _pending:
        _pending.remove(text)


def flush(said: str = "") -> None:
    """Log the kept warnings that ``said`` (the command's last line, as printed) does not hold already; from
    now on warnings are logged at once again."""
    global _pending
    pending, _pending = _pending or [], None
    plain = " ".join(said.split())
    for text in pending:
        if " ".join(text.split()) not in plain:
            logging.getLogger("gflow.recording").warning("%s", text)
