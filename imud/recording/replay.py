"""`imud replay FILE.mcap`: a recording published as the live daemon publishes, so every
subscriber (`imud echo`, `imud record`, `imud calibrate --device`, a ROS 2 bridge fed by imud's
keys) works on it.

Each device's native batches go out on `<prefix>/<device>/imu` at the pace their log times say
(times `rate`), their bytes as recorded: stamps and sequence numbers unchanged unless
`restamp`, which moves every stamp by one offset so the first sample is now. A loop (`loop`)
restamps: each pass continues the last one's stamps and sequence numbers, so a subscriber sees
one stream. `<prefix>/daemon/status` and `<prefix>/<device>/status` answer with the devices as
the daemon described them when the recording began (state running, the file named, the rate
and gaps as replayed), so clients find them; `<prefix>/daemon/config` with the recorded config
and calibration files, so a recorder of the replay keeps them and its ROS 2 messages. A device's
uncorrected stream, where the recording has it (`imud record --raw`), goes out on `/raw` at its
pace; otherwise batches recorded uncorrected (no calibration was applied) go out on `/raw` as
well: either way `imud calibrate --device` works on a replay.
"""

from __future__ import annotations

import collections
import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from imud import __version__
from imud.client import data_key
from imud.recording.reader import Recording
from imud.wire import FLAG_CALIBRATED, decode, encode

RATE_WINDOW_S = 5.0  # the status's rate: samples sent over the last this many seconds


@dataclass
class Pass:
    """What one pass over the file sent."""

    batches: int = 0
    samples: int = 0


