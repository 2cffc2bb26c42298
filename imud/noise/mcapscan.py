"""One device's samples out of an indexed MCAP recording, many batches at a time, for `imud noise`
on a day of data (4.3 M batches at 1 kHz).

The recording reader (imud/recording/reader.py) hands out one batch at a time through the `mcap`
library: 9.5 µs of Python a message before the batch is even decoded (14 µs with it), 41 s of
a day's 4.3 M batches. Measured for a quarter of an hour at 1 kHz (docs/performance.md §17):
10.8 s when each batch was fed to the Allan sums, 2.3 s with batches joined first, 1.4 s here.

Here the chunk index in the file's summary says where each chunk and its message index are; a
chunk is read with its message indexes in one read, decompressed (zstd, or none), and the
device's messages are located from its message index. Their batches' headers and values are
then read for all the messages of many chunks at once with NumPy (byte gathers at computed
offsets), and handed on as one run of samples with each batch's sequence number, count, lost
samples and first and last stamp, so the caller can cut the run at gaps.

Anything unexpected (a chunk compressed otherwise, a record that is not a message where the
index points, a batch whose length does not match its header) raises `NotScannable`: the caller
then reads the file with the recording reader, which names what is wrong."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.channels import ORDER, Channel
from imud.wire import HEADER, MAGIC, VERSION

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]

MIN_BYTES = 8 << 20  # decompressed records handed on at once (chunks joined up to it): about
# 200,000 samples of gyro, accel and temperature, a step of the Allan sums that costs little
_CHUNK_HEAD = struct.Struct("<BQQQQI")  # opcode, length, start, end, uncompressed size, crc
_MESSAGE_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, length, channel, sequence, log and publish time
_CDR_HEAD = 8  # imud_msgs/msg/Batch in CDR: the encapsulation header, the byte count
_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_MESSAGE = 0x06, 0x07, 0x05


class NotScannable(ValueError):
    """This file is not for the fast scan: read it with the recording reader."""


@dataclass
class Run:
    """A device's batches in order (those of no samples left out): per batch its first sequence
    number, count, lost_before and first and last stamp; the samples (gyro then accel, float64)
    and the temperature (None when the batches carry none)."""

    first_seq: I64
    count: I64
    lost: I64
    t_first: I64
    t_last: I64
    y: F64
    temp: F64 | None


def scan(paths: list[Path], topic: str) -> Iterator[Run]:
    """The batches on `topic` of the files `paths` (a split recording's parts, in order)."""
    import zstandard

    dctx = zstandard.ZstdDecompressor()
    pending: list[tuple[bytes, I64]] = []
    held = 0
    for path in paths:
        with open(path, "rb") as f:
            cid, chunks = _summary(f, topic, path)
            for ci in chunks:
                off = ci.message_index_offsets.get(cid)
                if off is None:
                    continue  # no message of this device in the chunk
                f.seek(ci.chunk_start_offset)
                raw = f.read(ci.chunk_length + ci.message_index_length)
                records = _records(raw, ci, dctx)
                where = _offsets(raw, off - ci.chunk_start_offset, cid)
                if where.size:
                    pending.append((records, where))
                    held += len(records)
                if held >= MIN_BYTES:
                    yield _decode(pending, cid)
                    pending, held = [], 0
        if pending:  # each file's own channel id: its runs are decoded apart
            yield _decode(pending, cid)
            pending, held = [], 0


def _summary(f: Any, topic: str, path: Path) -> tuple[int, list[Any]]:
    from mcap.reader import make_reader

    try:
        summary = make_reader(f).get_summary()
    except Exception as e:  # the library's own errors, struct's
        raise NotScannable(f"{path}: summary unreadable: {e}") from None
    if summary is None or not summary.chunk_indexes:
        raise NotScannable(f"{path}: no chunk index")
    ids = [c.id for c in summary.channels.values() if c.topic == topic]
    if len(ids) != 1:
        raise NotScannable(f"{path}: {len(ids)} channels on {topic}")
    return ids[0], sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def _records(raw: bytes, ci: Any, dctx: Any) -> bytes:
    """The chunk's records, decompressed."""
    if len(raw) < _CHUNK_HEAD.size + 4 or raw[0] != _OP_CHUNK:
        raise NotScannable("no chunk where the index says")
    pos = _CHUNK_HEAD.size
    (n,) = struct.unpack_from("<I", raw, pos)
    compression = raw[pos + 4 : pos + 4 + n].decode("ascii", "replace")
    pos += 4 + n
    (size,) = struct.unpack_from("<Q", raw, pos)
    body = raw[pos + 8 : pos + 8 + size]
    if compression == "":
        return body
    if compression != "zstd":
        raise NotScannable(f"a chunk compressed with {compression}")
    try:
        out: bytes = dctx.decompress(body, max_output_size=ci.uncompressed_size)
    except Exception as e:  # zstandard.ZstdError
        raise NotScannable(f"a damaged chunk: {e}") from None
    if len(out) != ci.uncompressed_size:
        raise NotScannable("a chunk of another size than its index says")
    return out


def _offsets(raw: bytes, at: int, cid: int) -> I64:
    """The chunk's messages of channel `cid`, their offsets in the records in order."""
    if at < 0 or at + 15 > len(raw) or raw[at] != _OP_MESSAGE_INDEX:
        raise NotScannable("no message index where the index says")
    channel, size = struct.unpack_from("<HI", raw, at + 9)
    if channel != cid or at + 15 + size > len(raw) or size % 16:
        raise NotScannable("a damaged message index")
    pairs = np.frombuffer(raw, "<u8", size // 8, at + 15).reshape(-1, 2)
    return np.sort(pairs[:, 1].astype(np.int64))  # file order: the order they were written


def _take(u8: U8, pos: I64, dtype: str) -> npt.NDArray[Any]:
    """The little-endian value of `dtype` at each byte position (unaligned)."""
    size = np.dtype(dtype).itemsize
    out: npt.NDArray[Any] = u8[pos[:, None] + np.arange(size)].view(dtype).reshape(-1)
    return out


def _gather(u8: U8, views: list[npt.NDArray[np.float32]], start: I64, n: I64) -> F32:
    """float32 values: n[i] of them from byte start[i] of each message, end to end. The records
    are read as four float32 arrays shifted by 0..3 bytes, each value from the one its start's
    alignment picks (no byte-wise copy)."""
    total = int(n.sum())
    if not total:
        return np.empty(0, np.float32)
    rep = np.repeat(start, n)
    k = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
    out = np.empty(total, np.float32)
    shift = rep & 3
    idx = (rep >> 2) + k
    for s in range(4):
        sel = shift == s
        if sel.any():
            out[sel] = views[s][idx[sel]]
    return out


F32 = npt.NDArray[np.float32]


def _decode(pending: list[tuple[bytes, I64]], cid: int) -> Run:
    lengths = [len(r) for r, _ in pending]
    base = np.cumsum([0, *lengths[:-1]])
    buf = b"".join(r for r, _ in pending)
    o = np.concatenate([w + b for (_, w), b in zip(pending, base, strict=True)])
    # where each message's chunk ends: no message may reach past it
    stop = np.repeat(base + np.array(lengths), [w.size for _, w in pending])
    u8 = np.frombuffer(buf, np.uint8)
    if (o < 0).any() or (o + _MESSAGE_HEAD + _CDR_HEAD + HEADER.size > stop).any():
        raise NotScannable("a message index pointing outside its chunk")
    if (u8[o] != _OP_MESSAGE).any() or (_take(u8, o + 9, "<u2") != cid).any():
        raise NotScannable("a record that is not the device's message where its index says")
    length = _take(u8, o + 1, "<u8")
    if (length > np.uint64(1 << 40)).any() or (o + 9 + length.astype(np.int64) > stop).any():
        raise NotScannable("a message longer than its chunk")
    length = length.astype(np.int64)
    cdr = o + _MESSAGE_HEAD
    w = cdr + _CDR_HEAD  # the wire bytes (docs/wire-format.md)
    wire_len = _take(u8, cdr + 4, "<u4").astype(np.int64)
    if (
        (u8[cdr] != 0).any()
        or (u8[cdr + 1] != 1).any()
        or (wire_len + 22 + _CDR_HEAD != length).any()
    ):
        raise NotScannable("a message that is not a little-endian CDR imud_msgs/msg/Batch")
    if (_take(u8, w, "<u4") != int.from_bytes(MAGIC, "little")).any() or (
        u8[w + 4] != VERSION
    ).any():
        raise NotScannable("a batch of another wire version")
    name_len = _take(u8, w + 6, "<u2").astype(np.int64)
    first_seq = _take(u8, w + 8, "<u8").astype(np.int64)
    n = _take(u8, w + 16, "<u4").astype(np.int64)
    lost = _take(u8, w + 24, "<u4").astype(np.int64)
    mask = _take(u8, w + 28, "<u4").astype(np.int64)
    t_off = w + HEADER.size + name_len + (-name_len) % 8
    cur = t_off + 12 * n  # past the stamps and the per-sample flags
    at: dict[Channel, I64] = {}
    for c, bit, width in ORDER:
        has = (mask & int(bit)) != 0
        at[c] = cur
        cur = cur + np.where(has, 4 * width * n, 0)
    if (cur != w + wire_len).any():
        raise NotScannable("a batch whose length does not match its header")
    keep = n > 0
    if not keep.all():
        o, n, first_seq, lost, mask, t_off = (a[keep] for a in (o, n, first_seq, lost, mask, t_off))
        at = {c: v[keep] for c, v in at.items()}
    for c in (Channel.GYRO, Channel.ACCEL):
        if ((mask & int(c)) == 0).any():
            raise NotScannable("a batch without the gyro or the accelerometer")
    views = [np.frombuffer(buf, np.float32, (len(buf) - s) // 4, s) for s in range(4)]
    g = _gather(u8, views, at[Channel.GYRO], 3 * n).reshape(-1, 3)
    a = _gather(u8, views, at[Channel.ACCEL], 3 * n).reshape(-1, 3)
    has_t = (mask & int(Channel.TEMPERATURE)) != 0
    temp = None
    if has_t.all():
        temp = _gather(u8, views, at[Channel.TEMPERATURE], n).astype(np.float64)
    y = np.empty((g.shape[0], 6))
    with np.errstate(invalid="ignore"):  # a chip's invalid sample is NaN: a gap, cut later
        y[:, 0:3], y[:, 3:6] = g, a
    t_first = _take(u8, t_off, "<i8").astype(np.int64)
    t_last = _take(u8, t_off + 8 * (n - 1), "<i8").astype(np.int64)
    return Run(first_seq, n, lost, t_first, t_last, y, temp)
