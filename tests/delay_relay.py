"""A TCP relay that delays every byte by a fixed time in each direction: the 20 ms link delay of
the deployment tests, where netem (``sch_netem``) is missing from the kernel.

    python tests/delay_relay.py LISTEN_PORT TARGET_HOST:TARGET_PORT DELAY_S

Listens on every address; for each connection it opens one to the target and pumps both ways.
Each chunk read is written ``DELAY_S`` seconds after it was read, in order (a FIFO per
direction), so the stream arrives whole and late, as over a long link. Prints ``relay ready``
once it listens, and ``relayed N`` (bytes carried) when it gets SIGTERM.
"""

from __future__ import annotations

import collections
import signal
import socket
import sys
import threading
import time


RELAYED = [0]  # bytes carried, both ways, all connections


def _pump(src: socket.socket, dst: socket.socket, delay: float) -> None:
    due: collections.deque = collections.deque()
    cond = threading.Condition()

    def writer() -> None:
        while True:
            with cond:
                while not due:
                    cond.wait()
                at, data = due.popleft()
            wait = at - time.monotonic()
            if wait > 0:
                time.sleep(wait)  # the delay being simulated
            try:
                if data is None:
                    dst.shutdown(socket.SHUT_WR)
                    return
                dst.sendall(data)
                RELAYED[0] += len(data)
            except OSError:
                return

    threading.Thread(target=writer, daemon=True).start()
    while True:
        try:
            data = src.recv(65536)
        except OSError:
            data = b""
        with cond:
            due.append((time.monotonic() + delay, data or None))
            cond.notify()
        if not data:
            return


def main() -> None:
    port, target, delay = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
    host, _, tport = target.rpartition(":")
    srv = socket.create_server(("0.0.0.0", port), reuse_port=False)

    def stop(*_) -> None:
        print(f"relayed {RELAYED[0]}", flush=True)
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    print("relay ready", flush=True)
    while True:
        conn, _ = srv.accept()
        try:
            up = socket.create_connection((host, int(tport)))
        except OSError:
            conn.close()
            continue
        for s in (conn, up):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        threading.Thread(target=_pump, args=(conn, up, delay), daemon=True).start()
        threading.Thread(target=_pump, args=(up, conn, delay), daemon=True).start()


if __name__ == "__main__":
    main()
