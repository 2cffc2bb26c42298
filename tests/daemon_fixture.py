"""Run the real daemon as a subprocess on a loopback port, with a fake systemd notify socket."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from tests.helpers import free_port


class DaemonProc:
    def __init__(
        self,
        tmp: Path,
        config_body: str,
        watchdog_usec: int = 1_000_000,
        session: bool = False,
        env: dict[str, str] | None = None,
    ) -> None:
        """`session`: the daemon leads a process group of its own (its bus processes in it),
        as under systemd, so the whole group can be signalled at once. `env`: added to the
        daemon's environment (its bus processes inherit it)."""
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.config = tmp / "imud.toml"
        self.config.write_text(
            f'[zenoh]\nlisten = ["{self.endpoint}"]\nprefix = "imud"\n\n' + config_body
        )
        self.notify_path = str(tmp / "notify.sock")
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.notify.bind(self.notify_path)
        self.notify.settimeout(0.1)
        self.messages: list[str] = []
        self._session: Any = None  # a Zenoh session of this process's, once the daemon answers
        self.log = tmp / "daemon.log"
        env = {
            **os.environ,
            "NOTIFY_SOCKET": self.notify_path,
            "WATCHDOG_USEC": str(watchdog_usec),
            **(env or {}),
        }
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "imud", "run", "--config", str(self.config)],
            stdout=subprocess.DEVNULL,
            stderr=open(self.log, "wb"),  # noqa: SIM115 - owned by the process
            env=env,
            start_new_session=session,
        )

    def cli(self, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "imud", *args],
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    def status(self, timeout: float = 10.0) -> dict[str, Any]:
        """The daemon's status, asked from this process (not through `imud status`: a CLI
        process per question competes with the daemon under test for the CPU)."""
        from imud.session import NoDaemon, get_status

        if self._session is None:
            self._session = self.answering_session()
        try:
            return get_status(self._session, timeout=timeout)
        except NoDaemon:
            raise AssertionError(f"the daemon did not answer:\n{self.log.read_text()}") from None

    def drain_notify(self) -> list[str]:
        while True:
            try:
                self.messages.append(self.notify.recv(4096).decode())
            except (TimeoutError, BlockingIOError):
                return self.messages

    def wait_started(self, timeout: float = 60.0) -> dict[str, Any]:
        """Until the daemon answers and no device is still starting."""
        from imud.session import NoDaemon, get_status

        end = time.monotonic() + timeout
        if self._session is None:
            self._session = self.answering_session()
        while time.monotonic() < end:
            assert self.proc.poll() is None, self.log.read_text()
            try:
                st = get_status(self._session, timeout=1.0)
            except NoDaemon:
                continue
            if all(d["state"] != "starting" for d in st["devices"]):
                return st
            time.sleep(0.1)
        raise AssertionError(f"daemon did not start:\n{self.log.read_text()}")

    def answering_session(self) -> Any:
        """A Zenoh session (`zenoh.Session`) to the daemon as soon as it answers a status query
        (its devices may still be starting)."""
        import imud.client as ic

        for _ in range(600):
            assert self.proc.poll() is None, self.log.read_text()
            try:
                s = ic.open_session(self.endpoint)
            except ic.NoDaemon:  # not listening yet
                time.sleep(0.1)
                continue
            try:
                ic.get_status(s, timeout=1.0)
                return s
            except ic.NoDaemon:
                s.close()
                time.sleep(0.1)
        raise AssertionError(f"the daemon never answered:\n{self.log.read_text()}")

    def collect(
        self,
        key: str,
        seconds: float,
        depth: int = 65536,
        until: threading.Event | None = None,
    ) -> list[bytes]:
        """Raw payloads a real subscriber on `key` receives for `seconds`, or until `until` is
        set if given (`seconds` then only bounds a broken test). Decoded later, so decoding
        does not compete with the daemon under test on a small machine."""
        import zenoh

        import imud.client as ic

        raw: list[bytes] = []
        with ic.open_session(self.endpoint) as s:
            sub = s.declare_subscriber(key, zenoh.handlers.FifoChannel(depth))
            end = time.monotonic() + seconds
            while time.monotonic() < end and not (until is not None and until.is_set()):
                sample = sub.try_recv()
                if sample is None:
                    time.sleep(0.01)
                    continue
                raw.append(sample.payload.to_bytes())
            sub.undeclare()  # type: ignore[no-untyped-call]
        return raw

    def stop(self, sig: int = signal.SIGTERM) -> tuple[int, float]:
        if self._session is not None:
            self._session.close()
            self._session = None
        if self.proc.poll() is not None:
            return self.proc.returncode, 0.0
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        self.notify.close()
        return code, time.monotonic() - t0
