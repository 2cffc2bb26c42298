"""Replacing a file so that a crash or power cut leaves the old contents or the new, never half:
write a temporary file in the same directory, fsync it, rename it over the old one, fsync the
directory. Used for everything imud writes that the daemon reads back (calibration files, a
chip's saved offsets)."""

from __future__ import annotations

import contextlib
import glob
import os
import tempfile
import time
from pathlib import Path

STALE_S = 600.0  # a temporary file this old is a killed writer's leftover, not a live write


def write_atomic(path: Path, text: str) -> None:
    """Replace `path` with `text` (UTF-8); the parent directory is created if missing."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _remove_leftovers(path)
    dfd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dfd)  # the rename itself is durable only once the directory is
    finally:
        os.close(dfd)


def _remove_leftovers(path: Path) -> None:
    """Temporary files of `path` that a writer killed between creating and renaming them left
    behind (a kill cannot run the cleanup above). Only old ones: a young one may be another
    process's write in progress."""
    cutoff = time.time() - STALE_S
    for p in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        with contextlib.suppress(OSError):  # gone already, or not ours to remove
            if p.is_file() and p.stat().st_mtime < cutoff:
                p.unlink()
