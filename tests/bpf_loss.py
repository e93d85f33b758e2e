"""Random packet loss on a Linux interface with no tool beyond ``tc`` (iproute2): a five-instruction
eBPF classifier, loaded here through the ``bpf()`` system call, that drops one packet in ``N``.

The deployment tests need packet loss where neither netem (``sch_netem``) nor nftables' ``nft``
is available. The program is::

    r0 = bpf_get_prandom_u32()      # helper 7
    w0 %= N
    if r0 != 0: return TC_ACT_OK    # 0
    return TC_ACT_SHOT              # 2: dropped

It is pinned in a private bpffs mount and attached with ``tc filter ... bpf da pinned PATH`` on the
ingress and egress of a clsact qdisc; ``tc -s qdisc`` counts what it dropped.
"""

from __future__ import annotations

import ctypes
import os
import re
import struct
import subprocess
import tempfile

_SYS_BPF = 321  # x86_64
_BPF_PROG_LOAD, _BPF_OBJ_PIN = 5, 6
_BPF_PROG_TYPE_SCHED_CLS = 3


def _insn(code: int, dst: int = 0, src: int = 0, off: int = 0, imm: int = 0) -> bytes:
    return struct.pack("<BBhi", code, (src << 4) | dst, off, imm)


def _program(one_in: int) -> bytes:
    return b"".join([
        _insn(0x85, imm=7),             # call bpf_get_prandom_u32
        _insn(0x94, imm=one_in),        # w0 %= one_in
        _insn(0x55, off=2, imm=0),      # if r0 != 0 goto ok
        _insn(0xB7, imm=2),             # r0 = TC_ACT_SHOT
        _insn(0x95),                    # exit
        _insn(0xB7, imm=0),             # ok: r0 = TC_ACT_OK
        _insn(0x95),                    # exit
    ])


def _bpf(cmd: int, attr: ctypes.Array) -> int:
    libc = ctypes.CDLL(None, use_errno=True)
    r = libc.syscall(_SYS_BPF, cmd, attr, len(attr))
    if r < 0:
        raise OSError(ctypes.get_errno(), f"bpf({cmd}): {os.strerror(ctypes.get_errno())}")
    return r


class BpfLoss:
    """Drop one packet in ``one_in`` on interfaces of a network namespace (``ns``), both ways."""

    def __init__(self, ns: str, one_in: int) -> None:
        self.ns = ns
        self.devs: list[str] = []
        self.dir = tempfile.mkdtemp(prefix="gflow-bpffs-")
        subprocess.run(["mount", "-t", "bpf", "bpf", self.dir], check=True, capture_output=True)
        prog = ctypes.create_string_buffer(_program(one_in))
        lic = ctypes.create_string_buffer(b"GPL")
        attr = ctypes.create_string_buffer(128)
        struct.pack_into("<IIQQ", attr, 0, _BPF_PROG_TYPE_SCHED_CLS, (len(prog) - 1) // 8,
                         ctypes.addressof(prog), ctypes.addressof(lic))
        fd = _bpf(_BPF_PROG_LOAD, attr)
        self.pinned = os.path.join(self.dir, "drop")
        path = ctypes.create_string_buffer(self.pinned.encode())
        pin = ctypes.create_string_buffer(128)
        struct.pack_into("<QI", pin, 0, ctypes.addressof(path), fd)
        try:
            _bpf(_BPF_OBJ_PIN, pin)
        finally:
            os.close(fd)

    def attach(self, dev: str) -> None:
        subprocess.run(["tc", "-n", self.ns, "qdisc", "add", "dev", dev, "clsact"], check=True, capture_output=True)
        self.devs.append(dev)
        for way in ("ingress", "egress"):
            subprocess.run(["tc", "-n", self.ns, "filter", "add", "dev", dev, way, "bpf", "da", "pinned", self.pinned],
                           check=True, capture_output=True)

    def dropped(self) -> int:
        n = 0
        for dev in self.devs:
            r = subprocess.run(["tc", "-n", self.ns, "-s", "qdisc", "show", "dev", dev], capture_output=True, text=True)
            for block in r.stdout.split("qdisc ")[1:]:
                if block.startswith("clsact"):
                    n += sum(int(x) for x in re.findall(r"dropped (\d+)", block))
        return n

    def close(self) -> None:
        for dev in self.devs:
            subprocess.run(["tc", "-n", self.ns, "qdisc", "del", "dev", dev, "clsact"], capture_output=True)
        self.devs = []
        subprocess.run(["umount", self.dir], capture_output=True)
        try:
            os.rmdir(self.dir)
        except OSError:
            pass


def supported() -> str:
    """'' when BpfLoss can be used here, else why not."""
    try:
        t = BpfLoss("", 100)
    except (OSError, subprocess.CalledProcessError) as e:
        return f"cannot load an eBPF packet-drop program: {e}"
    t.close()
    return ""
