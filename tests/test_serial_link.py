"""Serial links: a simulated serial chip behind a real pseudo-terminal, opened with pyserial
exactly as a driver opens /dev/ttyUSB0; and the errors a port that will not open gives."""

from __future__ import annotations

import time

import pytest

from imud.buses.serial import char_time_ns, open_serial
from imud.clock import MonotonicClock
from imud.errors import BusError
from imud.sim.pty import PtyLink


class Echo:
    """Answers every byte it receives with the byte + 1, each after one character time."""

    def __init__(self, baud: int, clock: MonotonicClock) -> None:
        self.clock = clock
        self.char_ns = char_time_ns(baud)
        self.queue: list[tuple[int, int]] = []  # (time its last bit is out, byte)

    def receive(self, data: bytes) -> None:
        t = self.queue[-1][0] if self.queue else self.clock.now_ns()
        for b in data:
            t = max(t, self.clock.now_ns()) + int(self.char_ns)
            self.queue.append((t, (b + 1) & 0xFF))

    def transmit(self, now_ns: int) -> bytes:
        out = bytes(b for t, b in self.queue if t <= now_ns)
        self.queue = [(t, b) for t, b in self.queue if t > now_ns]
        return out

    def next_transmit_ns(self) -> int | None:
        return self.queue[0][0] if self.queue else None


def _read_exactly(port: object, n: int, timeout_s: float = 5.0) -> bytes:
    out = b""
    end = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < end:
        out += port.read(n - len(out))  # type: ignore[attr-defined]
        time.sleep(0.001)
    return out


def test_pty_link_carries_bytes_both_ways_at_the_configured_baud() -> None:
    clock = MonotonicClock()
    die = Echo(115_200, clock)
    link = PtyLink(die, clock)
    port = open_serial(link.path, 115_200)
    link.release()
    try:
        assert port.baudrate == 115_200
        assert link.path.startswith("/dev/pts/")
        port.write(bytes([0x00, 0x41, 0xFF]))
        assert _read_exactly(port, 3) == bytes([0x01, 0x42, 0x00])  # no echo, no line editing
        assert link.bytes_in == 3
    finally:
        port.close()
        link.close()


def test_closing_the_port_ends_the_pump() -> None:
    clock = MonotonicClock()
    link = PtyLink(Echo(9600, clock), clock)
    port = open_serial(link.path, 9600)
    link.release()
    port.close()
    link._thread.join(timeout=2.0)
    assert not link._thread.is_alive()
    link.close()


def test_a_missing_port_names_it_and_the_fix(tmp_path: object) -> None:
    with pytest.raises(BusError) as e:
        open_serial("/dev/ttyNOPE42", 115_200)
    assert "/dev/ttyNOPE42" in str(e.value)
    assert "by-id" in str(e.value)
