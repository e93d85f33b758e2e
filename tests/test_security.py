"""Security across hosts, with real zenoh sessions on loopback and certificates made at test time:
TLS and mTLS endpoints, user/password logins, router config validation, the router's access
control, and a run that an outside peer tries to stop, end and feed with fake estimates (through
a TLS router with ACL, and directly in peer mode against a run key): the output equals the
undisturbed run's, and what arrived is counted."""

from __future__ import annotations

import dataclasses
import datetime
import ipaddress
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli.main import main
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.launcher import Launcher
from pipeline.runtime.router import Router, RouterConfigError, load_router_config
from pipeline.runtime.security import Security, Signer, load_run_key
from pipeline.runtime.transport import Bus, SessionError, ZenohSettings, free_port, open_session
from pipeline.recording.results import estimates
from pipeline.io.mcap_io import iter_records
from gflow_msgs.messages import Control, EndOfStream, Estimate, Header, NDArray, StageStatus, decode, encode

x509 = pytest.importorskip("cryptography.x509", reason="the cryptography package makes the test certificates")

ROOT = Path(__file__).resolve().parent.parent


# -- certificates -----------------------------------------------------------------------------

def _make_certs(d: Path) -> dict[str, Path]:
    """A CA; router, pipeline (CN gflow-pipeline) and outsider (CN outsider) certificates it signs;
    and a certificate of another CA (rogue)."""
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.timezone.utc)
    out: dict[str, Path] = {}

    def save(name, key, cert):
        (d / f"{name}.key").write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                          serialization.NoEncryption()))
        (d / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        out[name], out[name + "_key"] = d / f"{name}.pem", d / f"{name}.key"

    def ca(cn):
        k = ec.generate_private_key(ec.SECP256R1())
        n = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])
        c = (x509.CertificateBuilder().subject_name(n).issuer_name(n).public_key(k.public_key()).serial_number(1)
             .not_valid_before(now - datetime.timedelta(hours=1)).not_valid_after(now + datetime.timedelta(days=1))
             .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
             .add_extension(x509.KeyUsage(True, False, False, False, False, True, True, False, False), critical=True)
             .sign(k, hashes.SHA256()))
        return k, n, c

    def leaf(name, cn, ca_key, ca_name, expired=False, names=("localhost", "127.0.0.1")):
        k = ec.generate_private_key(ec.SECP256R1())
        end = now - datetime.timedelta(minutes=5) if expired else now + datetime.timedelta(days=1)
        san = [x509.IPAddress(ipaddress.ip_address(n)) if n[0].isdigit() else x509.DNSName(n) for n in names]
        c = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
             .issuer_name(ca_name).public_key(k.public_key()).serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(hours=1)).not_valid_after(end)
             .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
             .add_extension(x509.SubjectAlternativeName(san), False)
             .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                            False)
             .sign(ca_key, hashes.SHA256()))
        save(name, k, c)

    ca_key, ca_name, ca_cert = ca("gflow test CA")
    save("ca", ca_key, ca_cert)
    leaf("router", "router", ca_key, ca_name)
    leaf("pipeline", "gflow-pipeline", ca_key, ca_name)
    leaf("outsider", "outsider", ca_key, ca_name)
    leaf("expired", "router", ca_key, ca_name, expired=True)
    leaf("elsewhere", "router", ca_key, ca_name, names=("router.example.org",))
    rogue_key, rogue_name, rogue_cert = ca("rogue CA")
    save("rogue_ca", rogue_key, rogue_cert)
    return out


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> dict[str, Path]:
    return _make_certs(tmp_path_factory.mktemp("certs"))


def _router_file(tmp_path: Path, text: str) -> str:
    p = tmp_path / "router.yaml"
    p.write_text(text)
    return str(p)


def _tls_router(tmp_path, certs, port, mtls=True, acl=True, users="") -> Router:
    text = (f"listen: [tls/127.0.0.1:{port}]\n"
            f"tls: {{cert: {certs['router']}, key: {certs['router_key']}, ca: {certs['ca']}, mtls: {str(mtls).lower()}}}\n"
            + users
            + ("acl:\n  publishers:\n    - {streams: ['*'], cert_common_names: [gflow-pipeline]}\n" if acl else ""))
    return Router(load_router_config(_router_file(tmp_path, text)))


