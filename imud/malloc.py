"""Fewer glibc malloc arenas for the daemon process, set before its threads start.

glibc gives threads that allocate at the same time arenas of their own (up to eight per core),
and an arena returns memory to the system only from its top (or on `malloc_trim`), so a pattern
of allocations that fragments one heap fragments each of them. The daemon's threads (a relay
per bus, Zenoh's runtime, the event loop) pass batches between them all the time.

This cap was the first answer to the daemon's RSS creeping in the soak, and only a partial one:
with glibc's default the daemon grew by 50 MB in 11 minutes on configs/sim.toml, with at most two
arenas by 6-13 MB in 5. The cause was the relays' `sock.recv(1 MiB)` per message, cutting 1 MiB
blocks out of the heaps (`imud.buslink._recv_buffer` has the story); since they receive into a
buffer of their own the daemon's RSS stays flat with or without this cap (docs/reliability.md,
"Soak": 65.8-66.0 MB over 4-6 minutes either way). It stays as a bound on how far any later
pattern of that kind can spread: two arenas cost some contention on malloc's locks, which at a
few thousand batches a second does not show.
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
