"""Hostile messages on the live topics of a real multi-process run (chamfer graph, caviar1):
random bytes, wrong types, unknown tags, NaN particles, huge and overflowing shapes, future,
old and duplicate sequence numbers. No crash, no hang, no phantom or missing row, the output
equals the undisturbed run, and every bad message is counted (heartbeat and errors topic)."""

from __future__ import annotations

import threading
import time

import msgspec
import numpy as np

from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.launcher import Launcher
from pipeline.io.mcap_io import iter_records
from pipeline.recording.results import estimates
from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session
from gflow_msgs.messages import ErrorReport, Estimate, Frame, Header, NDArray, Particles, decode, encode

STOP = 120
REJECTED = {"malformed_message", "wrong_type", "future_seq", "old_seq", "duplicate_seq", "bad_array", "bad_values",
            "bad_header"}


def _plan(caviar1, paced: bool = True):
    # played at 15 frames/s, so that the run lasts while the injector probes and sends; the undisturbed
    # run, which nothing probes, as fast as it goes (pacing does not change a run's output)
    overrides = {"source": {"kind": "folder", "path": str(caviar1 / "frames"), "stop": STOP, "realtime": paced,
                            "fps": 15},
                 "filter": {"init": [129, 71, 30, 79]}, "preprocess": {"calibrate_box": [129, 71, 30, 79]}}
    return apply_defaults(load_graph("chamfer", overrides=overrides))


def _run(plan, rec, during=None):
    port = free_port()
    launcher = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)), recording=str(rec),
                        progress=False)
    result: dict = {}
    th = threading.Thread(target=lambda: result.setdefault("r", launcher.run()), daemon=True)
    th.start()
    if during is not None:
        during(launcher, port)
    th.join(180)
    assert not th.is_alive(), "the run hung"
    return result["r"]


def _bad_messages(src: int, rng: np.random.Generator) -> list[tuple[str, bytes]]:
    """(topic, payload) pairs, none of which may be joined; ``src`` is the source's current frame."""
    # a frame the source has not reached yet, so a real message of it is still to come: ``src`` is the
    # source's last heartbeat (sent every 0.5 s, so 8 frames behind at 15 frames/s, more on a busy
    # machine), and a frame it has passed would make the bad messages of it late (old or duplicate
    # seq) instead of bad arrays or values; the checks of shape and values come before the check of
    # how far ahead a frame is, so a frame well ahead is still judged by its content
    ahead = src + 30
    nan = np.zeros((5, 4))
    nan[2, 1] = np.nan
    inf = np.ones((5, 4))
    inf[0, 0] = np.inf

    def particles(seq, alpha):
        return encode(Particles(Header("cam0", seq, 0), "posterior", NDArray.of(alpha),
                                NDArray.of(np.zeros(len(alpha), np.int64)), NDArray.of(np.zeros(len(alpha)))))

    huge = Frame(Header("cam0", ahead, 0), NDArray("uint8", (10**6, 10**6, 3), b"\x00" * 16))
    overflow = Frame(Header("cam0", ahead, 0), NDArray("uint8", (2**40, 2**40, 2**20), b""))
    small = Frame(Header("cam0", ahead, 0), NDArray.of(np.zeros((20, 30, 3), np.uint8)))
    err = encode(ErrorReport(Header("cam0", ahead, 0), "x", "y", "z"))
    out = []
    for topic in ("frames", "features", "particles", "proposals"):
        t = f"gflow/cam0/{topic}"
        out += [(t, rng.bytes(int(rng.integers(1, 300)))),  # random bytes
                (t, msgspec.msgpack.encode({"type": "NoSuchType", "header": [1, 2]})),  # an unknown tag
                (t, err)]  # a well-formed message of the wrong type
    f, ft, pt, pp = (f"gflow/cam0/{t}" for t in ("frames", "features", "particles", "proposals"))
    out += [(f, encode(huge)), (f, encode(overflow)), (f, encode(small)),
            (f, encode(Frame(Header("cam0", src + 1000, 0), NDArray.of(np.zeros((288, 384, 3), np.uint8))))),
            (f, encode(Frame(Header("cam0", 0, 0), NDArray.of(np.zeros((288, 384, 3), np.uint8))))),  # old
            (pt, particles(ahead, nan)), (pt, particles(ahead, inf)), (pp, particles(ahead + 1, nan)),
            (pt, particles(src + 1000, np.ones((5, 4)))), (pp, particles(1, np.ones((5, 4)))),  # future, old
            (ft, encode(ErrorReport(Header("cam0", -3, 0), "x", "y", "z")))]
    return out


