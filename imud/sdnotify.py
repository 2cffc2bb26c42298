"""sd_notify(3) in a few lines: one datagram to $NOTIFY_SOCKET; a no-op outside systemd."""

from __future__ import annotations

import contextlib
import os
import socket


class Notifier:
    def __init__(self) -> None:
        addr = os.environ.get("NOTIFY_SOCKET", "")
        self._addr = "\0" + addr[1:] if addr.startswith("@") else addr
        self._sock: socket.socket | None = None
        if self._addr:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            # never wait for the manager: a full queue would otherwise freeze the event loop
            self._sock.setblocking(False)
        usec = os.environ.get("WATCHDOG_USEC")
        pid = os.environ.get("WATCHDOG_PID")
        ok = usec is not None and usec.isdigit() and (pid is None or pid == str(os.getpid()))
        self.watchdog_s: float | None = int(usec) / 1e6 if ok and usec else None

    def notify(self, *lines: str) -> None:
        if self._sock is None:
            return
        with contextlib.suppress(OSError):  # systemd busy or gone: drop this notification
            self._sock.sendto("\n".join(lines).encode(), self._addr)