def _client(port: int, certs, who: str | None, proto: str = "tls", **kw) -> ZenohSettings:
    sec = Security(tls_ca=str(certs["ca"]), tls_cert=str(certs[who]) if who else "",
                   tls_key=str(certs[who + "_key"]) if who else "", **kw)
    return ZenohSettings(mode="client", listen=(), connect=(f"{proto}/127.0.0.1:{port}",), security=sec)


def _wait(cond, timeout: float = 20.0, what: str = "condition") -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.01)


# -- router configuration ----------------------------------------------------------------------

@pytest.mark.parametrize("text, expected", [
    ("lisen: [tcp/127.0.0.1:7447]\n", "unknown key 'lisen'"),
    ("tls: {}\n", "listen: give at least one endpoint"),
    ("listen: [127.0.0.1:7447]\n", "is not an endpoint PROTO/HOST:PORT: tcp/127.0.0.1:7447 or tls"),
    ("listen: [tls/127.0.0.1:7447]\n", "tls/ listen endpoint needs the router's certificate"),
    ("listen: [tls/127.0.0.1:7447]\ntls: {cert: router.pem}\n", "tls.cert: file not found"),
    ("listen: [tcp/127.0.0.1:7447]\ntls: {mtls: yes please}\n", "tls.mtls must be true or false"),
    ("listen: [tcp/127.0.0.1:7447]\nusers: {gflow: ''}\n", "users.gflow: the password is empty"),
    # a password YAML reads as another kind of value was taken as its text ("5"), or refused naming no key
    ("listen: [tcp/127.0.0.1:7447]\nusers: {a: 5}\n", 'router.yaml: users.a: the password must be text, got 5 '
                                                       '(quote it: a: "5")'),
    ("listen: [tcp/127.0.0.1:7447]\nusers: {a: true}\n", 'users.a: the password must be text, got true (quote it: '
                                                          'a: "true")'),
    ("listen: [tcp/127.0.0.1:7447]\nusers: {a: [x]}\n", "router.yaml: users.a: the password must be text, got [x]"),
    ("listen: [tcp/127.0.0.1:7447]\nusers: {a: null}\n", "router.yaml: users.a: the password must be text, got null"),
    ("listen: [tcp/127.0.0.1:7447]\nusers: {5: pw}\n", "router.yaml: users: 5 is no user name"),
    ("listen: [tcp/127.0.0.1:7447]\nacl: {publishers: []}\n", "acl.publishers must list who may publish"),
    ("listen: [tcp/127.0.0.1:7447]\nacl: {publishers: [{streams: [cam0]}]}\n", "names nobody"),
    ("listen: [tcp/127.0.0.1:7447]\nacl: {publishers: [{usernames: [cam]}]}\n", "the router has no users"),
    ("listen: [tcp/127.0.0.1:7447]\nusers: {a: b}\nacl: {publishers: [{usernames: [cam]}]}\n", "user 'cam'"),
    ("listen: [tcp/127.0.0.1:7447]\nacl: {publishers: [{cert_common_names: [p]}]}\n", "set tls.mtls: true"),
    ("listen: [tcp/127.0.0.1:7447]\nacl: {publishers: [{usernames: [a]}], readers: everyone}\n",
     "acl.readers must be anyone, none"),
    ("listen: [tcp/127.0.0.1:7447\n", "not valid YAML"),
])
def test_router_config_errors_are_one_line(tmp_path, capsys, text, expected):
    path = _router_file(tmp_path, text)
    with pytest.raises(RouterConfigError, match=re.escape(expected)):
        load_router_config(path)
    assert main(["router", path]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gflow router: error: ") and err.count("\n") == 1 and expected in err


def test_router_config_to_acl(tmp_path, certs):
    path = _router_file(tmp_path, f"listen: [tls/0.0.0.0:7447]\n"
                                  f"tls: {{cert: {certs['router']}, key: {certs['router_key']}, ca: {certs['ca']}, "
                                  f"mtls: true}}\nusers: {{cam1: pw}}\nacl:\n  publishers:\n"
                                  f"    - {{streams: [cam1], usernames: [cam1]}}\n"
                                  f"    - {{cert_common_names: [gflow-pipeline]}}\n  readers: none\n")
    from pipeline.runtime.router import acl_config

    acl = acl_config(load_router_config(path))
    assert acl["default_permission"] == "deny"
    # readers: none; each rule also covers the progress keys, which ** does not match (a verbatim chunk)
    assert [r["key_exprs"] for r in acl["rules"][1:]] == [["gflow/cam1/**", "gflow/cam1/@progress/*"],
                                                          ["gflow/**", "gflow/*/@progress/*"]]
    assert acl["subjects"] == [{"id": "publisher0", "usernames": ["cam1"]},
                               {"id": "publisher1", "cert_common_names": ["gflow-pipeline"]}]


# -- TLS, mTLS, logins ------------------------------------------------------------------------

def _roundtrip(a: ZenohSettings, b: ZenohSettings, key: str = "gflow/t/x") -> None:
    """b receives what a publishes."""
    sa, sb = open_session(a), open_session(b)
    try:
        got: queue.SimpleQueue = queue.SimpleQueue()
        sb.declare_subscriber(key, lambda s: got.put(s.payload.to_bytes()))
        pub = sa.declare_publisher(key)
        _wait(lambda: pub.matching_status.matching, what="a matching subscriber")
        pub.put(b"hello")
        assert got.get(timeout=10) == b"hello"
    finally:
        sa.close()
        sb.close()


def test_tls_endpoint(tmp_path, certs, capsys):
    port = free_port()
    with _tls_router(tmp_path, certs, port, mtls=False, acl=False):
        _roundtrip(_client(port, certs, None), _client(port, certs, None))
        wrong_ca = ZenohSettings(mode="client", listen=(), connect=(f"tls/127.0.0.1:{port}",),
                                 security=Security(tls_ca=str(certs["rogue_ca"])))
        with pytest.raises(SessionError, match="is not signed by the CA in"):
            open_session(wrong_ca)
        # the same through the command line: one line, no traceback; a bare HOST:PORT becomes tls/
        rc = main(["topics", "--mode", "client", "--connect", f"127.0.0.1:{port}", "--tls-ca", str(certs["rogue_ca"]),
                   "--duration", "0.1"])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and "not signed by the CA" in err and "Traceback" not in err
        rc = main(["echo", "gflow/t/x", "--mode", "client", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "0.1"])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1, err


@pytest.mark.parametrize("cert, msg", [("expired", "has expired"), ("elsewhere", "is not issued for 127.0.0.1")])
def test_router_certificate_that_does_not_fit(tmp_path, certs, cert, msg):
    port = free_port()
    cfg = load_router_config(_router_file(tmp_path, f"listen: [tls/127.0.0.1:{port}]\n"
                                                    f"tls: {{cert: {certs[cert]}, key: {certs[cert + '_key']}}}\n"))
    with Router(cfg):
        with pytest.raises(SessionError, match=msg):
            open_session(_client(port, certs, None))


def test_mtls_endpoint(tmp_path, certs, capsys):
    port = free_port()
    with _tls_router(tmp_path, certs, port, mtls=True, acl=False):
        _roundtrip(_client(port, certs, "pipeline"), _client(port, certs, "outsider"))
        with pytest.raises(SessionError, match="requires a client certificate"):
            open_session(_client(port, certs, None))
        rc = main(["hz", "gflow/t/x", "--mode", "client", "--connect", f"127.0.0.1:{port}",
                   "--tls-ca", str(certs["ca"]), "--duration", "0.1"])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and "--tls-cert and --tls-key" in err, err
        # a certificate without its key, a key of another certificate: refused before zenoh sees them
        for extra, msg in ((["--tls-cert", str(certs["pipeline"])], "give both"),
                           (["--tls-cert", str(certs["pipeline"]), "--tls-key", str(certs["outsider_key"])],
                            "do not load together")):
            rc = main(["topics", "--mode", "client", "--connect", f"127.0.0.1:{port}", "--tls-ca", str(certs["ca"]),
                       *extra, "--duration", "0.1"])
            err = capsys.readouterr().err
            assert rc == 2 and err.count("\n") == 1 and msg in err, err


def test_user_password(tmp_path, capsys):
    port = free_port()
    cfg = load_router_config(_router_file(tmp_path, f"listen: [tcp/127.0.0.1:{port}]\nusers: {{cam: s3cret}}\n"))

    def client(user, pw):
        return ZenohSettings(mode="client", listen=(), connect=(f"tcp/127.0.0.1:{port}",),
                             security=Security(user=user, password=pw) if user else None)

    with Router(cfg):
        _roundtrip(client("cam", "s3cret"), client("cam", "s3cret"))
        with pytest.raises(SessionError, match="refused the login of user 'cam'"):
            open_session(client("cam", "guess"))
        with pytest.raises(SessionError, match="may require a login"):
            open_session(client(None, None))
        pw = tmp_path / "pw"
        pw.write_text("guess\n")
        rc = main(["topics", "--mode", "client", "--connect", f"127.0.0.1:{port}", "--user", "cam",
                   "--password-file", str(pw), "--duration", "0.1"])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and "refused the login of user 'cam' (a wrong password" in err, err


def test_acl_only_the_pipeline_publishes(tmp_path, certs):
    """Readers read; an outsider's puts are dropped by the router itself: here it is even told of
    the run's subscriptions (a policy added through the file's ``zenoh:`` entries), so it sends."""
    from pipeline.runtime.router import acl_config

    port = free_port()
    cfg = load_router_config(_router_file(tmp_path, f"listen: [tls/127.0.0.1:{port}]\n"
                                                    f"tls: {{cert: {certs['router']}, key: {certs['router_key']}, "
                                                    f"ca: {certs['ca']}, mtls: true}}\n"
                                                    f"acl:\n  publishers:\n    - {{cert_common_names: [gflow-pipeline]}}\n"))
    acl = acl_config(cfg)
    acl["policies"].append({"id": "tell-readers", "rules": ["see-subscribers"], "subjects": ["readers"]})
    cfg.zenoh = {"access_control": acl}
    with Router(cfg):
        pipe, outsider = open_session(_client(port, certs, "pipeline")), open_session(_client(port, certs, "outsider"))
        reader = open_session(_client(port, certs, "outsider"))
        try:
            seen: queue.SimpleQueue = queue.SimpleQueue()
            reader.declare_subscriber("gflow/t/**", lambda s: seen.put(s.payload.to_bytes()))  # readers: anyone
            inside: queue.SimpleQueue = queue.SimpleQueue()
            pipe.declare_subscriber("gflow/t/**", lambda s: inside.put(s.payload.to_bytes()))
            ppub, opub = pipe.declare_publisher("gflow/t/x"), outsider.declare_publisher("gflow/t/x")
            _wait(lambda: ppub.matching_status.matching and opub.matching_status.matching, what="the subscriptions")
            ppub.put(b"one")
            assert seen.get(timeout=10) == b"one"  # a reader reads
            assert inside.get(timeout=10) == b"one"
            for _ in range(5):
                opub.put(b"fake")
            ppub.put(b"two")
            assert inside.get(timeout=10) == b"two"  # the outsider's puts, sent before, never came
            assert seen.get(timeout=10) == b"two"
            assert inside.empty() and seen.empty()
        finally:
            for x in (pipe, outsider, reader):
                x.close()


def test_run_key_file(tmp_path):
    with pytest.raises(ValueError, match="run key file not found"):
        load_run_key(str(tmp_path / "nope"))
    short = tmp_path / "short"
    short.write_text("abc")
    with pytest.raises(ValueError, match="at least 16"):
        load_run_key(str(short))
    good = tmp_path / "k"
    good.write_text("0123456789abcdef0123\n")
    assert load_run_key(str(good)) == load_run_key(str(good)) != load_run_key("auto")
    s = Signer(load_run_key(str(good)))
    now = time.time_ns()
    tag = s.tag("gflow/a/b", 3, now, b"payload")
    assert s.valid("gflow/a/b", 3, now, b"payload", tag)
    assert not s.valid("gflow/a/b", 3, now, b"payloaD", tag) and not s.valid("gflow/a/c", 3, now, b"payload", tag)
    assert not s.valid("gflow/a/b", 4, now, b"payload", tag) and not s.valid("gflow/a/b", 3, now + 1, b"payload", tag)
    assert not Signer(load_run_key("auto")).valid("gflow/a/b", 3, now, b"payload", s.tag("gflow/a/b", 3, now, b"payload"))
    # a message of an earlier run under the same key (recorded by a reader, sent again) is stale
    old = now - int(400e9)
    assert not s.valid("gflow/a/b", 3, old, b"payload", s.tag("gflow/a/b", 3, old, b"payload"))


# -- a run that an outsider tries to stop, end and feed --------------------------------------------

FRAMES = 90  # 3 s at 30 frames/s: time for an outsider to join under load before the last 22 frames


def _plan(realtime: bool = True):
    # played in real time at 30 frames/s, so that the run lasts while the outsider acts; the run nobody
    # attacks, whose boxes the others must give, need not wait for the clock (the boxes do not depend on the pace)
    return apply_defaults(load_graph("demo", overrides={"source": {"frames": FRAMES, "realtime": realtime, "fps": 30},
                                                         "filter": {"particles": 150}}))


def _attack(settings: ZenohSettings, plan, wait_matching: bool) -> dict:
    """As an outsider: wait for the run's first estimates, then send stop, end-of-stream and 20 fake
    estimates of frames still to come. Returns what it saw."""
    s = open_session(settings)
    est_topic, frames_topic = plan.stages["filter"].outputs["estimate"], plan.stages["source"].outputs["frames"]
    try:
        bus = Bus(s)
        heard: queue.SimpleQueue = queue.SimpleQueue()
        bus.subscribe(est_topic, lambda k, p, ns, seq: heard.put(seq))
        recorder_heard = threading.Event()  # peer mode: a heartbeat of the recorder's means a link to it
        bus.subscribe(f"gflow/{plan.stream}/_status/recorder", lambda *a: recorder_heard.set())
        first = heard.get(timeout=60)
        header = Header(plan.stream, first, time.time_ns())
        sent = {"control": 0, "end": 0, "estimate": 0, "first": first}
        pubs = {t: bus.publisher(t) for t in (plan.control_topic, frames_topic, est_topic)}
        if wait_matching:  # peer mode: the run's subscribers are right there, the recorder's among them
            _wait(lambda: all(p.matching_status.matching for p in pubs.values()) and recorder_heard.is_set(),
                  what="the run's subscribers")
        bus.publish(plan.control_topic, encode(Control(header, "stop")), first, "Control")
        sent["control"] += 1
        bus.publish(frames_topic, encode(EndOfStream(Header(plan.stream, first + 1, time.time_ns()))), first + 1,
                    "EndOfStream")
        sent["end"] += 1
        for k in range(first + 2, first + 22):
            fake = Estimate(Header(plan.stream, k, time.time_ns()), (1.0, 2.0, 3.0, 4.0), (0.0, 0.0, 0.0, 0.0), 0,
                            (1.0, 2.0, 3.0, 4.0), (0.0, 0.0, 0.0, 0.0), 1.0, 1, 0.0, NDArray.of(np.zeros((2, 2))))
            bus.publish(est_topic, encode(fake), k, "Estimate")
            sent["estimate"] += 1
        sent["last_heard"] = first
        while sent["last_heard"] < FRAMES - 1:  # keep listening: a reader sees the run go on past the attack
            try:
                sent["last_heard"] = heard.get(timeout=10.0)  # (silent that long: the run has ended)
            except queue.Empty:
                break
        return sent
    finally:
        s.close()


def _run(plan, settings: ZenohSettings, rec: Path, outsider=None):
    launcher = Launcher(plan, zenoh=settings, recording=str(rec), progress=False)
    result: dict = {}
    th = threading.Thread(target=lambda: result.setdefault("r", launcher.run()), daemon=True)
    th.start()
    attack = outsider(launcher) if outsider is not None else None
    th.join(120)
    assert not th.is_alive(), "the run hung"
    r = result["r"]
    assert r.ok, (r.exits, r.stall)
    return r, attack


def _boxes(rec: Path) -> dict[int, tuple]:
    return {k: (v.box, v.state) for k, v in estimates(rec).items()}


def _max_unsigned(rec: Path) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in iter_records(rec):
        if "/_status/" in r.topic:
            st = decode(r.data)
            if isinstance(st, StageStatus) and st.rejected.get("unsigned"):
                out[st.stage] = max(out.get(st.stage, 0), st.rejected["unsigned"])
    return out


def test_outsider_cannot_stop_end_or_feed_a_run(tmp_path, certs):
    """Over TLS through a router with ACL (the outsider holds a valid certificate of another name),
    and against `gflow run` in peer mode with a run key (the outsider connects straight to the launcher)."""
    port = free_port()
    with _tls_router(tmp_path, certs, port, mtls=True, acl=True):
        pipe = _client(port, certs, "pipeline")
        r0, _ = _run(_plan(realtime=False), pipe, tmp_path / "quiet.mcap")
        quiet = _boxes(tmp_path / "quiet.mcap")
        assert sorted(quiet) == list(range(FRAMES))

        r1, seen = _run(_plan(), pipe, tmp_path / "acl.mcap",
                        lambda launcher: _attack(_client(port, certs, "outsider"), launcher.plan, wait_matching=False))
        assert seen["first"] < FRAMES - 22 and seen["last_heard"] >= FRAMES - 1, seen  # it read the whole run (and its end)
        assert _boxes(tmp_path / "acl.mcap") == quiet

    # the same attack on `gflow run` in peer mode with a run key: the outsider links to the launcher
    key = tmp_path / "run.key"
    key.write_text("a shared secret of the deployment\n")
    lport = free_port()
    cmd = [sys.executable, "-m", "pipeline.cli.main", "run", "demo", "--set", f"source.frames={FRAMES}",
           "--set", "source.realtime=true", "--set", "source.fps=30", "--set", "filter.particles=150",
           "--record", str(tmp_path / "peer.mcap"), "--listen", f"tcp/127.0.0.1:{lport}", "--run-key", str(key),
           "--stream", _plan().stream]  # the outsider knows the run's stream (runs get a random one by default)
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        outsider = ZenohSettings(listen=("tcp/127.0.0.1:0",), connect=(f"tcp/127.0.0.1:{lport}",))
        seen = _attack(outsider, _plan(), wait_matching=True)
        err = proc.communicate(timeout=120)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert seen["first"] < FRAMES - 22, seen
    assert _boxes(tmp_path / "peer.mcap") == quiet
    # what arrived was dropped, counted and reported, by the stage that dropped it: the recorder
    # (which hears everything) the stop, the end and the 20 estimates. (Which other stages heard
    # the stop depends on which links the outsider's peer session had made when it sent it.)
    line = next(x for x in err.splitlines() if x.startswith("ignored messages not signed with the run key"))
    unsigned = {n: int(c) for n, c in (part.split() for part in line.split("by stage: ")[1].split(", "))}
    assert set(unsigned) <= set(_plan().stages) and all(c >= 1 for c in unsigned.values()), line
    assert unsigned["recorder"] >= 22 and len(unsigned) >= 2, line
    in_recording = _max_unsigned(tmp_path / "peer.mcap")  # the recording keeps the counts
    assert in_recording and all(in_recording[n] <= unsigned[n] for n in in_recording), (in_recording, line)
    assert load_run_key(str(key)).encode() not in (tmp_path / "peer.mcap").read_bytes()  # and not the key


def test_gflow_router_command_stops_cleanly(tmp_path, certs):
    """The real command: serves a client, says where it listens, stops on SIGTERM with exit 0."""
    port = free_port()
    cfg = _router_file(tmp_path, f"listen: [tls/127.0.0.1:{port}]\n"
                                 f"tls: {{cert: {certs['router']}, key: {certs['router_key']}}}\n")
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "router", cfg], cwd=ROOT,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        assert f"listening on tls/127.0.0.1:{port}" in line and "TLS" in line, line
        s = open_session(_client(port, certs, None))
        s.close()
        proc.terminate()
        assert proc.wait(20) == 0
        assert "stopped" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()


