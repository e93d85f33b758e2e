"""Who may join a gflow zenoh network, and whose messages a run believes.

Three independent layers (docs/security.md shows them together):

* **TLS / mTLS** (:class:`Security` ``tls_*``): links to a router on a ``tls/HOST:PORT``
  endpoint are encrypted; the client checks the router's certificate against ``tls_ca``;
  with a client certificate (``tls_cert`` + ``tls_key``) the router can require one (mTLS)
  and its access control can name the certificate's common name.
* **User / password** (``user`` + ``password``): zenoh's usrpwd authentication; a router with
  a user list refuses a session without a listed login.
* **Run key** (``run_key``): every sample a run publishes carries a 16-byte HMAC-SHA256 of its
  key expression, sequence number, publish time and payload, under a secret shared by the
  run's processes (and by the hosts of one deployment, from one key file). Every process of
  the run drops a sample without a valid tag and counts it, so a peer that reaches an endpoint
  directly (peer mode bypasses a router's ACL) can neither stop, end nor feed a run. It does
  not hide anything: use TLS for that.

This module turns those settings into zenoh configuration entries, checks the files before
zenoh sees them (one-line errors naming the file), explains a refused connection in one line,
and signs / checks samples. It knows nothing of the CLI.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import socket
import ssl
import struct
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

__all__ = ["Security", "SecurityError", "Signer", "load_run_key", "check_pem_files", "explain_refusal", "TAG_SIZE"]

TAG_SIZE = 16


class SecurityError(ValueError):
    """A certificate, key, password or run key that cannot be used; the message is one line."""


@dataclass(frozen=True)
class Security:
    """How one process authenticates itself and the router (all optional; empty = off).

    tls_ca : CA certificate (PEM) that signed the router's certificate (and, on a router with
        mTLS, the clients' certificates).
    tls_cert, tls_key : this process's certificate and private key (PEM): the client
        certificate for mTLS, or the server certificate when listening on a ``tls/`` endpoint.
    mtls : listening: require a client certificate signed by ``tls_ca``. Connecting with a
        certificate turns it on by itself (zenoh only presents the certificate then).
    user, password : zenoh user/password authentication.
    run_key : hex of the run's signing secret ("" = samples are neither signed nor checked).
    """

    tls_ca: str = ""
    tls_cert: str = ""
    tls_key: str = ""
    mtls: bool = False
    user: str = ""
    password: str = field(default="", repr=False)
    run_key: str = field(default="", repr=False)

    @property
    def tls(self) -> bool:
        return bool(self.tls_ca or self.tls_cert)

    def zenoh_entries(self, listening: bool = False) -> dict[str, object]:
        """``{config path: value}`` for ``zenoh.Config.insert_json5`` (paths of eclipse-zenoh 1.x,
        tried against 1.10: ``transport/link/tls/*``, ``transport/auth/usrpwd/*``).

        ``listening`` (peer mode): zenoh refuses a link when either side presents a login the other
        side's user list lacks, so a listening process with a login also accepts that login (a
        private user file of its own): the stages of a run link to each other with the login, and
        a peer without it is refused."""
        out: dict[str, object] = {}
        tls = "transport/link/tls/"
        if self.tls_ca:
            out[tls + "root_ca_certificate"] = self.tls_ca
        if self.tls_cert:
            out[tls + "listen_certificate"] = self.tls_cert
            out[tls + "listen_private_key"] = self.tls_key
            out[tls + "connect_certificate"] = self.tls_cert
            out[tls + "connect_private_key"] = self.tls_key
        if self.mtls or self.tls_cert:
            out[tls + "enable_mtls"] = True
        if self.user:
            out["transport/auth/usrpwd/user"] = self.user
            out["transport/auth/usrpwd/password"] = self.password
            if listening:
                out["transport/auth/usrpwd/dictionary_file"] = _own_user_file(self.user, self.password)
        return out

    def check(self, listening_tls: bool = False) -> None:
        """Refuse, in one line, what zenoh would refuse with a vague error (or a traceback)."""
        if bool(self.tls_cert) != bool(self.tls_key):
            raise SecurityError("a TLS certificate needs its private key and the other way round: give both "
                                "--tls-cert and --tls-key")
        if listening_tls and not self.tls_cert:
            raise SecurityError("listening on a tls/ endpoint needs a server certificate and key (--tls-cert, --tls-key)")
        if self.mtls and not self.tls_ca:
            raise SecurityError("mTLS needs the CA certificate that signed the clients' certificates (--tls-ca)")
        if self.user and not self.password:
            raise SecurityError(f"user {self.user!r} has no password (give --password-file FILE or "
                                f"GFLOW_ZENOH_PASSWORD)")
        if self.password and not self.user:
            raise SecurityError("a password without a user name (give --user)")
        check_pem_files(self.tls_ca, self.tls_cert, self.tls_key)

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict | None) -> "Security | None":
        if not d:
            return None
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


_USER_FILES: dict[tuple[str, str], str] = {}


def _own_user_file(user: str, password: str) -> str:
    """A private file ``user:password`` for this process (removed at exit)."""
    key = (user, password)
    if key not in _USER_FILES:
        import atexit
        import tempfile

        fd, path = tempfile.mkstemp(prefix="gflow-login-", text=True)  # mode 0600
        with os.fdopen(fd, "w") as f:
            f.write(f"{user}:{password}\n")
        def remove() -> None:
            if os.path.exists(path):
                os.unlink(path)

        atexit.register(remove)
        _USER_FILES[key] = path
    return _USER_FILES[key]


def check_pem_files(ca: str = "", cert: str = "", key: str = "") -> None:
    """The CA file holds certificates; the certificate and key are PEM and belong together."""
    for what, path in (("CA certificate", ca), ("certificate", cert), ("private key", key)):
        if path and not Path(path).is_file():
            raise SecurityError(f"{what} not found: {path}")
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    if ca:
        try:
            ctx.load_verify_locations(cafile=ca)
        except (ssl.SSLError, OSError, ValueError) as e:
            raise SecurityError(f"{ca}: not a PEM CA certificate ({_ssl_reason(e)})") from None
    if cert:
        text = Path(cert).read_bytes()
        if b"-----BEGIN CERTIFICATE-----" not in text:
            raise SecurityError(f"{cert}: not a PEM certificate (no BEGIN CERTIFICATE block)")
        if b"PRIVATE KEY-----" not in Path(key).read_bytes():
            raise SecurityError(f"{key}: not a PEM private key (no BEGIN ... PRIVATE KEY block)")
        try:
            ctx.load_cert_chain(cert, key)
        except (ssl.SSLError, OSError, ValueError) as e:
            raise SecurityError(f"{cert} / {key}: the certificate and private key do not load together "
                                f"({_ssl_reason(e)})") from None


def _ssl_reason(e: BaseException) -> str:
    r = getattr(e, "reason", None) or getattr(e, "strerror", None) or str(e)
    return " ".join(str(r).replace("_", " ").lower().split())


def load_run_key(spec: str) -> str:
    """A run key from ``auto`` (a fresh random key: only this launcher's processes know it) or a
    key file (every host of a deployment reads the same one); returned as hex."""
    if spec == "auto":
        return secrets.token_hex(32)
    p = Path(spec)
    try:
        data = p.read_bytes().strip()
    except FileNotFoundError:
        raise SecurityError(f"run key file not found: {spec} (make one with: head -c 32 /dev/urandom | "
                            f"base64 > {spec}; chmod 600 {spec})") from None
    except OSError as e:
        raise SecurityError(f"run key file {spec}: {e.strerror or e}") from None
    if len(data) < 16:
        raise SecurityError(f"run key file {spec} holds {len(data)} bytes; a key needs at least 16 "
                            f"(head -c 32 /dev/urandom | base64 > {spec})")
    if os.name == "posix" and p.stat().st_mode & 0o077:
        import logging

        logging.getLogger(__name__).warning("run key file %s is readable by other users (chmod 600 %s)", spec, spec)
    return hashlib.sha256(b"gflow run key\0" + data).hexdigest()


_HEAD = struct.Struct("<qq")


#: a signed sample published this long before the receiving process started is stale: a replay of
#: an earlier run's message (a reader may have recorded it) under the same key file; the margin
#: allows for clocks of different hosts that disagree by less than this
STALE_S = 300.0


class Signer:
    """Signs and checks samples with a run key (HMAC-SHA256, truncated to 16 bytes). A sample
    published more than :data:`STALE_S` before this signer was made is refused as a replay."""

    def __init__(self, key_hex: str) -> None:
        import time

        self._key = bytes.fromhex(key_hex)
        self.not_before_ns = time.time_ns() - int(STALE_S * 1e9)

    def tag(self, key_expr: str, seq: int, publish_ns: int, payload: bytes) -> bytes:
        h = hmac.new(self._key, key_expr.encode("utf-8") + _HEAD.pack(seq, publish_ns), hashlib.sha256)
        h.update(payload)
        return h.digest()[:TAG_SIZE]

    def valid(self, key_expr: str, seq: int, publish_ns: int, payload: bytes, tag: bytes) -> bool:
        return (len(tag) == TAG_SIZE and publish_ns >= self.not_before_ns
                and hmac.compare_digest(self.tag(key_expr, seq, publish_ns, payload), tag))

    @classmethod
    def of(cls, security: Security | None) -> "Signer | None":
        return cls(security.run_key) if security is not None and security.run_key else None


def explain_refusal(connect: tuple[str, ...] | list[str], security: Security | None, timeout: float = 2.0) -> str:
    """Why zenoh could not connect to ``connect``, in one clause, found by trying the first endpoint
    with Python's own socket / TLS (zenoh only says "unable to connect"). "" when nothing is known."""
    sec = security or Security()
    for ep in connect:
        proto, _, addr = ep.partition("/")
        addr = addr.split("#")[0].split("?")[0]
        host, _, port = addr.rpartition(":")
        host = host.strip("[]")
        if proto not in ("tcp", "tls") or not port.isdigit():
            continue
        try:
            raw = socket.create_connection((host, int(port)), timeout=timeout)
        except OSError as e:
            return f"nothing accepts connections at {host}:{port} ({e.strerror or e})"
        with raw:
            if proto == "tcp":
                if sec.user:
                    return f"{ep} refused the login of user {sec.user!r} (a wrong password, or a user it does not list)"
                return (f"{ep} refused the session: the router may require a login (--user, --password-file) "
                        f"or TLS (a tls/ endpoint)")
            ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # checks the CA and the name, as zenoh does
            try:
                if sec.tls_ca:
                    ctx.load_verify_locations(cafile=sec.tls_ca)
                else:
                    ctx.load_default_certs()
                if sec.tls_cert and sec.tls_key:
                    ctx.load_cert_chain(sec.tls_cert, sec.tls_key)
            except (ssl.SSLError, OSError):
                return ""
            try:
                with ctx.wrap_socket(raw, server_hostname=host) as tls:
                    tls.settimeout(0.5)
                    try:
                        tls.recv(1)  # TLS 1.3: a refused client certificate shows on the first read
                    except socket.timeout:
                        pass
            except ssl.SSLCertVerificationError as e:
                why = (e.verify_message or "").lower()
                if "expired" in why or "not yet valid" in why:
                    return f"the certificate of {ep} {'has expired' if 'expired' in why else 'is not valid yet'}"
                if "mismatch" in why:
                    return (f"the certificate of {ep} is not issued for {host} (connect by a name or address "
                            f"its certificate lists)")
                return (f"the certificate of {ep} is not signed by "
                        + (f"the CA in {sec.tls_ca}" if sec.tls_ca else "a known CA (give --tls-ca)"))
            except ssl.SSLError as e:
                reason = _ssl_reason(e)
                if "certificate required" in reason or "handshake failure" in reason and not sec.tls_cert:
                    return f"{ep} requires a client certificate (mTLS): give --tls-cert and --tls-key"
                if "unknown ca" in reason or "bad certificate" in reason:
                    return f"{ep} does not accept this client certificate ({sec.tls_cert}): {reason}"
                if "wrong version" in reason or "record layer" in reason:
                    return f"{ep} does not speak TLS (is it a tcp/ endpoint?)"
                return f"TLS with {ep} failed: {reason}"
            except OSError as e:
                return f"{ep} closed the connection ({e.strerror or e})"
            if sec.user:
                return f"{ep} refused the login of user {sec.user!r} (a wrong password, or a user it does not list)"
            return f"{ep} accepted TLS but refused the session: the router may require a login (--user)"
    return ""
