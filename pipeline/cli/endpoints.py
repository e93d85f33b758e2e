"""A zenoh endpoint as the command line takes it (``--listen``, ``--connect``, a security file's
endpoints), checked before zenoh sees it."""

from __future__ import annotations

import argparse
import re

_ENDPOINT = re.compile(r"^(?P<proto>[a-z][a-z0-9-]*)/(?P<addr>[^\s?#]+)(\?[^\s#]*)?(#\S*)?$")
_HOST_PORT = re.compile(r"^(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


def parse_endpoint(text: str) -> str:
    """A zenoh endpoint ``PROTO/HOST:PORT`` (e.g. tcp/127.0.0.1:7447), checked before zenoh sees it.
    A bare ``HOST:PORT`` is kept as it is: :func:`pipeline.cli.security_options.apply_security` makes it
    ``tls/`` or ``tcp/``."""
    hp = _HOST_PORT.match(text.strip())
    if hp is not None and "/" not in text and 0 <= int(hp.group(2)) <= 65535:
        return text.strip()
    m = _ENDPOINT.match(text.strip())
    if m is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a zenoh endpoint; expected PROTO/HOST:PORT, "
                                         f"e.g. tcp/127.0.0.1:7447")
    if m["proto"] in ("tcp", "udp", "tls", "quic", "ws"):
        hp = _HOST_PORT.match(m["addr"])
        if hp is None or not 0 <= int(hp.group(2)) <= 65535:
            raise argparse.ArgumentTypeError(f"{text!r}: a {m['proto']} endpoint needs HOST:PORT with a port "
                                             f"0..65535, e.g. {m['proto']}/127.0.0.1:7447")
    return text.strip()
