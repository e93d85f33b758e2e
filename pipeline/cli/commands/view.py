"""``gflow view``: serve a live pipeline to the Foxglove app over its WebSocket protocol."""

from __future__ import annotations

ORDER = 62

import argparse
import sys
import time

from pipeline.cli.commands.common import CliError, add_zenoh_args, positive_float, positive_int, stream_name, tool_zenoh


def tcp_port(text: str) -> int:
    """A TCP port, 1-65535 (argparse type)."""
    v = positive_int(text)
    if v > 65535:
        raise argparse.ArgumentTypeError(f"a port is 1-65535, got {v}")
    return v


def _refuse_port_in_use(host: str, port: int) -> None:
    """Refuse, before waiting for a pipeline, a ``--host``/``--port`` that cannot be served on (another program
    holds the port, or the address is not this machine's): it was said only once a pipeline had started."""
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a server binds it (TIME_WAIT is no owner)
            s.bind((host, port))
    except OSError as e:
        raise CliError(f"cannot serve on {host}:{port}: {e.strerror or e}") from None


def _await_run(args, end: float | None) -> bool:
    """Wait for a pipeline (of ``--stream``: the run's stream or its graph's) to be announced on
    this machine, until ``end`` (None: until Ctrl-C); True when one runs. With ``--connect`` the
    user's endpoints are used as they are. A Ctrl-C meanwhile is an interruption (``gflow view:
    interrupted``, exit status 130, as ``gflow echo`` and ``gflow hz`` waiting say), not a wait
    that ran out."""
    from pipeline.runtime.running import await_running

    if args.connect or args.mode == "router" or args.multicast or await_running(args.stream, until=time.monotonic()):
        return True
    print("gflow view: waiting for a pipeline to start" + (f" with stream {args.stream}" if args.stream else "")
          + " (Ctrl-C stops)", file=sys.stderr, flush=True)
    return await_running(args.stream, until=end)


def cmd_view(args) -> int:
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise CliError("gflow view needs the foxglove-sdk package: pip install foxglove-sdk") from None
    from pipeline.cli.foxglove_bridge import FoxgloveBridge

    _refuse_port_in_use(args.host, args.port)
    end = None if args.duration is None else time.monotonic() + args.duration
    from pipeline.runtime.running import runs_of_camera, running

    if not _await_run(args, end):
        others = sorted({str(i.get("stream")) for i in running()}) if args.stream else []
        print("gflow view: no pipeline started" + (f" with stream {args.stream}" if args.stream else "")
              + (f"; running: {', '.join(others)}" if others else ""), file=sys.stderr)
        return 1

    if args.stream and not running(args.stream) and len(runs_of_camera(args.stream)) == 1:
        args.stream = runs_of_camera(args.stream)[0]["stream"]  # the graph's stream (cam0): its run
    settings, found = tool_zenoh(args, args.stream)
    streams = sorted({i["stream"] for i in found})
    stream = args.stream or (streams[0] if len(streams) == 1 else None)
    try:
        bridge = FoxgloveBridge(settings, stream=stream, host=args.host, port=args.port).start()
    except RuntimeError as e:  # the port is taken, say
        raise CliError(f"cannot serve on {args.host}:{args.port}: {e}") from None
    try:  # the ready line inside the try: a Ctrl-C right after it still stops the bridge
        s = stream or "STREAM"
        print(f"Foxglove: open {bridge.url} (Open connection -> Foxglove WebSocket); Image panel on "
              f"/gflow/{s}/frames with annotations /gflow/{s}/box (with a render stage also /gflow/{s}/image "
              f"and /gflow/{s}/annotations); Ctrl-C stops", file=sys.stderr, flush=True)
        while end is None or time.monotonic() < end:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        bridge.stop()
    n = sum(bridge.forwarded.values())
    print(f"forwarded {n} messages on {len(bridge.forwarded)} topics ("
          + ", ".join(f"{t} {c}" for t, c in sorted(bridge.forwarded.items())) + ")"
          + (f"; dropped {bridge.dropped} while busy" if bridge.dropped else ""), file=sys.stderr)
    for t, why in sorted(bridge.failed.items()):
        print(f"could not forward {t}: {why}", file=sys.stderr)
    return 0


def register(sub) -> None:
    p = sub.add_parser("view", help="show a live pipeline in Foxglove (WebSocket server, ws://127.0.0.1:8765)",
                       description="Serves the live topics over Foxglove's WebSocket protocol (foxglove-sdk): the "
                                   "render stage's video and overlays, and the estimate, errors and every stage's "
                                   "heartbeat as JSON (plot e.g. /gflow/demo/estimate.ess), the source's frames as images "
                                   "and each estimate's box as image annotations (/gflow/STREAM/box), whatever started "
                                   "the run. Started before the run, it waits for it. Features and "
                                   "particles are not forwarded. In the Foxglove app: Open connection -> Foxglove "
                                   "WebSocket -> ws://HOST:PORT.")
    p.add_argument("--stream", type=stream_name, help="the pipeline's stream (default: the one running)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1; 0.0.0.0 for other machines)")
    p.add_argument("--port", type=tcp_port, default=8765, help="WebSocket port (default 8765, Foxglove's)")
    p.add_argument("--duration", type=positive_float, help="stop after this many seconds (default: until Ctrl-C)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_view)
