"""CPU time spent in the simulators, per process.

A bus process that drives simulated chips spends part of its CPU on their physics and on their
simulated links; on silicon that part is gone. imud's own cost is the process's CPU less this.
Two ways in:

- calls from a bus worker into a simulated bus or chip (`counted`): the calling thread's CPU time
  across the call, a call nested in a counted one counted once;
- threads that are wholly a simulator's, such as a pty's pump (`ThreadMeter`): the thread's own
  cumulative CPU time, which it records now and then.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable
from typing import ParamSpec, TypeVar

P = ParamSpec("P")
R = TypeVar("R")

_lock = threading.Lock()
_calls_ns = 0  # counted calls, all threads
_ended_ns = 0  # meters of threads that have ended
_meters: set[ThreadMeter] = set()


class _Local(threading.local):
    inside = False  # within a counted call on this thread


_local = _Local()


def counted(fn: Callable[P, R]) -> Callable[P, R]:
    """`fn`'s CPU time on the calling thread counts as the simulators'."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        if _local.inside:
            return fn(*args, **kwargs)
        _local.inside = True
        t0 = time.thread_time_ns()
        try:
            return fn(*args, **kwargs)
        finally:
            spent = time.thread_time_ns() - t0
            _local.inside = False
            global _calls_ns
            with _lock:
                _calls_ns += spent

    return wrapper


class ThreadMeter:
    """The CPU time of a thread that is wholly a simulator's: it calls `tick` from itself now and
    then (each costs about 0.6 us), and `close` once it is done."""

    def __init__(self) -> None:
        self.ns = 0
        with _lock:
            _meters.add(self)

    def tick(self) -> None:
        self.ns = time.thread_time_ns()  # the calling thread's total since it started

    def close(self) -> None:
        global _ended_ns
        with _lock:
            if self in _meters:
                _meters.discard(self)
                _ended_ns += self.ns


def total_ns() -> int:
    """The simulators' CPU time in this process so far, ns."""
    with _lock:
        return _calls_ns + _ended_ns + sum(m.ns for m in _meters)
