"""An MCAP writer that takes a stream's messages a NumPy batch at a time.

Why not the `mcap` library's Writer for the messages: it builds, encodes and indexes each message
with Python calls (about 6 µs a message here), and a recording of the quick start writes some
1,800 messages a second, most of them fixed-size ROS 2 messages that imud already holds as one
NumPy record array. Here a batch's message records and its index entries are filled column by
column. Measured in `bench/record_cost.py` (docs/performance.md §16). The other records (header,
schemas, channels, chunks, indexes, summary, footer) are the library's own record classes.

The file: magic, header, then schemas, channels, attachments and metadata as they come, and
chunks (zstd) each followed by its message indexes; `finish` writes the data end, the summary
(schemas, channels, statistics, chunk, attachment and metadata indexes, summary offsets), footer
and magic. Every CRC the format has is filled in.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from typing import IO

import numpy as np
import numpy.typing as npt
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
CHUNK_BYTES = 4 << 20  # uncompressed: a chunk closes here, or at `flush`
ZSTD_LEVEL = 3  # the library's: level 1 saves 0.08 % of a core and makes files 12 % larger
_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # a message record before its data: opcode, length, channel, ...
_MSG = struct.Struct("<BQHIQQ")
_MESSAGE_INDEX = struct.Struct("<BQHI")  # opcode, length, channel, records' byte length
I64 = npt.NDArray[np.int64]


def _head_dtype(size: int) -> np.dtype[np.void]:
    return np.dtype(
        [
            ("op", "u1"),
            ("len", "<u8"),
            ("ch", "<u2"),
            ("seq", "<u4"),
            ("log", "<u8"),
            ("pub", "<u8"),
            ("data", f"V{size}"),
        ]
    )


class McapWriter:
    """One MCAP file onto `stream` (binary, seekable not needed). Not thread-safe."""

    def __init__(
        self,
        stream: IO[bytes],
        profile: str,
        library: str,
        chunk_bytes: int = CHUNK_BYTES,
        level: int = ZSTD_LEVEL,
    ) -> None:
        self._stream = stream
        self._pos = 0  # bytes written to the stream
        self._crc = 0  # of the data section
        self._chunk_bytes = chunk_bytes
        self._zstd = zstandard.ZstdCompressor(level=level)
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._stats = Statistics(
            attachment_count=0,
            channel_count=0,
            channel_message_counts=defaultdict(int),
            chunk_count=0,
            message_count=0,
            message_end_time=0,
            message_start_time=0,
            metadata_count=0,
            schema_count=0,
        )
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        # the open chunk: its records, size, span, and per channel (log times, offsets)
        self._parts: list[bytes] = []
        self._size = 0
        self._start = self._end = 0
        self._batches: dict[int, list[tuple[I64, I64]]] = defaultdict(list)
        self._singles: dict[int, list[int]] = defaultdict(list)  # log time, offset, ...
        self._write(MAGIC)
        self._record(Header(profile=profile, library=library))

    # --- the data section --------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        self._stream.write(data)
        self._crc = zlib.crc32(data, self._crc)
        self._pos += len(data)

    def _record(self, r: McapRecord) -> int:
        """Write one record; returns its offset in the file."""
        b = RecordBuilder()
        r.write(b)
        at = self._pos
        self._write(_end(b))
        return at

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        s = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._schemas[sid] = s
        self._stats.schema_count += 1
        self._record(s)
        return sid

    def channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str]
    ) -> int:
        cid = len(self._channels) + 1
        c = Channel(
            id=cid,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=metadata,
        )
        self._channels[cid] = c
        self._stats.channel_count += 1
        self._record(c)
        return cid

    def attachment(
        self, create_ns: int, log_ns: int, name: str, media_type: str, data: bytes
    ) -> None:
        a = Attachment(
            create_time=create_ns, log_time=log_ns, name=name, media_type=media_type, data=data
        )
        b = RecordBuilder()
        a.write(b)
        at = self._pos
        self._write(_end(b))
        self._stats.attachment_count += 1
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=at,
                length=self._pos - at,
                create_time=create_ns,
                log_time=log_ns,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )

    def metadata(self, name: str, data: dict[str, str]) -> None:
        at = self._record(Metadata(name=name, metadata=data))
        self._stats.metadata_count += 1
        self._metadata_indexes.append(MetadataIndex(offset=at, length=self._pos - at, name=name))

    # --- messages ----------------------------------------------------------------------------
    def message(self, channel_id: int, log_ns: int, sequence: int, data: bytes) -> None:
        """One message (a variable-size one: a native batch, a diagnostics array)."""
        rec = _MSG.pack(Opcode.MESSAGE, _HEAD - 9 + len(data), channel_id, sequence & 0xFFFFFFFF,
                        log_ns, log_ns) + data  # fmt: skip
        self._singles[channel_id].extend((log_ns, self._size))
        self._add(channel_id, rec, log_ns, log_ns, 1)

    def messages(
        self, channel_id: int, log_ns: I64, first_sequence: int, data: bytes, size: int
    ) -> None:
        """len(log_ns) messages of `size` bytes each, `data` their payloads end to end, sequence
        numbers from `first_sequence` on, published at their log times."""
        n = int(log_ns.shape[0])
        if not n:
            return
        if len(data) != n * size:
            raise ValueError(f"{len(data)} bytes are not {n} messages of {size}")
        rec = np.empty(n, dtype=_head_dtype(size))
        rec["op"] = Opcode.MESSAGE
        rec["len"] = _HEAD - 9 + size
        rec["ch"] = channel_id
        rec["seq"] = (first_sequence + np.arange(n, dtype=np.int64)) & 0xFFFFFFFF
        rec["log"] = log_ns
        rec["pub"] = log_ns
        rec["data"] = np.frombuffer(data, dtype=f"V{size}")
        offsets = self._size + np.arange(n, dtype=np.int64) * (_HEAD + size)
        self._batches[channel_id].append((np.asarray(log_ns, dtype=np.int64), offsets))
        self._add(channel_id, rec.tobytes(), int(log_ns.min()), int(log_ns.max()), n)

    def _add(self, channel_id: int, rec: bytes, lo: int, hi: int, n: int) -> None:
        s = self._stats
        if s.message_count == 0:
            s.message_start_time, s.message_end_time = lo, hi
        else:
            s.message_start_time = min(lo, s.message_start_time)
            s.message_end_time = max(hi, s.message_end_time)
        s.message_count += n
        s.channel_message_counts[channel_id] += n
        if not self._parts:
            self._start, self._end = lo, hi
        else:
            self._start, self._end = min(lo, self._start), max(hi, self._end)
        self._parts.append(rec)
        self._size += len(rec)
        if self._size >= self._chunk_bytes:
            self.flush()

    # --- chunks and the summary -------------------------------------------------------------
    def flush(self) -> None:
        """Close the open chunk: it and its message indexes go to the stream (a reader of the
        file as it stands then has every message so far). The stream is not flushed here."""
        if not self._parts:
            return
        data = b"".join(self._parts)
        packed = self._zstd.compress(data)
        chunk = Chunk(
            compression="zstd",
            data=packed,
            message_start_time=self._start,
            message_end_time=self._end,
            uncompressed_crc=zlib.crc32(data),
            uncompressed_size=len(data),
        )
        at = self._record(chunk)
        chunk_length = self._pos - at
        index_at = self._pos
        offsets: dict[int, int] = {}
        for cid in sorted({*self._batches, *self._singles}):
            offsets[cid] = self._pos
            self._write(_message_index(cid, self._batches.get(cid, []), self._singles.get(cid, [])))
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=self._start,
                message_end_time=self._end,
                chunk_start_offset=at,
                chunk_length=chunk_length,
                message_index_offsets=offsets,
                message_index_length=self._pos - index_at,
                compression="zstd",
                compressed_size=len(packed),
                uncompressed_size=len(data),
            )
        )
        self._stats.chunk_count += 1
        self._parts, self._size = [], 0
        self._batches, self._singles = defaultdict(list), defaultdict(list)

    def finish(self) -> None:
        """The last chunk, the data end, the summary and the footer; the stream is left open."""
        self.flush()
        self._record(DataEnd(data_section_crc=self._crc))
        start = self._pos
        b = RecordBuilder()
        groups: list[SummaryOffset] = []

        def group(op: Opcode, records: list[McapRecord]) -> None:
            if not records:
                return
            g = b.count
            for r in records:
                r.write(b)
            groups.append(
                SummaryOffset(group_opcode=op, group_start=start + g, group_length=b.count - g)
            )

        group(Opcode.SCHEMA, list(self._schemas.values()))
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(Opcode.STATISTICS, [self._stats])
        group(Opcode.CHUNK_INDEX, list(self._chunk_indexes))
        group(Opcode.ATTACHMENT_INDEX, list(self._attachment_indexes))
        group(Opcode.METADATA_INDEX, list(self._metadata_indexes))
        offsets_at = start + b.count
        for o in groups:
            o.write(b)
        summary = _end(b)
        tail = struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, start, offsets_at)
        crc = zlib.crc32(tail, zlib.crc32(summary))
        self._stream.write(summary)
        f = RecordBuilder()
        Footer(summary_start=start, summary_offset_start=offsets_at, summary_crc=crc).write(f)
        self._stream.write(_end(f))
        self._stream.write(MAGIC)


def _message_index(channel_id: int, batches: list[tuple[I64, I64]], singles: list[int]) -> bytes:
    """A channel's message index record for a chunk: (log time, offset) of each message."""
    pairs = [np.asarray(singles, dtype="<u8").reshape(-1, 2)]
    pairs += [np.column_stack((t, o)).astype("<u8") for t, o in batches]
    body = np.concatenate(pairs).tobytes()
    return (
        _MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 2 + 4 + len(body), channel_id, len(body)) + body
    )


def _end(b: RecordBuilder) -> bytes:
    """The bytes a record builder holds (the library's method is untyped)."""
    return bytes(b.end())  # type: ignore[no-untyped-call]
