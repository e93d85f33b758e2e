"""Hosts simulated by Linux network namespaces, for the deployment tests.

``Net`` builds one namespace per host (``cam``, ``edge``, ``ops``...) and one for a zenoh router,
each host linked to the router's namespace by its own veth pair (10.77.<i>.2 on the host,
10.77.<i>.1 on the router side). IP forwarding stays off in the router's namespace, so hosts
reach each other only through the zenoh router, as across real sites. Every command run on a
host gets its own /dev/shm (a private tmpfs in its mount namespace), so no shared memory
crosses hosts. ``close()`` kills what was started and deletes the namespaces; tests call it
from a fixture finalizer, so nothing is left behind after a failure.

Needs root and ``ip netns`` (``available()`` says why not, for a skip); packet loss uses
``nft`` where installed, else an eBPF program attached with ``tc`` (netem is missing from many
kernels; ``tests/bpf_loss.py``).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

ROUTER_PORT = 7447
RELAY_PORT = 7448  # tests/delay_relay.py in front of the router: a delayed link

#: a zenoh router in one Python process (the eclipse-zenoh wheel ships no zenohd)
ROUTER_CODE = """
import json, signal, sys, threading, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(c)
done = threading.Event()
signal.signal(signal.SIGTERM, lambda *a: done.set())
print("router ready", flush=True)
done.wait()
s.close()
"""


def _run(*argv: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(list(argv), capture_output=True, text=True, check=check, timeout=30)


def available() -> str:
    """'' when network namespaces can be made here, else why not (a skip reason)."""
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is missing"
    if os.geteuid() != 0:
        return "network namespaces need root (the deployment tests run as root in CI)"
    probe = f"gfprobe{os.getpid()}"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if r.returncode != 0:
        return f"ip netns add is not permitted here: {r.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return ""


def wait_for(cond: Callable[[], object], what: str, timeout: float = 60.0, every: float = 0.05):
    """Poll ``cond`` until it is truthy (and return it); fail naming ``what`` after ``timeout`` s."""
    end = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(every)


class Net:
    """Hosts and a router namespace; see the module docstring."""

    def __init__(self, hosts: tuple[str, ...] = ("cam", "edge", "ops"), tag: str | None = None) -> None:
        self.tag = tag or f"{os.getpid() % 100000}"
        self.hosts = list(hosts)
        self.router_ns = f"gf{self.tag}rt"
        self.procs: list[subprocess.Popen] = []
        self.made: list[str] = []
        self.nft = False

    # -- names -----------------------------------------------------------------------------
    def ns(self, host: str) -> str:
        return f"gf{self.tag}{host}"

    def _i(self, host: str) -> int:
        return self.hosts.index(host) + 1

    def veth_router_side(self, host: str) -> str:
        return f"gf{self.tag}r{self._i(host)}"[:15]

    def ip(self, host: str) -> str:
        return f"10.77.{self._i(host)}.2"

    def router_ip(self, host: str) -> str:
        """The router's address as ``host`` sees it."""
        return f"10.77.{self._i(host)}.1"

    def router_endpoint(self, host: str) -> str:
        return f"tcp/{self.router_ip(host)}:{ROUTER_PORT}"

    # -- building ---------------------------------------------------------------------------
    def up(self) -> "Net":
        for ns in [self.router_ns] + [self.ns(h) for h in self.hosts]:
            _run("ip", "netns", "add", ns)
            self.made.append(ns)
            _run("ip", "-n", ns, "link", "set", "lo", "up")
        for h in self.hosts:
            i, rside, hside = self._i(h), self.veth_router_side(h), f"gf{self.tag}h{self._i(h)}"[:15]
            _run("ip", "link", "add", rside, "netns", self.router_ns, "type", "veth", "peer", "name", hside,
                 "netns", self.ns(h))
            _run("ip", "-n", self.router_ns, "addr", "add", f"10.77.{i}.1/24", "dev", rside)
            _run("ip", "-n", self.ns(h), "addr", "add", f"10.77.{i}.2/24", "dev", hside)
            _run("ip", "-n", self.router_ns, "link", "set", rside, "up")
            _run("ip", "-n", self.ns(h), "link", "set", hside, "up")
        return self

    def close(self) -> None:
        self.clear_loss()
        for p in self.procs:
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        for p in self.procs:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                pass
        for ns in reversed(self.made):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        self.made = []

    # -- processes --------------------------------------------------------------------------
    def popen(self, host: str | None, argv: list[str], env: dict | None = None, cwd: str | Path | None = None,
              **kw) -> subprocess.Popen:
        """Start ``argv`` on ``host`` (None: in the router's namespace), with a private /dev/shm.
        stdout and stderr are pipes unless given."""
        ns = self.router_ns if host is None else self.ns(host)
        wrap = ["ip", "netns", "exec", ns, "sh", "-c",
                'mount -t tmpfs -o size=256m gfshm /dev/shm 2>/dev/null; exec "$@"', "sh", *argv]
        kw.setdefault("stdout", subprocess.PIPE)
        kw.setdefault("stderr", subprocess.PIPE)
        p = subprocess.Popen(wrap, env=env, cwd=cwd, text=True, start_new_session=True, **kw)
        self.procs.append(p)
        return p

    def start_router(self, env: dict | None = None) -> subprocess.Popen:
        """A zenoh router (a Python session in router mode) in the router's namespace, listening
        on every address; returns once it listens."""
        p = self.popen(None, [sys.executable, "-c", ROUTER_CODE, f"tcp/0.0.0.0:{ROUTER_PORT}"], env=env)
        assert p.stdout is not None
        line = p.stdout.readline()
        if "router ready" not in line:
            raise AssertionError(f"the zenoh router did not start: {line} {p.stderr.read() if p.stderr else ''}")
        return p

    def start_delay_relay(self, delay_s: float, env: dict | None = None) -> subprocess.Popen:
        """A relay in the router's namespace that delays each direction by ``delay_s`` before the
        router (tests/delay_relay.py); hosts that connect to :meth:`relay_endpoint` see a long link."""
        relay = str(Path(__file__).resolve().parent / "delay_relay.py")
        p = self.popen(None, [sys.executable, relay, str(RELAY_PORT), f"127.0.0.1:{ROUTER_PORT}", str(delay_s)], env=env)
        assert p.stdout is not None
        line = p.stdout.readline()
        if "relay ready" not in line:
            raise AssertionError(f"the delay relay did not start: {line} {p.stderr.read() if p.stderr else ''}")
        return p

    def relay_endpoint(self, host: str) -> str:
        return f"tcp/{self.router_ip(host)}:{RELAY_PORT}"

    # -- faults -----------------------------------------------------------------------------
    def link(self, host: str, up: bool) -> None:
        """Cut (or restore) ``host``'s link to the router."""
        _run("ip", "-n", self.router_ns, "link", "set", self.veth_router_side(host), "up" if up else "down")

    def forward(self, on: bool) -> None:
        """IP forwarding in the router's namespace: hosts reach each other's addresses directly
        (without a zenoh router in the middle)."""
        _run("ip", "netns", "exec", self.router_ns, "sysctl", "-qw", f"net.ipv4.ip_forward={int(on)}")
        for h in self.hosts:
            _run("ip", "-n", self.ns(h), "route", "replace", "default", "via", self.router_ip(h))

    def kill_host(self, host: str) -> None:
        """The host dies: every process in its namespace is killed at once (SIGKILL)."""
        r = _run("ip", "netns", "pids", self.ns(host), check=False)
        for pid in r.stdout.split():
            try:
                os.kill(int(pid), signal.SIGKILL)
            except (ProcessLookupError, ValueError):
                pass

    def loss(self, percent: float) -> None:
        """Drop ``percent`` % of the packets leaving and entering the router's namespace, at random:
        with nftables' ``numgen random`` where ``nft`` is installed, else with an eBPF classifier
        attached by ``tc`` to every router-side link (``tests/bpf_loss.py``)."""
        if shutil.which("nft"):
            n = max(1, int(round(percent)))
            rules = (f"table inet gfloss {{\n chain in {{ type filter hook input priority 0; numgen random mod 100 < {n} counter drop\n }}\n"
                     f" chain out {{ type filter hook output priority 0; numgen random mod 100 < {n} counter drop\n }}\n}}\n")
            subprocess.run(["ip", "netns", "exec", self.router_ns, "nft", "-f", "-"], input=rules, text=True,
                           capture_output=True, check=True, timeout=30)
            self.nft = True
            return
        from bpf_loss import BpfLoss

        self.bpf = BpfLoss(self.router_ns, max(1, int(round(100.0 / percent))))
        for h in self.hosts:
            self.bpf.attach(self.veth_router_side(h))

    def clear_loss(self) -> None:
        if self.nft:
            subprocess.run(["ip", "netns", "exec", self.router_ns, "nft", "delete", "table", "inet", "gfloss"],
                           capture_output=True)
            self.nft = False
        if getattr(self, "bpf", None) is not None:
            self.bpf.close()
            self.bpf = None

    def dropped(self) -> int:
        """Packets the loss rules dropped so far (nft's counters or the clsact qdiscs'), or -1 if unknown."""
        if getattr(self, "bpf", None) is not None:
            return self.bpf.dropped()
        r = subprocess.run(["ip", "netns", "exec", self.router_ns, "nft", "list", "table", "inet", "gfloss"],
                           capture_output=True, text=True)
        import re

        return -1 if r.returncode != 0 else sum(int(n) for n in re.findall(r"counter packets (\d+)", r.stdout))

    def rx_bytes(self, host: str) -> int:
        """Bytes the router's side of ``host``'s link has sent to it (what ``host`` received)."""
        p = Path(f"/sys/class/net/{self.veth_router_side(host)}/statistics/tx_bytes")
        r = _run("ip", "netns", "exec", self.router_ns, "cat", str(p))
        return int(r.stdout.strip())
