"""An MCAP file as imud writes it: profile `ros2`, schemas `ros2msg`, messages `cdr`, chunked
and compressed, with chunk indexes and a summary (so Foxglove, rosbags and `ros2 bag` treat it as
indexed), the daemon's config and calibration files as attachments.

Crash safety: the writer closes its chunk and hands the bytes to the kernel every `flush_s` of
wall time (and fsyncs them), so a recorder killed with SIGKILL, or a power cut, loses at most
that much: the file is then complete up to the last flush but has no footer, which `imud record
--recover` (imud/recording/recover.py) turns into an indexed file. A library's default 1 MiB
chunk would hold seconds of a fast device, and the first chunk nothing until it fills
(a writer killed with its defaults leaves 0 bytes on disk).

Splitting: `split_bytes` / `split_s` start a new file (`NAME_001.mcap`, ...) once the current
one reaches that size or span; each file is whole on its own (schemas, channels, attachments).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from imud import __version__
from imud.recording.mcapwrite import McapWriter
from imud.recording.schemas import definition

FLUSH_S = 1.0
LIBRARY = f"imud {__version__}"


@dataclass(frozen=True)
class Attachment:
    name: str
    media_type: str
    data: bytes
    created_ns: int = 0


@dataclass
class _File:
    path: Path
    stream: IO[bytes]
    writer: McapWriter
    started_ns: int  # the first message's log time
    channels: dict[tuple[str, str], int] = field(default_factory=dict)
    schemas: dict[str, int] = field(default_factory=dict)


class McapOut:
    """Messages into one MCAP file, or a series of them. `add(topic, type_name, log_ns,
    payload)` writes one CDR message; `close()` writes the summary. Not thread-safe: one
    writer thread."""

    def __init__(
        self,
        path: Path,
        attachments: list[Attachment] | None = None,
        metadata: dict[str, dict[str, str]] | None = None,
        split_bytes: int | None = None,
        split_s: float | None = None,
        flush_s: float = FLUSH_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.base = path
        self.attachments = list(attachments or [])
        self.metadata = dict(metadata or {})
        self.split_bytes = split_bytes
        self.split_ns = None if split_s is None else int(split_s * 1e9)
        self.flush_s = flush_s
        self.clock = clock
        self.paths: list[Path] = []  # every file written, in order
        self.messages = 0
        self._sequence: dict[str, int] = {}  # per topic, from 1, across files
        self._file: _File | None = None
        self._last_flush = clock()

    # --- files ------------------------------------------------------------------------------
    def _name(self, k: int) -> Path:
        if self.split_bytes is None and self.split_ns is None:
            return self.base
        return self.base.with_name(f"{self.base.stem}_{k:03d}{self.base.suffix or '.mcap'}")

    def _open(self, first_ns: int) -> _File:
        path = self._name(len(self.paths))
        stream = open(path, "xb")  # noqa: SIM115 - closed by _close_file
        writer = McapWriter(stream, profile="ros2", library=LIBRARY)
        for name, data in self.metadata.items():
            writer.metadata(name, data)
        for a in self.attachments:
            created = a.created_ns or time.time_ns()
            writer.attachment(created, created, a.name, a.media_type, a.data)
        self.paths.append(path)
        f = _File(path, stream, writer, first_ns)
        self._file = f
        self._sync(f)  # the header and attachments on disk before the first message
        return f

    def _close_file(self, f: _File) -> None:
        f.writer.finish()
        f.stream.flush()
        os.fsync(f.stream.fileno())
        f.stream.close()
        self._file = None

    def _sync(self, f: _File) -> None:
        f.writer.flush()  # closes the open chunk
        f.stream.flush()
        os.fsync(f.stream.fileno())
        self._last_flush = self.clock()

    # --- messages ---------------------------------------------------------------------------
    def add(self, topic: str, type_name: str, log_ns: int, payload: bytes) -> None:
        """One message."""
        f = self._at(log_ns)
        seq = self._sequence.get(topic, 0) + 1
        self._sequence[topic] = seq
        f.writer.message(self._cid(f, topic, type_name), log_ns, seq, payload)
        self._written(f, 1)

    def add_many(
        self, topic: str, type_name: str, log_ns: npt.NDArray[np.int64], data: bytes, size: int
    ) -> None:
        """len(log_ns) messages of `size` bytes each (`data`, end to end), in log-time order: a
        split due among them starts the next file at the first message it is due for."""
        n = int(log_ns.shape[0])
        i = 0
        while i < n:
            f = self._at(int(log_ns[i]))
            j = n
            if self.split_ns is not None:
                j = i + int(np.searchsorted(log_ns[i:], f.started_ns + self.split_ns))
                j = max(j, i + 1)
            seq = self._sequence.get(topic, 0) + 1
            self._sequence[topic] = seq + (j - i) - 1
            cid = self._cid(f, topic, type_name)
            f.writer.messages(cid, log_ns[i:j], seq, data[i * size : j * size], size)
            self._written(f, j - i)
            i = j

    def _at(self, log_ns: int) -> _File:
        """The file a message logged at `log_ns` goes into (the next one once a split is due)."""
        f = self._file
        if f is not None and self._split_due(f, log_ns):
            self._close_file(f)
            f = None
        return self._open(log_ns) if f is None else f

    def _cid(self, f: _File, topic: str, type_name: str) -> int:
        cid = f.channels.get((topic, type_name))
        return self._channel(f, topic, type_name) if cid is None else cid

    def _written(self, f: _File, n: int) -> None:
        self.messages += n
        if self.clock() - self._last_flush >= self.flush_s:
            self._sync(f)

    def _channel(self, f: _File, topic: str, type_name: str) -> int:
        sid = f.schemas.get(type_name)
        if sid is None:
            sid = f.writer.schema(type_name, "ros2msg", definition(type_name).encode())
            f.schemas[type_name] = sid
        # rosbag2's player reads the QoS it offered from here (empty: its defaults)
        meta = {"offered_qos_profiles": ""}
        cid = f.writer.channel(topic, "cdr", sid, meta)
        f.channels[(topic, type_name)] = cid
        return cid

    def _split_due(self, f: _File, log_ns: int) -> bool:
        if self.split_ns is not None and log_ns - f.started_ns >= self.split_ns:
            return True
        return self.split_bytes is not None and f.stream.tell() >= self.split_bytes

    def flush(self) -> None:
        """Hand everything so far to the disk (a flush point, as every `flush_s`)."""
        if self._file is not None:
            self._sync(self._file)

    def bytes_written(self) -> int:
        """The bytes in the files so far (the current one's as flushed)."""
        done = sum(p.stat().st_size for p in self.paths[:-1]) if len(self.paths) > 1 else 0
        return done + (self._file.stream.tell() if self._file is not None else 0)

    def close(self) -> None:
        """The summary and footer of the open file: it is then indexed and complete."""
        if self._file is not None:
            self._close_file(self._file)

    def __enter__(self) -> McapOut:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
