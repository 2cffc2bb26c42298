"""`imud record`'s engine: a subscriber of a running daemon that writes every batch it receives,
as received, and the ROS 2 messages the daemon's own output would make of them, into MCAP.

The recorder never slows acquisition: it is one more Zenoh subscriber, whose samples Zenoh puts
in a ring of `max_queued` batches a device that the writer drains a few times a second. A writer
that cannot keep up (a slow disk) lets the ring fill, and then its oldest batches go: the seq gap
they leave, which no batch's lost_before announces, is counted per device (`dropped`), and the
daemon and the other subscribers never wait on it.

Per device: `imud/<device>/batch` holds the native batches (imud_msgs/msg/Batch: the wire bytes,
docs/wire-format.md: seq, lost_before, flags, every channel, every stamp), logged at their last
sample's stamp; the ROS 2 topics (REP-145) hold the messages imud/ros2/messages.py makes from the
same batches with the daemon's own config, logged at their header stamps; `/diagnostics` once a
second from the daemon's status. The config file and each device's calibration file go in as
attachments.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
import zenoh

from imud.client import data_key
from imud.recording.daemoncfg import DaemonConfig
from imud.recording.mcapfile import Attachment
from imud.recording.schemas import BATCH, batch_cdr
from imud.ros2.messages import Payloads, Ros2Messages, Topic
from imud.wire import peek

log = logging.getLogger("imud.record")

MAX_QUEUED = 16384  # batches a device held for a slow disk before the oldest go (and are counted)
HOLD_MS = 200.0  # of a stream made into ROS 2 messages in one step: fewer, larger NumPy steps


def native_topic(prefix: str, device: str) -> str:
    return f"/{prefix}/{device}/batch"


def raw_topic(prefix: str, device: str) -> str:
    return f"/{prefix}/{device}/raw"


class Sink(Protocol):
    """Where the recorder's messages go: an MCAP file (McapOut), a Foxglove server."""

    paths: list[Path]

    def add(self, topic: str, type_name: str, log_ns: int, payload: bytes) -> None: ...
    def add_many(
        self, topic: str, type_name: str, log_ns: npt.NDArray[np.int64], data: bytes, size: int
    ) -> None: ...
    def flush(self) -> None: ...
    def close(self) -> None: ...
    def bytes_written(self) -> int: ...


@dataclass
class Counts:
    """One device's recording so far."""

    batches: int = 0
    samples: int = 0
    lost: int = 0  # samples the daemon said it lost (lost_before), after the first batch
    dropped: int = 0  # samples the recorder itself could not keep (a full ring)
    next_seq: int | None = None


