"""Start-up timestamps for ``bench/bench_startup.py``: with ``GFLOW_STARTUP_TRACE=FILE`` set, the
CLI, the launcher and every stage process append ``WALL_NS PID LABEL`` lines to FILE (one
``write`` on an ``O_APPEND`` file each, so lines from several processes do not mix). Without
the variable, :func:`mark` is a dictionary look-up. Imports nothing but ``os`` and ``time``."""

from __future__ import annotations

import os
import time

__all__ = ["mark"]


def mark(label: str, t_ns: int | None = None) -> None:
    """Append ``label`` with the wall time now (or ``t_ns``) when start-up tracing is on."""
    path = os.environ.get("GFLOW_STARTUP_TRACE")
    if not path:
        return
    line = f"{time.time_ns() if t_ns is None else t_ns} {os.getpid()} {label}\n".encode()
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        try:
            os.write(fd, line)
        finally:
            os.close(fd)
    except OSError:
        pass
