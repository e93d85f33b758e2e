"""``gflow router``: a zenoh router (no other binary needed), with TLS, logins and access control."""

from __future__ import annotations

ORDER = 75

import argparse
import sys
import threading

from pipeline.cli.commands.common import CliError
from pipeline.runtime.signals import StopSignals

EXAMPLE = """\
example (router.yaml; paths are relative to the file):

  listen: [tls/0.0.0.0:7447]
  tls: {cert: router.pem, key: router.key, ca: ca.pem, mtls: true}
  users: {cam: cam-secret}           # or users_file: users.txt (user:password lines)
  acl:
    publishers:                      # only these may publish gflow/<stream>/**
      - {streams: ["*"], cert_common_names: [gflow-pipeline]}
    readers: anyone                  # anyone | none | {usernames: [...], cert_common_names: [...]}

  gflow router router.yaml
  gflow router --listen tcp/0.0.0.0:7447              (no file: plain TCP, no login)
  gflow router router.yaml --print-config             (the zenoh configuration, then exit)

and on the hosts of the pipeline:

  gflow run graph.yaml --mode client --connect ROUTER:7447 --tls-ca ca.pem \\
      --tls-cert pipeline.pem --tls-key pipeline.key --run-key deployment.key

See docs/security.md."""


def cmd_router(args) -> int:
    import json

    from pipeline.runtime.router import Router, load_router_config, zenoh_config

    if not args.config and not args.listen:
        raise CliError("give a router config file or --listen ENDPOINT (see 'gflow router --help')")
    cfg = load_router_config(args.config, listen=args.listen, tls_cert=args.tls_cert, tls_key=args.tls_key,
                             tls_ca=args.tls_ca, mtls=args.mtls, users_file=args.users_file)
    if args.print_config:
        print(json.dumps(zenoh_config(cfg), indent=2))
        return 0
    if args.zenoh_log:
        import zenoh

        zenoh.init_log_from_env_or(args.zenoh_log)  # refused handshakes and logins show at warn
    stop = threading.Event()
    # Ctrl-C, SIGTERM, SIGHUP on a sigwait thread, not a Python handler setting the Event (which
    # deadlocks when the signal lands while this thread holds the Event's lock, in stop.wait);
    # taken before the router opens, so zenoh's threads block them too
    with StopSignals(lambda _: stop.set()), Router(cfg):
        print(f"gflow router: {cfg.describe()} (Ctrl-C to stop)", file=sys.stderr, flush=True)
        stop.wait()
    print("gflow router: stopped", file=sys.stderr)
    return 0


def register(sub) -> None:
    p = sub.add_parser("router", help="run a zenoh router (TLS, logins, access control) for gflow across hosts",
                       description="Run a zenoh router in this process: the meeting point of a deployment across "
                                   "hosts. Stages and tools connect to it with --mode client --connect HOST:PORT. "
                                   "Everything comes from one YAML file; the options override it.",
                       epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", nargs="?", help="router config file (YAML): listen, tls, users, acl")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tls/0.0.0.0:7447 (repeatable; replaces the file's)")
    p.add_argument("--tls-cert", metavar="FILE", help="the router's certificate (PEM), for tls/ endpoints")
    p.add_argument("--tls-key", metavar="FILE", help="its private key (PEM)")
    p.add_argument("--tls-ca", metavar="FILE", help="CA certificate that signed the clients' certificates")
    p.add_argument("--mtls", action="store_true", help="require client certificates signed by --tls-ca")
    p.add_argument("--users-file", metavar="FILE", help="user:password lines: refuse sessions without a listed login")
    p.add_argument("--zenoh-log", choices=["error", "warn", "info", "debug"],
                   help="show zenoh's own log at this level (refused TLS handshakes and logins show at warn)")
    p.add_argument("--print-config", action="store_true", help="print the zenoh configuration and exit")
    p.set_defaults(func=cmd_router)
