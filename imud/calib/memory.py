"""Whether this process can have the memory a large recording needs, asked before it is spent.

A recording of hours at a high rate holds tens of millions of rows; reading and calibrating it
costs a fixed number of bytes a row. Asked first, a machine without them gets a refusal that
names the sizes and the fix; not asked, the kernel's OOM killer ends the process half-way with
no word (or, under an address-space limit, NumPy raises MemoryError from deep inside).

What is free is the least of: the kernel's MemAvailable, what the process's address-space
limit (RLIMIT_AS, `ulimit -v`) leaves, and what its cgroup's memory.max leaves (a container or
a systemd unit with MemoryMax=)."""

from __future__ import annotations

import resource
from pathlib import Path

_PROC = Path("/proc")
_CGROUP_ROOT = Path("/sys/fs/cgroup")


def _kib_field(text: str, name: str) -> int | None:
    for line in text.splitlines():
        if line.startswith(name + ":"):
            fields = line.split()
            if len(fields) >= 2 and fields[1].isdigit():
                return int(fields[1]) * 1024
    return None


def _read(path: Path) -> str | None:
    try:
        return path.read_text()
    except OSError:
        return None


def _meminfo_available() -> int | None:
    text = _read(_PROC / "meminfo")
    return None if text is None else _kib_field(text, "MemAvailable")


def _address_space_left() -> int | None:
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    status = _read(_PROC / "self" / "status")
    used = None if status is None else _kib_field(status, "VmSize")
    return max(0, soft - (used or 0))


def _cgroup_left() -> int | None:
    """cgroup v2: the process's group's memory.max less its memory.current."""
    text = _read(_PROC / "self" / "cgroup")
    if text is None:
        return None
    for line in text.splitlines():
        if line.startswith("0::"):
            group = _CGROUP_ROOT / line[3:].lstrip("/")
            limit, current = _read(group / "memory.max"), _read(group / "memory.current")
            if limit is None or current is None or not limit.strip().isdigit():
                return None  # "max": no limit of its own
            return max(0, int(limit) - int(current.strip() or 0))
    return None


def available() -> int | None:
    """Bytes this process can still allocate, or None where the machine does not say."""
    known = [v for v in (_meminfo_available(), _address_space_left(), _cgroup_left()) if v]
    return min(known) if known else None


def shortfall(need: int, what: str) -> str | None:
    """None when `need` bytes fit; else a sentence for the user naming both sizes and the fix.
    what: the thing needing them, e.g. "10,000,000 rows"."""
    free = available()
    if free is None or need <= free:
        return None
    return (
        f"{what} need about {size_text(need)} of memory to read and calibrate, and "
        f"{size_text(free)} is free: a calibration needs minutes of data, not hours; cut the "
        "recording (its first million rows: `head -n 1000001 FILE > part.csv`) or run where "
        "memory is free"
    )


def size_text(n: int) -> str:
    """A byte count as people say it: 683 MB, 2.1 GB."""
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"
