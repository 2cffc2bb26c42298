"""Client side of imud: decode batches into NumPy arrays and ask a daemon for its status.

import imud.client as ic
with ic.open_session("tcp/127.0.0.1:7450") as s:
    for batch in ic.batches(s, "imu0", limit=10):
        print(batch.t_ns, batch.accel)
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import zenoh

from imud.session import BadEndpoint, NoDaemon, get_config, get_status, open_session
from imud.wire import KIND_SAMPLES, KIND_TRUTH, Batch, WireError, decode

__all__ = [
    "KIND_SAMPLES",
    "KIND_TRUTH",
    "BadEndpoint",
    "Batch",
    "NoDaemon",
    "WireError",
    "batches",
    "data_key",
    "decode",
    "get_config",
    "get_status",
    "open_session",
]


def data_key(device: str, prefix: str = "imud", truth: bool = False, raw: bool = False) -> str:
    """Where a device's batches are published: corrected (`imu`), uncorrected (`raw`, computed
    only while someone subscribes), or its simulator's ground truth (`sim/truth`)."""
    return f"{prefix}/{device}/{'sim/truth' if truth else 'raw' if raw else 'imu'}"


def batches(
    session: zenoh.Session,
    device: str,
    prefix: str = "imud",
    truth: bool = False,
    limit: int | None = None,
    timeout: float | None = None,
    depth: int = 16384,
    raw: bool = False,
) -> Iterator[Batch]:
    """Yield decoded batches from `<prefix>/<device>/imu` (or `/raw`, or `/sim/truth`) as they
    arrive.

    `depth` batches are queued for the caller (8 s of a 32 kHz stream): a Python consumer that
    pauses (GC, a slow print) must not push back on Zenoh, which would drop batches for it."""
    key = data_key(device, prefix, truth, raw)
    sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(depth))
    try:
        seen = 0
        while limit is None or seen < limit:
            sample = sub.recv() if timeout is None else _recv_timeout(sub, timeout)
            if sample is None:
                return
            yield decode(sample.payload.to_bytes())
            seen += 1
    finally:
        sub.undeclare()  # type: ignore[no-untyped-call]


def _recv_timeout(sub: Any, timeout: float) -> Any:
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        s = sub.try_recv()
        if s is not None:
            return s
        time.sleep(0.005)
    return None
