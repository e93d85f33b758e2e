"""The security options every networked command shares (``gflow run``, ``track``, ``demo``,
``topics``, ``echo``, ``hz``, ``pub``, ``replay``, ``ps``), and the client file that holds them.

Options (each also a key of ``--security FILE``, a YAML file; options win)::

    --tls-ca FILE          CA certificate that signed the router's certificate
    --tls-cert FILE        this side's certificate, for a router that requires one (mTLS)
    --tls-key FILE         its private key
    --user NAME            zenoh user/password login
    --password-file FILE   the password (or the environment variable GFLOW_ZENOH_PASSWORD)
    --run-key auto|FILE    sign every message of the run; drop unsigned ones (see security.md)

A bare ``--connect HOST:PORT`` becomes ``tls/HOST:PORT`` with TLS options, else ``tcp/HOST:PORT``,
so users need not learn zenoh's endpoint syntax.

The security file (paths relative to the file)::

    connect: [router.example.org:7447]
    mode: client
    tls: {ca: ca.pem, cert: edge.pem, key: edge.key}
    user: edge
    password_file: edge.password
    run_key: deployment.key
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.cli.endpoints import parse_endpoint
from pipeline.io.text_files import read_text

if TYPE_CHECKING:  # imported where used: a command's options are added without hashlib, ssl and secrets
    from pipeline.runtime.security import Security

__all__ = ["add_security_args", "apply_security", "SECURITY_FILE_KEYS"]

SECURITY_FILE_KEYS = ("connect", "listen", "mode", "tls", "user", "password_file", "run_key")
_TLS_KEYS = ("ca", "cert", "key")


def add_security_args(g) -> None:
    """Add the options to an argparse group."""
    g.add_argument("--security", metavar="FILE", help="YAML file with the options below (and connect, mode)")
    g.add_argument("--tls-ca", metavar="FILE", help="CA certificate (PEM) that signed the router's certificate")
    g.add_argument("--tls-cert", metavar="FILE", help="client certificate (PEM), for a router that requires one (mTLS)")
    g.add_argument("--tls-key", metavar="FILE", help="private key (PEM) of --tls-cert")
    g.add_argument("--user", metavar="NAME", help="zenoh user name, for a router with user/password authentication")
    g.add_argument("--password-file", metavar="FILE",
                   help="file holding the password of --user (or set GFLOW_ZENOH_PASSWORD)")
    g.add_argument("--run-key", metavar="auto|FILE",
                   help="sign every message of the run and ignore (and count) unsigned ones: 'auto' for a key "
                        "of this run only, or a key file shared by the hosts of a deployment")


def _refused(message: str) -> Exception:
    """A :class:`pipeline.runtime.security.SecurityError` saying ``message``: its module is imported only when one
    is raised (it brings ssl, hashlib and secrets, which a command given no security option does not need)."""
    from pipeline.runtime.security import SecurityError as error

    return error(message)


def _load_file(path: str) -> dict:
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(read_text(p, "security file", _refused))
    except FileNotFoundError:
        raise _refused(f"security file not found: {path}") from None
    except IsADirectoryError:
        raise _refused(f"{path} is a folder, not a security file (give a .yaml file)") from None
    except OSError as e:
        raise _refused(f"security file {path}: {e.strerror or e}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise _refused(f"{path}{where}: not valid YAML ({getattr(e, 'problem', None) or e})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise _refused(f"{path}: expected a mapping of {', '.join(SECURITY_FILE_KEYS)}")
    bad = sorted(set(data) - set(SECURITY_FILE_KEYS))
    if bad:
        raise _refused(f"{path}: unknown key {bad[0]!r} (expected {', '.join(SECURITY_FILE_KEYS)})")
    base = p.resolve().parent

    def rel(v, key: str) -> str:
        if not isinstance(v, str) or not v:
            raise _refused(f"{path}: {key} must be a file name, got {v!r}")
        return v if key == "run_key" and v == "auto" else str((base / v).resolve())

    out: dict = {}
    tls = data.get("tls")
    if tls is not None:
        if not isinstance(tls, dict) or set(tls) - set(_TLS_KEYS):
            raise _refused(f"{path}: tls must be a mapping of {', '.join(_TLS_KEYS)}, got {tls!r}")
        out.update({f"tls_{k}": rel(v, f"tls.{k}") for k, v in tls.items()})
    for k in ("password_file", "run_key"):
        if k in data:
            out[k] = rel(data[k], k)
    if "user" in data:
        if not isinstance(data["user"], str) or not data["user"]:
            raise _refused(f"{path}: user must be a name, got {data['user']!r}")
        out["user"] = data["user"]
    for k in ("connect", "listen"):
        if k in data:
            v = [data[k]] if isinstance(data[k], str) else data[k]
            if not isinstance(v, list) or not all(isinstance(e, str) for e in v):
                raise _refused(f"{path}: {k} must be a list of endpoints, got {data[k]!r}")
            out[k] = v
    if "mode" in data:
        if data["mode"] not in ("peer", "client"):
            raise _refused(f"{path}: mode must be peer or client, got {data['mode']!r}")
        out["mode"] = data["mode"]
    return out


def _endpoint(text: str, tls: bool) -> str:
    """``HOST:PORT`` -> ``tls/HOST:PORT`` (with TLS options) or ``tcp/HOST:PORT``; others unchanged."""
    if "/" not in text:
        text = ("tls/" if tls else "tcp/") + text
    try:
        return parse_endpoint(text)
    except argparse.ArgumentTypeError as e:
        raise _refused(str(e)) from None


def apply_security(args) -> Security | None:
    """Read ``--security FILE`` and the options into ``args`` (once), check the files, turn bare
    ``HOST:PORT`` endpoints into zenoh's, and return the :class:`Security` (None: none given)."""
    if getattr(args, "_security_done", False):
        return getattr(args, "_security", None)
    get = lambda name: getattr(args, name, None)  # noqa: E731 (a Namespace built by hand may lack options)
    f = _load_file(args.security) if get("security") else {}
    ca, cert, key = (get("tls_ca") or f.get("tls_ca", ""), get("tls_cert") or f.get("tls_cert", ""),
                     get("tls_key") or f.get("tls_key", ""))
    user = get("user") or f.get("user", "")
    pw_file = get("password_file") or f.get("password_file", "")
    password = ""
    if pw_file:
        try:
            password = read_text(pw_file, "password file", _refused).strip()
        except OSError as e:
            raise _refused(f"password file {pw_file}: {e.strerror or e}") from None
        if not password:
            raise _refused(f"password file {pw_file} is empty")
    elif user:
        password = os.environ.get("GFLOW_ZENOH_PASSWORD", "")
    run_key = get("run_key") or f.get("run_key", "")
    tls = bool(ca or cert)
    if f.get("connect") and not get("connect"):
        args.connect = f["connect"]
    if f.get("listen") and not get("listen"):
        args.listen = f["listen"]
    if f.get("mode") and get("mode") in (None, "peer"):
        args.mode = f["mode"]
    if get("connect"):
        args.connect = [_endpoint(e, tls) for e in args.connect]
    if get("listen"):
        args.listen = [_endpoint(e, tls) for e in args.listen]
    eps = list(get("connect") or ()) + list(get("listen") or ())
    if tls and eps and not any(e.startswith(("tls/", "quic/")) for e in eps):
        raise _refused(f"TLS options are given but no endpoint is tls/ ({', '.join(eps)}): the link would not be "
                       f"encrypted; write tls/HOST:PORT, or just HOST:PORT")
    sec = None
    if ca or cert or key or user or run_key:
        from pipeline.runtime.security import Security, load_run_key

        sec = Security(tls_ca=ca, tls_cert=cert, tls_key=key, user=user, password=password,
                       run_key=load_run_key(run_key) if run_key else "")
        sec.check(listening_tls=any(e.startswith("tls/") for e in (get("listen") or ())))
    args._security, args._security_done = sec, True
    return sec
