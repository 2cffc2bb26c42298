"""Where a process's resident memory is: every `--interval` seconds, one line of /proc/PID/smaps
broken down by kind of mapping, for finding which allocator holds a process's growth.

Columns (MB of RSS): `rss` (all), `anon` and `file` (smaps_rollup's Anonymous and the rest),
`heap` (the [heap] mapping: glibc's main arena, grown with brk), `arenas` (anonymous mappings
inside a 64 MB-aligned reservation of 64 MB: glibc's other arenas, one per thread that
allocated while the others' were locked, up to M_ARENA_MAX), `other` (the remaining anonymous
mappings: chunks glibc mmapped on their own (at or over its mmap threshold), thread stacks,
Rust's and numpy's big buffers), `n_anon` (how many anonymous mappings), `threads`.

    .venv/bin/python bench/memwatch.py PID [--interval 10] [--minutes 6]

Stops when the process ends.
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

ARENA = 64 << 20  # glibc's HEAP_MAX_SIZE on 64-bit: 2 * DEFAULT_MMAP_THRESHOLD_MAX
_HEAD = re.compile(r"^([0-9a-f]+)-([0-9a-f]+) \S+ \S+ \S+ (\d+)\s*(.*)$")


def breakdown(pid: int) -> dict[str, float]:
    """MB of RSS by kind (see the module docstring)."""
    text = Path(f"/proc/{pid}/smaps").read_text()
    out = dict.fromkeys(("rss", "anon", "file", "heap", "arenas", "other"), 0.0)
    n_anon = 0
    cur: tuple[int, int, str, bool] | None = None
    arena_bases: set[int] = set()
    maps: list[tuple[int, int, str, int]] = []  # start, end, name, rss kB
    for line in text.splitlines():
        m = _HEAD.match(line)
        if m:
            start, end = int(m.group(1), 16), int(m.group(2), 16)
            name = m.group(4).strip()
            cur = (start, end, name, int(m.group(3)) == 0)
            continue
        if cur is not None and line.startswith("Rss:"):
            rss = int(line.split()[1])
            maps.append((cur[0], cur[1], cur[2], rss))
            if cur[3] and not cur[2] and cur[0] % ARENA == 0:
                arena_bases.add(cur[0])
    for start, end, name, rss in maps:
        mb = rss / 1024
        out["rss"] += mb
        if name and not name.startswith("["):
            out["file"] += mb
            continue
        out["anon"] += mb
        if name == "[heap]":
            out["heap"] += mb
        elif not name:
            n_anon += 1
            base = start - start % ARENA
            if base in arena_bases and end <= base + ARENA:
                out["arenas"] += mb
            else:
                out["other"] += mb
        else:
            out["other"] += mb  # [stack] and the like
    out["n_anon"] = n_anon
    status = Path(f"/proc/{pid}/status").read_text()
    m = re.search(r"^Threads:\s+(\d+)", status, re.M)
    out["threads"] = int(m.group(1)) if m else 0
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("pid", type=int)
    ap.add_argument("--interval", type=float, default=10.0)
    ap.add_argument("--minutes", type=float, default=1e9)
    args = ap.parse_args()
    t0 = time.monotonic()
    end = t0 + args.minutes * 60
    print("     t    rss   anon   file   heap arenas  other n_anon threads", flush=True)
    while time.monotonic() < end:
        try:
            b = breakdown(args.pid)
        except (OSError, ValueError):
            return 0
        print(f"{time.monotonic() - t0:6.0f} {b['rss']:6.1f} {b['anon']:6.1f} {b['file']:6.1f} "
              f"{b['heap']:6.1f} {b['arenas']:6.1f} {b['other']:6.1f} {b['n_anon']:6.0f} "
              f"{b['threads']:7.0f}", flush=True)  # fmt: skip
        time.sleep(args.interval)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
