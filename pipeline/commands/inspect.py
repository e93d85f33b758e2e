"""``gflow topics``, ``gflow echo``, ``gflow hz``: look at a live pipeline."""

from __future__ import annotations

ORDER = 60

from .common import add_zenoh_args, zenoh_from_args


def _key(topic: str) -> str:
    return topic if topic.startswith("gflow/") else f"gflow/{topic}"


def cmd_topics(args) -> int:
    from ..live import list_topics

    list_topics(zenoh_from_args(args, default_connect=True), args.duration)
    return 0


def cmd_echo(args) -> int:
    from ..live import echo

    echo(zenoh_from_args(args, default_connect=True), _key(args.topic), args.count, args.timeout)
    return 0


def cmd_hz(args) -> int:
    from ..live import hz

    hz(zenoh_from_args(args, default_connect=True), _key(args.topic), args.duration)
    return 0


def register(sub) -> None:
    p = sub.add_parser("topics", help="list the topics of a live pipeline")
    p.add_argument("--duration", type=float, default=2.0, help="seconds to listen (default 2)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_topics)

    p = sub.add_parser("echo", help="print the messages on a live topic")
    p.add_argument("topic", help="key expression, e.g. gflow/cam0/estimate or cam0/**")
    p.add_argument("-n", "--count", type=int, help="stop after N messages")
    p.add_argument("--timeout", type=float, help="stop after this many seconds")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_echo)

    p = sub.add_parser("hz", help="measure the rate of a live topic")
    p.add_argument("topic", help="key expression, e.g. gflow/cam0/frames")
    p.add_argument("--duration", type=float, default=3.0, help="seconds to measure (default 3)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_hz)
