"""A zenoh router run from Python (the eclipse-zenoh wheel has no ``zenohd``): listen endpoints,
TLS / mTLS, user/password authentication and access control, from one YAML file.

The file (every key optional except ``listen``; paths relative to the file)::

    listen: [tls/0.0.0.0:7447]          # endpoints (tcp/HOST:PORT, tls/HOST:PORT, ...)
    tls:
      cert: router.pem                  # the router's certificate and key (for tls/ endpoints)
      key: router.key
      ca: ca.pem                        # CA of the client certificates (needed by mtls)
      mtls: true                        # refuse clients without a certificate signed by ca
    users:                              # user/password authentication: name -> password
      cam: cam-secret                   #   (or users_file: FILE with user:password lines)
    acl:                                # who may publish a stream's data and control topics
      publishers:
        - {streams: ["*"], cert_common_names: [gflow-pipeline]}
        - {streams: [cam1], usernames: [cam]}
      readers: anyone                   # anyone (default) | none | {usernames: [...], cert_common_names: [...]}
    zenoh: {}                           # further zenoh config entries, path -> value (advanced)

With ``acl`` the router denies by default: only the named publishers may put, delete or hold a
liveliness token under ``gflow/<stream>/**`` (every message type, both ways); readers may
subscribe and receive; nothing else passes. (Zenoh's ACL priority is explicit deny > explicit
allow > default, so "everyone but the pipeline" can only be said by a default deny.) Within one
publisher entry, ``cert_common_names`` and ``usernames`` must both match (zenoh's subjects are
a product of their lists); give two entries for "either".
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.io.text_files import read_text
from pipeline.runtime.security import SecurityError, check_pem_files

__all__ = ["RouterConfig", "RouterConfigError", "load_router_config", "acl_config", "zenoh_config", "Router"]

_TOP = ("listen", "tls", "users", "users_file", "acl", "zenoh")
_TLS = ("cert", "key", "ca", "mtls")
_ACL = ("publishers", "readers")
_SUBJECT = ("streams", "cert_common_names", "usernames")
_ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token",
                 "liveliness_query", "declare_liveliness_subscriber"]


class RouterConfigError(SecurityError):
    """A router configuration that cannot be used; the message names the file and the key."""


@dataclass
class RouterConfig:
    listen: list[str]
    tls_cert: str = ""
    tls_key: str = ""
    tls_ca: str = ""
    mtls: bool = False
    users: dict[str, str] = field(default_factory=dict)
    publishers: list[dict] = field(default_factory=list)  # [{streams, cert_common_names, usernames}]
    readers: str | dict = "anyone"
    acl: bool = False
    zenoh: dict = field(default_factory=dict)
    source: str = "options"

    def describe(self) -> str:
        """One line: where it listens and what it requires."""
        parts = [f"listening on {', '.join(self.listen)}"]
        if self.tls_cert:
            parts.append("TLS" + (" with client certificates (mTLS)" if self.mtls else ""))
        if self.users:
            parts.append(f"{len(self.users)} user(s) with passwords")
        if self.acl:
            pubs = "; ".join(_describe_subject(p) for p in self.publishers)
            rd = self.readers if isinstance(self.readers, str) else _describe_subject(self.readers)
            parts.append(f"ACL: publish {pubs}; read: {rd}")
        return ", ".join(parts)


def _describe_subject(s: dict) -> str:
    who = " and ".join(f"{k.replace('_', ' ')[:-1]} {'/'.join(v)}" for k, v in s.items()
                       if k != "streams" and v) or "anyone"
    streams = s.get("streams")
    return who + (f" on {', '.join(streams)}" if streams else "")


def _fail(where: str, msg: str) -> RouterConfigError:
    return RouterConfigError(f"{where}: {msg}")


def _str_list(v, where: str, key: str) -> list[str]:
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, list) or not v or not all(isinstance(x, str) and x for x in v):
        raise _fail(where, f"{key} must be a non-empty list of names, got {v!r}")
    return v


def _subject(v, where: str, key: str, streams: bool) -> dict:
    if not isinstance(v, dict):
        raise _fail(where, f"{key} must be a mapping of {', '.join(_SUBJECT)}, got {v!r}")
    allowed = _SUBJECT if streams else _SUBJECT[1:]
    bad = sorted(set(v) - set(allowed))
    if bad:
        raise _fail(where, f"unknown key {key}.{bad[0]} (expected {', '.join(allowed)})")
    out = {k: _str_list(v[k], where, f"{key}.{k}") for k in allowed if k in v}
    if not (out.get("cert_common_names") or out.get("usernames")):
        raise _fail(where, f"{key} names nobody: give cert_common_names and/or usernames")
    for s in out.get("streams", []):
        if s != "*" and ("/" in s or "*" in s or "$" in s):
            raise _fail(where, f"{key}.streams: {s!r} is not a stream id (or '*')")
    return out


def _read_router_file(path: str) -> tuple[dict, Path]:
    """The mapping of a router file, checked for its top-level keys, and the folder its relative
    paths start from."""
    import yaml

    try:
        data = yaml.safe_load(read_text(path, "router config", RouterConfigError)) or {}
    except FileNotFoundError:
        raise RouterConfigError(f"router config not found: {path}") from None
    except OSError as e:
        raise RouterConfigError(f"{path}: {e.strerror or e}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        raise _fail(path + (f" line {mark.line + 1}" if mark is not None else ""),
                    f"not valid YAML ({getattr(e, 'problem', None) or e})") from None
    if not isinstance(data, dict):
        raise _fail(path, f"expected a mapping with keys {', '.join(_TOP)}")
    bad = sorted(set(data) - set(_TOP))
    if bad:
        raise _fail(path, f"unknown key {bad[0]!r} (expected {', '.join(_TOP)})")
    return data, Path(path).resolve().parent


def _file_of(v, key: str, where: str, base: Path) -> str:
    """The absolute path of the file ``v`` names under ``key`` (relative to ``base``), which must exist."""
    if not isinstance(v, str) or not v:
        raise _fail(where, f"{key} must be a file name, got {v!r}")
    p = (base / v).resolve()
    if not p.is_file():
        raise _fail(where, f"{key}: file not found: {p}")
    return str(p)


def _apply_tls(cfg: RouterConfig, tls: object, options: dict, where: str, base: Path, from_file: bool) -> None:
    """Fill ``cfg``'s certificate, key, CA and mTLS from the ``tls`` section and the options (which
    win), and check they fit its listen endpoints and each other (``from_file``: name the file's keys
    in errors, else the command's options)."""
    if not isinstance(tls, dict):
        raise _fail(where, f"tls must be a mapping of {', '.join(_TLS)}, got {tls!r}")
    bad = sorted(set(tls) - set(_TLS))
    if bad:
        raise _fail(where, f"unknown key tls.{bad[0]} (expected {', '.join(_TLS)})")
    cfg.tls_cert = options.get("tls_cert") or (_file_of(tls["cert"], "tls.cert", where, base) if "cert" in tls else "")
    cfg.tls_key = options.get("tls_key") or (_file_of(tls["key"], "tls.key", where, base) if "key" in tls else "")
    cfg.tls_ca = options.get("tls_ca") or (_file_of(tls["ca"], "tls.ca", where, base) if "ca" in tls else "")
    mtls = tls.get("mtls", False)
    if not isinstance(mtls, bool):
        raise _fail(where, f"tls.mtls must be true or false, got {mtls!r}")
    cfg.mtls = bool(options.get("mtls")) or mtls
    if bool(cfg.tls_cert) != bool(cfg.tls_key):
        raise _fail(where, "tls: the router's certificate needs its private key and the other way round (cert and key)")
    if any(e.startswith(("tls/", "quic/")) for e in cfg.listen) and not cfg.tls_cert:
        raise _fail(where, "a tls/ listen endpoint needs the router's certificate and key ("
                    + ("tls.cert, tls.key)" if from_file else "--tls-cert, --tls-key)"))
    if cfg.tls_cert and not any(e.startswith(("tls/", "quic/")) for e in cfg.listen):
        raise _fail(where, "tls.cert is given but no listen endpoint is tls/HOST:PORT: the certificate would not be used")
    if cfg.mtls and not cfg.tls_ca:
        raise _fail(where, "tls.mtls needs tls.ca, the CA certificate that signed the clients' certificates")
    try:
        check_pem_files(cfg.tls_ca, cfg.tls_cert, cfg.tls_key)
    except SecurityError as e:
        raise _fail(where, str(e)) from None


def _yaml_word(v: object) -> str:
    """A YAML value as the file wrote it: ``null``, ``true``, ``5``, ``[x]``."""
    import yaml

    return yaml.safe_dump(v, default_flow_style=True).strip().removesuffix("...").strip()


def _users_of(data: dict, options: dict, where: str, base: Path) -> dict[str, str] | None:
    """User name -> password from ``users`` or ``users_file`` (the option wins over the file's key);
    None when neither is given."""
    users_file = options.get("users_file") or data.get("users_file")
    if "users" in data and users_file:
        raise _fail(where, "give users or users_file, not both")
    if users_file:
        uf = users_file if options.get("users_file") else _file_of(users_file, "users_file", where, base)
        return _read_users(uf)
    if "users" in data:
        users = data["users"]
        if not isinstance(users, dict) or not users:
            raise _fail(where, f"users must be a mapping of user name -> password, got {users!r}")
        for u, pw in users.items():
            if not isinstance(u, str) or not u or ":" in u:
                raise _fail(where, f"users: {u!r} is no user name (a name of text, without ':')")
            if not isinstance(pw, str):  # YAML's 5, true or 1e3 were taken as the text "5", "True", "1000.0"
                raise _fail(where, f"users.{u}: the password must be text, got {_yaml_word(pw)}"
                                   + (f" (quote it: {u}: \"{_yaml_word(pw)}\")" if isinstance(pw, (int, float)) else ""))
            if not pw:
                raise _fail(where, f"users.{u}: the password is empty")
        return dict(users)
    return None


def _apply_acl(cfg: RouterConfig, acl: object, where: str) -> None:
    """Fill ``cfg``'s publishers and readers from the ``acl`` section and check that every subject it
    names can be told apart (usernames need users, certificate names need mTLS)."""
    if not isinstance(acl, dict):
        raise _fail(where, f"acl must be a mapping of {', '.join(_ACL)}, got {acl!r}")
    bad = sorted(set(acl) - set(_ACL))
    if bad:
        raise _fail(where, f"unknown key acl.{bad[0]} (expected {', '.join(_ACL)})")
    pubs = acl.get("publishers")
    if not isinstance(pubs, list) or not pubs:
        raise _fail(where, "acl.publishers must list who may publish, e.g. "
                           "[{streams: ['*'], cert_common_names: [gflow-pipeline]}]")
    cfg.publishers = [_subject(p, where, f"acl.publishers[{i}]", True) for i, p in enumerate(pubs)]
    readers = acl.get("readers", "anyone")
    if isinstance(readers, str):
        if readers not in ("anyone", "none"):
            raise _fail(where, f"acl.readers must be anyone, none or a mapping of cert_common_names / usernames, "
                               f"got {readers!r}")
    else:
        readers = _subject(readers, where, "acl.readers", False)
    cfg.readers = readers
    cfg.acl = True
    named = {n for p in cfg.publishers for n in p.get("usernames", [])}
    if named and not cfg.users:
        raise _fail(where, "acl names usernames but the router has no users (users or users_file)")
    if any(p.get("cert_common_names") for p in cfg.publishers) and not cfg.mtls:
        raise _fail(where, "acl names cert_common_names, which only mTLS clients present: set tls.mtls: true")
    unknown = sorted(named - set(cfg.users))
    if unknown:
        raise _fail(where, f"acl names user {unknown[0]!r}, who is not in users")


def load_router_config(path: str | None = None, **options) -> RouterConfig:
    """Read and check a router file; ``options`` (listen, tls_cert, tls_key, tls_ca, mtls,
    users_file) override it. Every error is one line naming the file and the key.

    The sections are checked in order: the file itself (:func:`_read_router_file`), ``listen``,
    ``tls`` (:func:`_apply_tls`), ``users`` / ``users_file`` (:func:`_users_of`), ``acl``
    (:func:`_apply_acl`) and ``zenoh``.
    """
    data: dict = {}
    where = "router options"
    base = Path.cwd()
    if path:
        where = path
        data, base = _read_router_file(path)
    listen = options.get("listen") or data.get("listen")
    if listen is None:
        raise _fail(where, "listen: give at least one endpoint, e.g. tls/0.0.0.0:7447 or tcp/0.0.0.0:7447")
    listen = [_endpoint(e, where) for e in _str_list(listen, where, "listen")]
    cfg = RouterConfig(listen=listen, source=where)
    _apply_tls(cfg, data.get("tls") or {}, options, where, base, bool(path))
    users = _users_of(data, options, where, base)
    if users is not None:
        cfg.users = users
    acl = data.get("acl")
    if acl is not None:
        _apply_acl(cfg, acl, where)
    extra = data.get("zenoh") or {}
    if not isinstance(extra, dict):
        raise _fail(where, f"zenoh must be a mapping of config path -> value, got {extra!r}")
    cfg.zenoh = extra
    return cfg


_ENDPOINT = re.compile(r"^(tcp|tls|udp|quic|ws)/(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


def _endpoint(e: str, where: str) -> str:
    m = _ENDPOINT.match(e.strip())
    if m is None or int(m.group(3)) > 65535:
        hint = f": tcp/{e} or tls/{e}" if "/" not in e else ", e.g. tls/0.0.0.0:7447"
        raise _fail(where, f"listen: {e!r} is not an endpoint PROTO/HOST:PORT{hint}")
    return e.strip()


def _read_users(path: str) -> dict[str, str]:
    users: dict[str, str] = {}
    try:
        lines = read_text(path, "users file", RouterConfigError).splitlines()
    except OSError as e:
        raise RouterConfigError(f"users file {path}: {e.strerror or e}") from None
    for i, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        u, sep, pw = line.strip().partition(":")
        if not sep or not u or not pw:
            raise RouterConfigError(f"users file {path} line {i}: expected user:password")
        users[u] = pw
    if not users:
        raise RouterConfigError(f"users file {path} lists no user:password line")
    return users


def _with_progress(keys: list[str]) -> list[str]:
    """``keys`` plus the progress keys under them: ``**`` does not match a verbatim chunk such as
    ``@progress`` (``gflow/<stream>/@progress/<stage>``, :meth:`Plan.progress_topic`)."""
    return keys + [k[: -len("**")] + "*/@progress/*" if k == "gflow/**" else k[: -len("**")] + "@progress/*"
                   for k in keys if k.endswith("/**")]


def acl_config(cfg: RouterConfig) -> dict:
    """zenoh's ``access_control`` section for ``cfg`` (default deny; see the module doc)."""
    # a publisher of one stream must still learn of a reader's subscription to gflow/** (zenoh's ACL
    # matches a declaration only when its key lies inside the rule's), or it never sends to it
    rules: list[dict] = [{"id": "see-subscribers", "permission": "allow", "flows": ["egress"],
                          "messages": ["declare_subscriber", "declare_liveliness_subscriber"], "key_exprs": _with_progress(["gflow/**"])}]
    subjects: list[dict] = []
    policies: list[dict] = []
    for i, p in enumerate(cfg.publishers):
        streams = p.get("streams", ["*"])
        keys = ["gflow/**"] if "*" in streams else [f"gflow/{s}/**" for s in streams]
        rules.append({"id": f"publish{i}", "permission": "allow", "flows": ["ingress", "egress"],
                      "messages": list(_ALL_MESSAGES), "key_exprs": _with_progress(keys)})
        subjects.append({"id": f"publisher{i}", **{k: v for k, v in p.items() if k != "streams"}})
        policies.append({"id": f"publishers{i}", "rules": [f"publish{i}", "see-subscribers"],
                         "subjects": [f"publisher{i}"]})
    if cfg.readers != "none":
        rules.append({"id": "read-in", "permission": "allow", "flows": ["ingress"],
                      "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"],
                      "key_exprs": _with_progress(["gflow/**"])})
        rules.append({"id": "read-out", "permission": "allow", "flows": ["egress"],
                      "messages": ["put", "delete", "reply", "liveliness_token"], "key_exprs": _with_progress(["gflow/**"])})
        readers = {} if cfg.readers == "anyone" else cfg.readers
        assert isinstance(readers, dict)  # anyone, none or a mapping: checked when the configuration was read
        subjects.append({"id": "readers", **readers})
        policies.append({"id": "readers", "rules": ["read-in", "read-out"], "subjects": ["readers"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def zenoh_config(cfg: RouterConfig, users_file: str = "") -> dict[str, object]:
    """``{config path: value}`` for the router's ``zenoh.Config`` (``users_file``: where the
    user:password lines were written, when there are users)."""
    out: dict[str, object] = {"mode": "router", "scouting/multicast/enabled": False, "listen/endpoints": cfg.listen}
    tls = "transport/link/tls/"
    if cfg.tls_cert:
        out[tls + "listen_certificate"] = cfg.tls_cert
        out[tls + "listen_private_key"] = cfg.tls_key
    if cfg.tls_ca:
        out[tls + "root_ca_certificate"] = cfg.tls_ca
    if cfg.mtls:
        out[tls + "enable_mtls"] = True
    if cfg.users:
        out["transport/auth/usrpwd/dictionary_file"] = users_file or "<users file>"
    if cfg.acl:
        out["access_control"] = acl_config(cfg)
    out.update(cfg.zenoh)
    return out


class Router:
    """A running router: ``Router(cfg)`` opens it (a one-line :class:`RouterConfigError` if zenoh
    refuses the configuration or an endpoint is busy); ``close()`` shuts it down."""

    def __init__(self, cfg: RouterConfig) -> None:
        import zenoh

        self.cfg = cfg
        self._users_file = ""
        if cfg.users:  # zenoh reads users from a file only: a private temporary one
            fd, self._users_file = tempfile.mkstemp(prefix="gflow-router-users-", text=True)
            with os.fdopen(fd, "w") as f:
                f.write("".join(f"{u}:{p}\n" for u, p in cfg.users.items()))
        c = zenoh.Config()
        try:
            for k, v in zenoh_config(cfg, self._users_file).items():
                c.insert_json5(k, json.dumps(v))
        except Exception as e:
            self._remove_users()
            raise RouterConfigError(f"{cfg.source}: zenoh refused the configuration: {str(e).split(' at /')[0]}") \
                from None
        try:
            self.session = zenoh.open(c)
        except Exception as e:
            self._remove_users()
            raise RouterConfigError(f"could not start the router on {', '.join(cfg.listen)}: "
                                    f"{str(e).split(' at /')[0]} (is the port in use?)") from None

    def _remove_users(self) -> None:
        if self._users_file:
            try:
                os.unlink(self._users_file)
            except FileNotFoundError:
                pass
            self._users_file = ""

    def close(self) -> None:
        try:
            self.session.close()
        finally:
            self._remove_users()

    def __enter__(self) -> "Router":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
