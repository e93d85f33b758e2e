"""The recorder's stage process: every message on ``gflow/<stream>/**`` (or those the
recorder's ``topics`` keep) into one MCAP file.

* It is outside flow control: its inbox is bounded (:class:`~pipeline.runtime.inbox.BoundedInbox`),
  and a full one holds the publishers back.
* It writes the path its plan names (a restarted recorder, its next segment file) with the
  graph and the configuration as metadata, flushes on a timer, and says in its heartbeat which
  topics' end of stream it has written (a stage that sent one waits for that before it exits).
* Told to stop (``stop`` on the control topic, SIGINT, SIGTERM), it keeps what is still arriving
  until the network goes quiet, then closes the file properly. A full disk closes the recording
  at its last complete chunk and exits with ``EXIT_DISK_FULL`` (not worth a restart).
"""

from __future__ import annotations

import logging
import queue
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from pipeline.runtime.checkpoint import Checkpoint, read_checkpoint, write_checkpoint

from pipeline.runtime.graph import RecorderParams, recorded_topic_filter
from pipeline.runtime.inbox import BoundedInbox
from pipeline.runtime.node_base import NodeBase
from pipeline.runtime.node_plan import EXIT_DISK_FULL, NodePlan

if TYPE_CHECKING:
    from pipeline.io.recorder import McapRecorder

__all__ = ["RecorderNode", "RECORDER_INBOX_BYTES"]

log = logging.getLogger("gflow.node")

RECORDER_INBOX_BYTES = 32 * 2**20  # what the recorder holds unwritten before the publishers wait (pipeline/runtime/inbox.py)


class RecorderNode(NodeBase):
    """The recorder."""

    def __init__(self, node_plan: NodePlan) -> None:
        super().__init__(node_plan)
        self.recorder: McapRecorder | None = None
        self.ended: set[str] = set()  # topics whose end of stream it has recorded, for its heartbeat
        self.keep = recorded_topic_filter(self.sp.params, self.plan.stream)  # the recorder's topics (--record-topics)
        # a restarted recorder's count goes on from what the one before it reported (Checkpoint.steps)
        state_dir = node_plan.state_dir
        self.checkpoint_path = (Path(state_dir) / f"{self.name}.ckpt"
                                if state_dir and self.sp.restart == "on-failure" else None)
        self.earlier = self._earlier_messages()
        self._checkpoint_lock = threading.Lock()  # heartbeats come from two threads

    def make_inbox(self) -> queue.SimpleQueue | BoundedInbox:
        return BoundedInbox(RECORDER_INBOX_BYTES)

    def declare(self) -> None:
        self.bus.subscribe(f"gflow/{self.plan.stream}/**", self._on_sample, with_type=True, with_source=True)

    def _on_sample(self, key: str, payload: bytes, pub_ns: int, seq: int, type_name: str = "", source: str = "") -> None:
        if self.keep(key):  # with the publisher's session: the results leave out what came from outside the run
            self.inbox.put((key, payload, pub_ns, seq, type_name, source))

    def _earlier_messages(self) -> int:
        """The messages the recorders before this one (a restart's earlier segments) had reported."""
        path = self.checkpoint_path
        if path is None or not self.restarts or not path.is_file():
            return 0
        try:
            return read_checkpoint(path).steps
        except (OSError, msgspec.DecodeError) as e:
            log.warning("[%s] checkpoint %s unusable (%s); counting messages from 0", self.name, path, e)
            return 0

    def report(self) -> dict[str, Any]:
        steps = self.earlier + (self.recorder.messages if self.recorder is not None else 0)
        if self.checkpoint_path is not None and steps > self.earlier:  # what a restart goes on from: what was said
            try:
                with self._checkpoint_lock:
                    write_checkpoint(self.checkpoint_path, Checkpoint(seq=-1, data=None, max_out={}, steps=steps))
            except OSError as e:  # the run's folder gone at the very end: the count is only for a restart
                log.debug("[%s] checkpoint not written: %s", self.name, e)
        return {"steps": steps, "ended": tuple(sorted(self.ended))}

    def finishing(self) -> bool:
        rec = self.recorder
        return rec is not None and rec.is_open

    def serve(self) -> int:
        from pipeline.io.recorder import DiskFull, McapRecorder  # the recorder's own import (mcap)
        from pipeline.runtime.run_metadata import run_metadata

        plan = self.plan
        rp = RecorderParams(**self.sp.params)
        path = self.node_plan.recording or plan.recording_path()
        assert path is not None

        meta = run_metadata(plan)
        try:
            self.recorder = rec = McapRecorder(path, flush_interval=rp.flush_interval, compression=rp.compression,
                                               chunk_size=rp.chunk_size, metadata=meta).open()
        except DiskFull as e:
            print(f"recorder: {e.strerror}", file=sys.stderr)
            return EXIT_DISK_FULL
        log.info("[%s] recording to %s", self.name, path)
        self.state = "running"
        try:
            while True:
                try:
                    key, payload, pub_ns, seq, type_name, source = self.inbox.get(timeout=0.05)
                except queue.Empty:
                    rec.maybe_flush()
                    if self.stop.is_set():
                        break
                    continue
                rec.write(key, payload, seq, publish_ns=pub_ns, type_name=type_name, source=source)
                if type_name == "EndOfStream":
                    self.ended.add(key)
                    self.send_status()  # the stage that sent it waits for this before it exits
            # keep what is still arriving until the network goes quiet (at most 2 s, or 0.5 s
            # when the launcher is gone and every process must be gone within 1 s), then close
            quick = self.orphaned.is_set()
            quiet_until = time.monotonic() + (0.15 if quick else 0.3)
            deadline = time.monotonic() + (0.5 if quick else 2.0)
            while time.monotonic() < min(quiet_until, deadline):
                try:
                    key, payload, pub_ns, seq, type_name, source = self.inbox.get(timeout=0.05)
                except queue.Empty:
                    continue
                rec.write(key, payload, seq, publish_ns=pub_ns, type_name=type_name, source=source)
                if "/_status/" not in key:
                    quiet_until = time.monotonic() + 0.3
            rec.close()
        except DiskFull as e:
            print(f"recorder: {e.strerror}", file=sys.stderr)
            self.state = "stopped"
            return EXIT_DISK_FULL
        finally:
            try:
                rec.close()  # after an exception; a no-op once closed
            except DiskFull:
                pass
            self.state = "stopped" if self.state == "stopped" else "done"
        return 0
