"""Publishing off the acquisition path.

Bus workers must never wait for the network (a 32 kHz FIFO lasts 4 ms), and subscribers should
not lose batches to a momentary transport stall. So workers hand encoded batches to one publisher
thread through a bounded queue, and that thread puts them with congestion control BLOCK. Only
when a subscriber stays stuck until the queue is full are batches dropped, and then counted per
device (`publish_dropped` in status).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

from imud.rt import go_realtime

log = logging.getLogger("imud.publisher")
QUEUE_DEPTH = 20_000  # batches: seconds of every device's stream


class PublisherThread:
    def __init__(self, depth: int = QUEUE_DEPTH, realtime_priority: int | None = None) -> None:
        self.realtime_priority = realtime_priority
        self._q: queue.Queue[tuple[Callable[[bytes], Any], bytes, Any] | None] = queue.Queue(depth)
        self._thread = threading.Thread(target=self._run, name="publisher", daemon=True)
        self.published = 0

    def start(self) -> None:
        self._thread.start()

    def submit(self, put: Callable[[bytes], Any], payload: bytes, on_drop: Any) -> None:
        """Non-blocking: queue one batch, or call `on_drop()` when the queue is full."""
        try:
            self._q.put_nowait((put, payload, on_drop))
        except queue.Full:
            on_drop()

    def _run(self) -> None:
        if self.realtime_priority:
            # it takes the GIL for every put: preempted by some other process while holding it,
            # it would stall the real-time bus workers (priority inversion). Rank just below them.
            go_realtime(self.realtime_priority, "publisher")
        while True:
            item = self._q.get()
            if item is None:
                return
            put, payload, _ = item
            try:
                put(payload)
                self.published += 1
            except Exception:  # a closed session at shutdown, a Zenoh error: log, go on
                log.exception("publishing failed")

    def stop(self, timeout: float = 1.0) -> None:
        """Flush what is queued (for at most `timeout`), then end the thread."""
        try:
            self._q.put(None, timeout=timeout)
        except queue.Full:
            return
        self._thread.join(timeout)
