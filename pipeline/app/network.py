"""Where a run's launcher listens when not told (:func:`default_listen`) and a run's zenoh settings when none
are given (:func:`default_zenoh`): apart from :mod:`pipeline.app.graph_run`, so that ``gflow track`` makes its
request (and says a mistake found in it) without importing what runs a graph (the messages, the graph loader, the
stages)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pipeline.runtime.transport import ZenohSettings

__all__ = ["DEFAULT_ENDPOINT", "default_listen", "default_zenoh"]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def default_listen() -> tuple[str, ...]:
    """Where a launcher listens unless told: 7447 on loopback (so `gflow topics` finds the run), or
    a free port when 7447 is busy."""
    import socket

    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", 7447))
            return (DEFAULT_ENDPOINT,)
        except OSError:
            from pipeline.runtime.transport import free_port

            return (f"tcp/127.0.0.1:{free_port()}",)


def default_zenoh() -> ZenohSettings:
    """A run's zenoh settings when none are given: peer mode on loopback, multicast scouting off."""
    from pipeline.runtime.transport import ZenohSettings

    return ZenohSettings(mode="peer", listen=default_listen(), connect=(), multicast=False, security=None)