class Recorder:
    def __init__(
        self,
        session: zenoh.Session,
        prefix: str,
        devices: list[str],
        view: dict[str, Any] | None,
        out: Sink,
        max_queued: int = MAX_QUEUED,
        native: bool = True,
        on_status: Callable[[list[dict[str, Any]], int], None] | None = None,
        hold_ms: float = HOLD_MS,
        raw: bool = False,
    ) -> None:
        """native: write the native batches too (a file: yes; a live view: no). on_status: also
        given the devices' status once a second. hold_ms: how much of a stream each ROS 2 step
        takes (a view wants them sooner than a file). raw: also each device's uncorrected
        stream, on `/<prefix>/<device>/raw` (what a calibration is fitted to)."""
        self.session = session
        self.prefix = prefix
        self.devices = list(devices)
        self.out = out
        self.max_queued = max_queued
        self.native = native
        self.on_status = on_status
        self.hold_ms = hold_ms
        self.raw = raw
        self.counts = {d: Counts() for d in devices}
        self._subs: list[tuple[str, Any]] = []
        self._raw_subs: list[tuple[str, Any]] = []
        self._config: DaemonConfig | None = None
        self.ros2: Ros2Messages | None = None
        self.ros2_error: str | None = None
        if view is not None:
            self._ros2_from(view)

    # --- what the daemon runs ---------------------------------------------------------------
    def _ros2_from(self, view: dict[str, Any]) -> None:
        """The daemon's ROS 2 messages, built here from its config, its calibration files read
        from the copies it sent (the covariances use their measured noise)."""
        cal = {
            name: c["text"] for name, c in (view.get("calibration") or {}).items() if c.get("text")
        }
        self._config = DaemonConfig(view["config"], cal)
        if self._config.config is None:  # the native data still go in
            self.ros2_error = f"{self._config.error}: no ROS 2 messages"
            log.error("%s", self.ros2_error)
            return
        self.ros2 = Ros2Messages(
            self._config.config, self._ros, diagnostics=True, hold_ms=self.hold_ms
        )

    # --- receiving ----------------------------------------------------------------------------
    def start(self) -> None:
        """One subscriber a device, each into a ring of `max_queued` batches that Zenoh fills and
        this drains: no Python thread runs a sample, and a full ring drops its oldest, never
        waiting on the daemon (the seq gap it leaves is counted as the recorder's)."""
        for d in self.devices:
            # the uncorrected stream first: a replay waiting for its subscribers (--wait) starts
            # once the native one has one, and then this one is there too
            if self.raw:  # the daemon computes it while someone subscribes
                raw_ring: Any = zenoh.handlers.RingChannel(self.max_queued)
                key = data_key(d, self.prefix, raw=True)
                self._raw_subs.append((d, self.session.declare_subscriber(key, raw_ring)))
            ring: Any = zenoh.handlers.RingChannel(self.max_queued)
            sub = self.session.declare_subscriber(data_key(d, self.prefix), ring)
            self._subs.append((d, sub))

    def drain(self, timeout_s: float) -> int:
        """Write what arrived, after waiting `timeout_s` for more (the writer wakes a few times a
        second and takes what came, not once a batch); returns batches written."""
        if timeout_s > 0:
            time.sleep(timeout_s)
        n = 0
        for device, sub in self._subs:
            while (sample := sub.try_recv()) is not None:
                self._write(device, sample.payload.to_bytes())
                n += 1
        for device, sub in self._raw_subs:
            while (sample := sub.try_recv()) is not None:
                payload = sample.payload.to_bytes()
                _, count, _, last_ns, _ = peek(payload)
                if count:
                    self.out.add(raw_topic(self.prefix, device), BATCH, last_ns, batch_cdr(payload))
        return n

    def _write(self, device: str, payload: bytes) -> None:
        try:
            first_seq, n, _, last_ns, lost_before = peek(payload)
        except Exception:  # not a batch: nothing of it can be recorded as one
            log.error("%s: a payload that is not an imud batch was not recorded", device)
            return
        c = self.counts[device]
        c.batches += 1
        c.samples += n
        if c.next_seq is not None:
            c.lost += lost_before
            # a gap the daemon did not announce: batches the ring dropped before this drained
            c.dropped += max(0, first_seq - c.next_seq - lost_before)
        c.next_seq = first_seq + n
        if not n:  # no instant to log it at; its loss is counted
            return
        if self.native:
            self.out.add(native_topic(self.prefix, device), BATCH, last_ns, batch_cdr(payload))
        if self.ros2 is not None:
            self.ros2.batch(device, payload)

    def _ros(self, topic: Topic, msgs: Payloads) -> None:
        if isinstance(msgs.records, list):
            for t, p in zip(msgs.stamps_ns.tolist(), msgs.records, strict=True):
                self.out.add(topic.name, topic.type_name, t, p)
        else:  # logged at their header stamps
            size = msgs.records.dtype.itemsize
            self.out.add_many(
                topic.name, topic.type_name, msgs.stamps_ns, msgs.records.tobytes(), size
            )

    def flush(self) -> None:
        """Everything written so far to the disk (a flush point)."""
        self.out.flush()

    def status(self, devices: list[dict[str, Any]], now_ns: int) -> None:
        """Once a second, the daemon's devices' status: /diagnostics."""
        if self.ros2 is not None:
            self.ros2.tick(devices, now_ns)
        if self.on_status is not None:
            self.on_status(devices, now_ns)

    def stop(self) -> None:
        """Write what is queued, stop receiving, write what the ROS 2 side holds, close the file.
        A write that fails (a full disk) raises OSError once all is let go of."""
        try:
            self.drain(0.0)
        finally:
            for _, s in (*self._subs, *self._raw_subs):
                s.undeclare()
            self._subs, self._raw_subs = [], []
            try:
                if self.ros2 is not None:
                    self.ros2.flush()
                    self.ros2.close()
                self.out.close()
            finally:
                if self._config is not None:
                    self._config.close()


def attachments(view: dict[str, Any] | None) -> list[Attachment]:
    """The daemon's config file and each device's calibration file, as they were read."""
    if view is None:
        return []
    now = time.time_ns()
    out = []
    if view.get("text") is not None:
        name = Path(view.get("path") or "imud.toml").name
        out.append(Attachment(name, "application/toml", view["text"].encode(), now))
    for device, cal in sorted((view.get("calibration") or {}).items()):
        if cal.get("text") is not None:
            name = f"{device}: {Path(cal['path']).name}"
            out.append(Attachment(name, "application/toml", cal["text"].encode(), now))
    return out