def test_acl_per_stream_by_user(tmp_path):
    """Each camera's login may publish its own stream only (zenoh's usernames subjects)."""
    port = free_port()
    cfg = load_router_config(_router_file(tmp_path, f"listen: [tcp/127.0.0.1:{port}]\n"
                                                    f"users: {{cam1: one, cam2: two, ops: look}}\n"
                                                    f"acl:\n  publishers:\n"
                                                    f"    - {{streams: [cam1], usernames: [cam1]}}\n"
                                                    f"    - {{streams: [cam2], usernames: [cam2]}}\n"))

    def login(user, pw):
        return open_session(ZenohSettings(mode="client", listen=(), connect=(f"tcp/127.0.0.1:{port}",),
                                          security=Security(user=user, password=pw)))

    with Router(cfg):
        cam1, ops, ops2 = login("cam1", "one"), login("ops", "look"), login("ops", "look")
        try:
            seen: queue.SimpleQueue = queue.SimpleQueue()
            ops.declare_subscriber("gflow/**", lambda s: seen.put((str(s.key_expr), s.payload.to_bytes())))
            own = cam1.declare_publisher("gflow/cam1/x")
            _wait(lambda: own.matching_status.matching, what="the reader's subscription")
            cam1.put("gflow/cam2/x", b"not mine")
            ops2.put("gflow/cam1/x", b"reader")  # (a session's own subscribers would see its puts)
            own.put(b"mine")
            assert seen.get(timeout=10) == ("gflow/cam1/x", b"mine")
            own.put(b"again")
            assert seen.get(timeout=10) == ("gflow/cam1/x", b"again") and seen.empty()
        finally:
            for x in (cam1, ops, ops2):
                x.close()


