"""Messages between a bus worker and the daemon, over one SOCK_SEQPACKET socket (boundaries
kept), whether the worker runs in a process of its own or in a thread of the daemon's.

Worker to daemon: b"P" + device index (u16) + stream (u8, `Stream`) + an encoded batch
(`imud.wire`); b"S" + JSON {"heartbeat_ns": int, "generation": int, "devices": [status, ...]};
b"A" + generation (u32): the reload plan the daemon sent was applied, and from here on device
indices and statuses are the new list's.
Daemon to worker: b"R" + device index (u16) + on (u8): someone started (1) or stopped (0)
subscribing to the device's uncorrected stream; b"C" + JSON {"config": ..., "plan": ...}: a
reloaded config and what it does on this bus (`imud.reload.BusPlan`). The daemon closing its end
stops the worker.
"""

from __future__ import annotations

import struct
from enum import IntEnum

PUBLISH = b"P"
STATUS = b"S"
RAW_WANTED = b"R"
RECONFIGURE = b"C"
APPLIED = b"A"
GENERATION = struct.Struct("<I")
HEADER = struct.Struct("<cHB")
RECV_MAX = 1 << 20


class Stream(IntEnum):
    """Which of a device's streams a batch belongs to, and so its key."""

    DATA = 0  # <prefix>/<device>/imu: calibrated samples
    TRUTH = 1  # <prefix>/<device>/sim/truth: the simulator's ground truth
    RAW = 2  # <prefix>/<device>/raw: before calibration, computed only while subscribed

    @property
    def key(self) -> str:
        return _KEYS[self]


_KEYS = {Stream.DATA: "imu", Stream.TRUTH: "sim/truth", Stream.RAW: "raw"}
