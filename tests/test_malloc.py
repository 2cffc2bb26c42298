"""The daemon caps glibc's malloc arenas (imud.malloc) unless the environment already chose."""

from __future__ import annotations

import os
import subprocess
import sys

PROBE = "from imud.malloc import cap_arenas; print(cap_arenas())"


def _probe(env: dict[str, str]) -> str:
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env,
                       timeout=30, check=True)  # fmt: skip
    return r.stdout.strip()


def test_arenas_are_capped_on_glibc() -> None:
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    libc = os.confstr("CS_GNU_LIBC_VERSION") or ""
    assert libc.startswith("glibc")  # this machine's C library: Debian's
    assert _probe(env) == "True"  # mallopt accepted M_ARENA_MAX


def test_an_operators_malloc_arena_max_stands() -> None:
    assert _probe({**os.environ, "MALLOC_ARENA_MAX": "4"}) == "False"
