"""Bus processes forked from a copy of the daemon made before it starts any thread of its own.

The daemon has imported everything a bus process runs (the worker, the drivers, NumPy,
pydantic) by the time it starts; a zygote forked from it then, before Zenoh, the event loop or
any relay thread exists, forks each bus process on request. A bus process so starts in a few
milliseconds and shares the imported pages with the daemon and its siblings: an interpreter of
its own would spend ~0.9 s of CPU importing the same modules, and a fork server
(`multiprocessing`'s) another interpreter doing so for each daemon.

Requests and answers go over one SOCK_SEQPACKET socket: b"S" + the spec as JSON, with the bus
socket's descriptor attached (SCM_RIGHTS), answered by b"P" + pid; the zygote reaps its children
and reports b"X" + pid + exit code (negative: the signal that ended it). The zygote ends when the
daemon's end of the socket closes.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import socket
import struct
import threading
from typing import Any

SPAWN = b"S"
SPAWNED = b"P"
EXITED = b"X"
_PID = struct.Struct("<i")
_EXIT = struct.Struct("<ii")
_REAP_EVERY_S = 0.1
_MAX = 1 << 20


def _threads() -> int:
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return threading.active_count()


def _serve(ctl: socket.socket) -> None:
    """The zygote: fork a bus process per request; report each one's end."""
    # Ctrl-C and a SIGTERM to the whole process group are the daemon's to handle: it stops its
    # bus processes, whose ends the zygote reports, then closes the socket, which ends it
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    children: set[int] = set()
    while True:
        ready, _, _ = select.select([ctl], [], [], _REAP_EVERY_S)
        for pid in list(children):
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                children.discard(pid)
                code = os.waitstatus_to_exitcode(status)
                with contextlib.suppress(OSError):
                    ctl.send(EXITED + _EXIT.pack(pid, code))
        if not ready:
            continue
        msg, fds, _, _ = socket.recv_fds(ctl, _MAX, 1)
        if not msg:  # the daemon is gone
            return
        if msg[:1] != SPAWN or len(fds) != 1:
            for fd in fds:
                os.close(fd)
            continue
        spec = json.loads(msg[1:])
        pid = os.fork()
        if pid == 0:
            code = 0
            try:
                ctl.close()
                from imud.buschild import child_main

                child_main(socket.socket(fileno=fds[0]), spec)
            except BaseException:
                code = 1
            finally:
                os._exit(code)
        os.close(fds[0])
        children.add(pid)
        ctl.send(SPAWNED + _PID.pack(pid))


class Zygote:
    """The daemon's handle on its zygote. Made before any thread starts (`fork_safe`)."""

    def __init__(self) -> None:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        import imud.buschild  # noqa: F401  (what the bus processes run: imported once, here)

        pid = os.fork()
        if pid == 0:
            code = 0
            try:
                ours.close()
                _serve(theirs)
            except BaseException:
                code = 1
            finally:
                os._exit(code)
        theirs.close()
        self.pid = pid
        self._sock = ours
        self._lock = threading.Lock()  # one spawn at a time
        self._cond = threading.Condition()
        self._spawned: list[int] = []
        self._exits: dict[int, int] = {}
        self._alive = True
        threading.Thread(target=self._read, name="zygote", daemon=True).start()

    @staticmethod
    def fork_safe() -> bool:
        """Whether this process can fork a zygote now: no Python thread runs but the main one,
        and no other OS thread but the pool NumPy's BLAS keeps idle (it re-initialises it in a
        forked child, as in any fork server)."""
        import numpy  # noqa: F401  (imported now, so its pool is counted below)

        blas = max(0, _threads() - 1)
        return threading.active_count() == 1 and blas <= (os.cpu_count() or 1)

    def _read(self) -> None:
        while True:
            try:
                msg = self._sock.recv(64)
            except OSError:
                msg = b""
            with self._cond:
                if not msg:
                    self._alive = False
                    self._cond.notify_all()
                    return
                if msg[:1] == SPAWNED:
                    self._spawned.append(_PID.unpack_from(msg, 1)[0])
                elif msg[:1] == EXITED:
                    pid, code = _EXIT.unpack_from(msg, 1)
                    self._exits[pid] = code
                self._cond.notify_all()

    def spawn(self, sock: socket.socket, spec: dict[str, Any]) -> int:
        """A bus process running `imud.buschild.child_main` on `sock`; its pid."""
        with self._lock:
            socket.send_fds(self._sock, [SPAWN + json.dumps(spec).encode()], [sock.fileno()])
            with self._cond:
                if not self._cond.wait_for(lambda: self._spawned or not self._alive, 30.0):
                    raise OSError("the zygote did not answer a spawn request within 30 s")
                if not self._spawned:
                    raise OSError("the zygote is gone")
                return self._spawned.pop(0)

    def wait(self, pid: int, timeout: float) -> int | None:
        """The exit code of a bus process once it ended (within `timeout` s), else None."""
        with self._cond:
            self._cond.wait_for(lambda: pid in self._exits or not self._alive, timeout)
            return self._exits.get(pid)

    def ended(self, pid: int) -> bool:
        with self._cond:
            return pid in self._exits

    @property
    def alive(self) -> bool:
        return self._alive

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.close()