class Replay:
    def __init__(
        self,
        rec: Recording,
        session: zenoh.Session,
        prefix: str,
        devices: list[str],
        rate: float = 1.0,
        restamp: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        on_batch: Callable[[str, bytes], None] | None = None,
    ) -> None:
        """on_batch: also given every batch published (the ROS 2 output of a replay)."""
        self.rec = rec
        self.session = session
        self.prefix = prefix
        self.devices = devices
        self.rate = rate
        self.restamp = restamp
        self.clock, self.sleep = clock, sleep
        self.on_batch = on_batch
        self.sent = {d: 0 for d in devices}  # samples, over every pass
        self._pubs: dict[str, Any] = {}
        self._raw: dict[str, Any] = {}
        self._queryables: list[Any] = []
        self._shift_ns = 0  # added to every stamp (restamp, loops)
        self._seq_shift = {d: 0 for d in devices}  # added to every seq (loops)
        self._last = {d: (0, 0) for d in devices}  # last (seq end, stamp) sent, for loops
        self._base: dict[str, dict[str, Any]] = {}  # each device's status, less the live part
        self._started = clock()
        self.lost = {d: 0 for d in devices}  # the gaps replayed (lost_before), samples
        self._recent: dict[str, collections.deque[tuple[float, int]]] = {
            d: collections.deque() for d in devices
        }
        self.config_view: dict[str, Any] | None = None  # what <prefix>/daemon/config answers

    def start(self) -> None:
        self._started = self.clock()
        for d in self.devices:
            self._pubs[d] = self.session.declare_publisher(data_key(d, self.prefix))
            self._raw[d] = self.session.declare_publisher(data_key(d, self.prefix, raw=True))
            self._queryables.append(
                self.session.declare_queryable(
                    f"{self.prefix}/{d}/status", self._answer(self._describe(d))
                )
            )
        self._queryables.append(
            self.session.declare_queryable(
                f"{self.prefix}/daemon/status", self._answer(self.status)
            )
        )
        if self.config_view is not None:  # a recorder of this replay keeps it, as of a daemon
            view = self.config_view
            self._queryables.append(
                self.session.declare_queryable(
                    f"{self.prefix}/daemon/config", self._answer(lambda: view)
                )
            )

    def subscribed(self) -> bool:
        """Whether every device's stream has a subscriber (a recorder, an echo) by now."""
        return all(bool(p.matching_status.matching) for p in self._pubs.values())

    def _answer(self, body: Callable[[], dict[str, Any]]) -> Callable[[zenoh.Query], None]:
        def answer(q: zenoh.Query) -> None:
            with q:
                q.reply(q.key_expr, json.dumps(body()), encoding=zenoh.Encoding.APPLICATION_JSON)

        return answer

    def _describe(self, name: str) -> Callable[[], dict[str, Any]]:
        return lambda: self._device(name)

    def _device(self, name: str) -> dict[str, Any]:
        """The device as the daemon described it when the recording began (every field a
        status has, for a file that did not keep that: from its batches), replaying."""
        info = self._base.get(name)
        if info is None:
            info = self._base[name] = self._described(name)
        # what a daemon's status says of a running device, counted from what this replay sent:
        # its rate over the last seconds (at --rate, not as recorded), the gaps it replayed
        window = self._recent[name]
        now = self.clock()
        while window and now - window[0][0] > RATE_WINDOW_S:
            window.popleft()
        span = now - window[0][0] if window else 0.0
        rate = sum(n for _, n in window) / span if span > 0.5 else 0.0
        return {
            **info,
            "state": "running",
            "replaying": str(self.rec.path),
            "samples": self.sent[name],
            "lost_samples": self.lost[name],
            "measured_rate_hz": round(rate, 3),
        }

    def _described(self, name: str) -> dict[str, Any]:
        from imud.channels import CHANNELS, channels_in
        from imud.status import DeviceStatus

        first = next((decode(w) for d, _, w in self.rec.batches([name]) if d == name), None)
        channels = [] if first is None else [CHANNELS[c].key for c in channels_in(first.mask)]
        base = DeviceStatus(name, "?", "(recording)", 0.0, channels, False).to_json()
        return {**base, **self.rec.info.get(name, {})}

    def status(self) -> dict[str, Any]:
        """What the daemon status queryable answers."""
        return {
            "version": f"{__version__} (replaying {self.rec.path.name})",
            "uptime_s": round(self.clock() - self._started, 1),
            "replay": str(self.rec.path),
            "devices": [self._device(d) for d in self.devices],
            "buses": [],
        }

    def run_pass(self, stop: threading.Event) -> Pass:
        """Publish the file once at its pace; returns what it sent (stops early on `stop`)."""
        out = Pass()
        t0_log: int | None = None
        t0 = self.clock()
        first_pass_shift: int | None = None
        for device, raw, log_ns, wire in self.rec.streams(self.devices):
            if stop.is_set():
                break
            if t0_log is None:
                t0_log = log_ns
                if self.restamp and first_pass_shift is None and self._shift_ns == 0:
                    first_pass_shift = time.time_ns() - log_ns
                    self._shift_ns = first_pass_shift
            due = t0 + (log_ns - t0_log) / 1e9 / self.rate
            wait = due - self.clock()
            if wait > 0:
                self.sleep(wait)
            payload = self._shifted(device, wire)
            if raw:  # the uncorrected stream recorded beside it (--raw)
                self._raw[device].put(payload)
                continue
            self._pubs[device].put(payload)
            if self.on_batch is not None:
                self.on_batch(device, payload)
            b = decode(payload)
            if not (b.flags & FLAG_CALIBRATED) and device not in self.rec.raw:
                self._raw[device].put(payload)
            self._last[device] = (b.first_seq + b.count, int(b.t_ns[-1]) if b.count else 0)
            if self.sent[device]:
                self.lost[device] += b.lost_before
            self._recent[device].append((self.clock(), b.count))
            out.batches += 1
            out.samples += b.count
            self.sent[device] += b.count
        return out

    def _shifted(self, device: str, wire: bytes) -> bytes:
        if not self._shift_ns and not self._seq_shift[device]:
            return wire
        b = decode(wire)
        return encode(
            b.device,
            b.first_seq + self._seq_shift[device],
            b.t_ns + np.int64(self._shift_ns),
            b.channels,
            b.sample_flags,
            kind=b.kind,
            flags=b.flags,
            lost_before=b.lost_before,
        )

    def next_loop(self, first_stamp: dict[str, tuple[int, int]], period_ns: int) -> None:
        """Before another pass: stamps and seqs continue where this pass ended.
        first_stamp: per device, the file's first (seq, stamp)."""
        ends = [stamp for _, stamp in self._last.values() if stamp]
        starts = [stamp for _, stamp in first_stamp.values() if stamp]
        if ends and starts:
            self._shift_ns = max(ends) + period_ns - min(starts)
        for d in self.devices:
            seq_end, _ = self._last[d]
            first_seq, _ = first_stamp.get(d, (0, 0))
            self._seq_shift[d] = seq_end - first_seq

    def stop(self) -> None:
        for q in self._queryables:
            q.undeclare()
        for p in (*self._pubs.values(), *self._raw.values()):
            p.undeclare()
        self._queryables, self._pubs, self._raw = [], {}, {}


def first_samples(rec: Recording, devices: list[str]) -> dict[str, tuple[int, int]]:
    """Per device, the file's first (seq, stamp): where a loop starts again from."""
    out: dict[str, tuple[int, int]] = {}
    for device, _, wire in rec.batches(devices):
        if device not in out:
            b = decode(wire)
            if b.count:
                out[device] = (b.first_seq, int(b.t_ns[0]))
        if len(out) == len(devices):
            break
    return out