def _rejected(launcher, stage: str) -> int:
    st = launcher.status.get(stage)
    return sum(st.rejected.values()) if st is not None else 0


def test_hostile_messages_on_every_input_topic(caviar1, tmp_path):
    plan = _plan(caviar1)
    base = estimates_of(_run(_plan(caviar1, paced=False), tmp_path / "base.mcap"), tmp_path / "base.mcap")
    sent: dict[str, int] = {}
    before: dict[str, int] = {}
    rng = np.random.default_rng(0)
    readers = {"frames": "preprocess", "features": "filter", "proposals": "filter", "particles": "proposal"}

    def inject(launcher, port):
        deadline = time.monotonic() + 60
        while not (launcher.status.get("filter") and launcher.status["filter"].steps >= 5):
            assert time.monotonic() < deadline
            time.sleep(0.02)
        s = open_session(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",)))
        bus = Bus(s)
        # probe each topic with one bad message until its reader has counted one: from then on
        # the injector's messages reach it (reliable, in order)
        for topic, stage in readers.items():
            n0 = _rejected(launcher, stage)
            while _rejected(launcher, stage) == n0:
                assert time.monotonic() < deadline, f"{stage} never heard the injector on {topic}"
                bus.publish(f"gflow/cam0/{topic}", b"\xc1 probe", 0)
                time.sleep(0.1)
        # the heartbeats settle (sent every 0.5 s): what was counted before the hostile messages
        last, since = None, time.monotonic()
        while time.monotonic() - since < 1.2:
            now = {n: _rejected(launcher, n) for n in set(readers.values())}
            if now != last:
                last, since = now, time.monotonic()
            time.sleep(0.05)
        before.update(last)
        for _ in range(3):
            src = launcher.status["source"].last_seq
            for topic, payload in _bad_messages(src, rng):
                bus.publish(topic, payload, 0)
                sent[topic] = sent.get(topic, 0) + 1
            bus.publish("gflow/cam0/_control", b"\xc1 garbage", 0)
            time.sleep(0.1)
        s.close()

    r = _run(plan, tmp_path / "run.mcap", inject)
    assert sum(sent.values()) == 3 * len(_bad_messages(0, rng))  # every round went out during the run
    assert r.ok, (r.exits, r.stall)
    est = estimates_of(r, tmp_path / "run.mcap")
    assert sorted(est) == list(range(STOP))  # no phantom, no missing row
    assert est == base  # nothing real was displaced: the output is the undisturbed one
    # every bad message on an input topic was rejected and counted by the stage that reads it
    errors = [m for m in (decode(x.data) for x in iter_records(tmp_path / "run.mcap", topics=["gflow/cam0/errors"]))
              if isinstance(m, ErrorReport) and m.kind in REJECTED]
    counted = sum(n for st in r.status.values() for k, n in st.rejected.items() if k != "bad_control")
    assert len(errors) == counted  # the heartbeats and the errors topic agree
    assert counted - sum(before.values()) == sum(sent.values()), (sent, before, {n: st.rejected for n, st in
                                                                               r.status.items()})
    # the garbage on the control topic was counted by every stage process (recorder included)
    assert all(st.rejected.get("bad_control") == 3 for st in r.status.values()), {n: st.rejected for n, st in
                                                                                  r.status.items()}
    kinds = {e.kind for e in errors}
    assert {"malformed_message", "wrong_type", "future_seq", "old_seq", "bad_array", "bad_values"} <= kinds, kinds
    # unknown tags share their topic's one unknown channel
    unknown = {x.topic for x in iter_records(tmp_path / "run.mcap") if x.type == "unknown"}
    assert unknown <= {f"gflow/cam0/{t}" for t in ("frames", "features", "particles", "proposals", "_control")}


def estimates_of(r, rec) -> dict[int, tuple]:
    assert r.ok, (r.exits, r.stall)
    return {k: (e.box, e.state) for k, e in estimates(rec).items() if isinstance(e, Estimate)}