def test_client_security_file(tmp_path, certs, capsys):
    """--security FILE: paths relative to the file, a bare HOST:PORT made tls/, one-line errors."""
    import argparse

    from pipeline.cli.security_options import apply_security

    (tmp_path / "pw").write_text("s3cret\n")
    f = tmp_path / "edge.yaml"
    f.write_text(f"connect: [10.0.0.5:7447]\nmode: client\ntls: {{ca: {certs['ca']}, cert: {certs['pipeline']}, "
                 f"key: {certs['pipeline_key']}}}\nuser: cam\npassword_file: pw\n")
    args = argparse.Namespace(security=str(f), connect=None, listen=None, mode="peer")
    sec = apply_security(args)
    assert args.connect == ["tls/10.0.0.5:7447"] and args.mode == "client"
    assert sec is not None and sec.password == "s3cret" and sec.tls_cert == str(certs["pipeline"])
    assert sec.zenoh_entries()["transport/link/tls/enable_mtls"] is True
    rc = main(["topics", "--connect", "tcp/10.0.0.5:7447", "--tls-ca", str(certs["ca"]), "--duration", "0.1"])
    err = capsys.readouterr().err
    assert rc == 2 and "the link would not be encrypted" in err, err
    for text, msg in (("conect: [a:1]\n", "unknown key 'conect'"), ("tls: {ca: nope.pem}\n", "not found"),
                      ("mode: router\n", "mode must be peer or client"), ("user: cam\n", "has no password")):
        f.write_text(text)
        rc = main(["topics", "--security", str(f), "--duration", "0.1"])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and msg in err, err


def test_login_in_peer_mode():
    """Peers with a login link to each other (each accepts its own login); a peer without it is refused."""
    port = free_port()
    sec = Security(user="cam", password="s3cret")
    a = ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",), security=sec)
    b = ZenohSettings(listen=("tcp/127.0.0.1:0",), connect=(f"tcp/127.0.0.1:{port}",), security=sec)
    _roundtrip(a, b)
    sa = open_session(a)
    try:
        for settings in (dataclasses.replace(b, security=None),
                         dataclasses.replace(b, security=Security(user="cam", password="guess"))):
            if settings.security is None:
                outsider = open_session(settings)  # zenoh's peer mode opens anyway, with no link
                try:
                    assert list(outsider.info.peers_zid()) == []
                finally:
                    outsider.close()
            else:  # with a login of its own, the missing link is an error
                with pytest.raises(SessionError, match="refused the login of user 'cam'"):
                    open_session(settings)
    finally:
        sa.close()
