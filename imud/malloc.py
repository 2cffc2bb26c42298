"""Fewer glibc malloc arenas for the daemon process, set before its threads start.

glibc gives threads that allocate at the same time arenas of their own (up to eight per core),
and an arena returns memory to the system only from its top, so payloads allocated by one thread
and freed by another leave each arena fragmented. The daemon's threads (a relay per bus,
Zenoh's runtime, the event loop) pass batches between them all the time: measured with
`bench/soak.py --config configs/sim.toml`, its RSS grew by 50 MB in the 11 minutes after warm-up
with glibc's default, and by 6 MB in 5 minutes, levelling off, with at most two arenas
(docs/reliability.md, "Soak"). Two arenas cost some contention on malloc's locks, which at a few
thousand batches a second does not show.
"""

from __future__ import annotations

import ctypes
import os
import sys

M_ARENA_MAX = -8  # glibc's <malloc.h>
ARENAS = 2


def cap_arenas(n: int = ARENAS) -> bool:
    """mallopt(M_ARENA_MAX, n) on glibc. False, and nothing done, where the C library has no
    mallopt (musl) or MALLOC_ARENA_MAX is set in the environment (the operator's choice)."""
    if os.environ.get("MALLOC_ARENA_MAX") or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_ARENA_MAX, n))
