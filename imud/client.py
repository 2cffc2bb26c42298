"""Client side of imud: decode batches into NumPy arrays and ask a daemon for its status.

import imud.client as ic
with ic.open_session("tcp/127.0.0.1:7447") as s:
    for batch in ic.batches(s, "imu0", limit=10):
        print(batch.t_ns, batch.accel)
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import zenoh

from imud.config import DEFAULT_ENDPOINT
from imud.wire import KIND_SAMPLES, KIND_TRUTH, Batch, WireError, decode
from imud.zsession import client_config

__all__ = [
    "KIND_SAMPLES",
    "KIND_TRUTH",
    "Batch",
    "NoDaemon",
    "WireError",
    "batches",
    "decode",
    "get_status",
    "open_session",
]


class NoDaemon(ConnectionError):
    pass


def open_session(endpoint: str = DEFAULT_ENDPOINT) -> zenoh.Session:
    """A client session to one daemon, with multicast scouting disabled (`client_config`): it talks
    to the given endpoint only. Raises `NoDaemon` if nothing listens there."""
    try:
        return zenoh.open(client_config(endpoint))
    except zenoh.ZError as e:
        raise NoDaemon(f"no imud daemon reachable at {endpoint}: {e}") from None


def get_status(
    session: zenoh.Session, prefix: str = "imud", device: str | None = None, timeout: float = 2.0
) -> dict[str, Any]:
    key = f"{prefix}/{device or 'daemon'}/status"
    for reply in session.get(key, timeout=timeout):
        if reply.ok is not None:
            parsed: dict[str, Any] = json.loads(reply.ok.payload.to_string())
            return parsed
    raise NoDaemon(f"no answer on {key} within {timeout:g} s")


def batches(
    session: zenoh.Session,
    device: str,
    prefix: str = "imud",
    truth: bool = False,
    limit: int | None = None,
    timeout: float | None = None,
    depth: int = 16384,
) -> Iterator[Batch]:
    """Yield decoded batches from `<prefix>/<device>/imu` (or `/sim/truth`) as they arrive.

    `depth` batches are queued for the caller (8 s of a 32 kHz stream): a Python consumer that
    pauses (GC, a slow print) must not push back on Zenoh, which would drop batches for it."""
    key = f"{prefix}/{device}/{'sim/truth' if truth else 'imu'}"
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
