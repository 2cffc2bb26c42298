"""A simulated serial chip behind a real pseudo-terminal.

The driver opens the pty's path with pyserial at its configured baud, exactly as it opens
`/dev/ttyUSB0`; a pump thread moves bytes between the pty's master side and the simulated chip.
A pty carries bytes as fast as they are written, so the chip paces its own output at the link's
bit rate (`StreamDie.transmit`). Like a UART whose reader falls behind, bytes that find the host's
receive buffer full are lost (counted in `overrun_bytes`).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
import threading
import tty

from imud.clock import Clock
from imud.sim.api import StreamDie
from imud.sim.cpu import ThreadMeter

log = logging.getLogger("imud.sim")

MIN_WAKE_NS = 1_000_000  # the pump's finest step, like a USB serial adapter's 1 ms frames
MAX_WAKE_NS = 5_000_000


class PtyLink:
    """One pseudo-terminal and its pump. `path` is what the driver opens."""

    def __init__(self, die: StreamDie, clock: Clock) -> None:
        self.die = die
        self.clock = clock
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing before the driver configures it
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self._slave)
        self.overrun_bytes = 0
        self.bytes_in = 0
        self.bytes_out = 0
        self._stop = threading.Event()
        self._meter = ThreadMeter()  # the pump is wholly the simulator's
        self._thread = threading.Thread(target=self._run, name=f"pty {self.path}", daemon=True)
        self._thread.start()

    def release(self) -> None:
        """The driver has the port open: drop our own slave descriptor, so the pump ends when the
        driver closes its port (reads on the master then fail with EIO)."""
        if self._slave >= 0:
            os.close(self._slave)
            self._slave = -1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.release()
        with contextlib.suppress(OSError):
            os.close(self.master)

    def _wait_s(self) -> float:
        nxt = self.die.next_transmit_ns()
        if nxt is None:
            return MAX_WAKE_NS / 1e9
        wait = min(max(nxt - self.clock.now_ns(), MIN_WAKE_NS), MAX_WAKE_NS)
        return wait / 1e9

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._meter.tick()
                readable, _, _ = select.select([self.master], [], [], self._wait_s())
                if readable:
                    try:
                        data = os.read(self.master, 4096)
                    except BlockingIOError:
                        data = b""
                    if data:
                        self.bytes_in += len(data)
                        self.die.receive(data)
                out = self.die.transmit(self.clock.now_ns())
                if out:
                    self._send(out)
        except OSError as e:
            if e.errno != errno.EIO:  # EIO: the driver closed the port, the link is gone
                log.warning("simulated serial link %s: %s", self.path, e)
        except Exception:
            log.exception("simulated serial link %s failed", self.path)
        finally:
            self._meter.tick()
            self._meter.close()

    def _send(self, out: bytes) -> None:
        try:
            n = os.write(self.master, out)
        except BlockingIOError:
            n = 0
        self.bytes_out += n
        self.overrun_bytes += len(out) - n
