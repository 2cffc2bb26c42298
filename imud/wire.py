"""The batch wire format (version 2), shared by the daemon and `imud.client`.

Little-endian. A 32-byte header, the UTF-8 device name padded with zeros to a multiple of 8
bytes, then N int64 timestamps, N uint32 per-sample flags, and one float32 array per channel the
header's channel mask names, in bit order (`imud.channels`). See docs/wire-format.md.
"""

from __future__ import annotations

import functools
import struct
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from imud.channels import CHANNELS, ORDER, Channel, SampleFlag
from imud.compiled import load

MAGIC = b"IMUD"
VERSION = 2
KIND_SAMPLES = 0
KIND_TRUTH = 1
FLAG_CALIBRATED = 1 << 0
FLAG_RESYNC = 1 << 1
FLAG_GAP_UNCERTAIN = 1 << 2  # lost_before is the sample clock's best estimate (docs/wire-format.md)
HEADER = struct.Struct("<4sBBHQIIII")  # magic, version, kind, name_len, first_seq, count,
#                                        flags, lost_before, channel mask
assert HEADER.size == 32
_STAMP = struct.Struct("<q")
_KNOWN = sum(CHANNELS)
_BIT_WIDTH = {c: (bit, width) for c, bit, width in ORDER}

F32 = npt.NDArray[np.float32]
_kernels = load("imud._kernels")
# the kernel writes in the machine's byte order, which must be the wire's (little-endian)
_pack = _kernels.pack if _kernels is not None and sys.byteorder == "little" else None


@dataclass(frozen=True, slots=True)
class Batch:
    device: str
    kind: int
    first_seq: int
    flags: int
    lost_before: int
    t_ns: npt.NDArray[np.int64]
    sample_flags: npt.NDArray[np.uint32]
    channels: dict[Channel, F32] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def seq(self) -> npt.NDArray[np.int64]:
        return self.first_seq + np.arange(self.count, dtype=np.int64)

    @property
    def mask(self) -> Channel:
        return Channel(sum(self.channels))

    def get(self, channel: Channel) -> F32 | None:
        return self.channels.get(channel)

    def invalid(self, channel: Channel) -> npt.NDArray[np.bool_]:
        """Per sample: the chip marked this channel's value invalid (it reads NaN)."""
        out: npt.NDArray[np.bool_] = (self.sample_flags & np.uint32(channel)) != 0
        return out

    def flagged(self, flag: SampleFlag) -> npt.NDArray[np.bool_]:
        out: npt.NDArray[np.bool_] = (self.sample_flags & np.uint32(flag)) != 0
        return out

    # the common channels by name; None when the batch does not carry them
    @property
    def accel(self) -> F32 | None:
        return self.channels.get(Channel.ACCEL)

    @property
    def gyro(self) -> F32 | None:
        return self.channels.get(Channel.GYRO)

    @property
    def temperature_c(self) -> F32 | None:
        return self.channels.get(Channel.TEMPERATURE)


class WireError(ValueError):
    pass


def encode(
    device: str,
    first_seq: int,
    t_ns: npt.ArrayLike,
    channels: Mapping[Channel, npt.ArrayLike],
    sample_flags: npt.ArrayLike | None = None,
    *,
    kind: int = KIND_SAMPLES,
    flags: int = 0,
    lost_before: int = 0,
) -> bytes:
    name = device.encode()
    t = np.ascontiguousarray(t_ns, dtype="<i8")
    n = t.shape[0]
    pad = (-len(name)) % 8
    mask = 0
    arrays: list[npt.NDArray[np.generic]] = []
    for ch in sorted(channels):  # bit order
        bit, width = _BIT_WIDTH[ch]
        values = channels[ch]
        arr = values if isinstance(values, np.ndarray) else np.asarray(values, dtype="<f4")
        if arr.size != n * width:
            raise WireError(f"{CHANNELS[ch].key}: {arr.shape} values for {n} samples")
        arrays.append(arr)
        mask |= bit
    sf = None
    if sample_flags is not None:
        sf = np.ascontiguousarray(sample_flags, dtype="<u4").reshape(n)
    head = HEADER.pack(MAGIC, VERSION, kind, len(name), first_seq, n, flags, lost_before, mask)
    prefix = b"".join((head, name, b"\0" * pad))
    if _pack is not None:
        try:  # one copy into the batch's bytes, float32 on the way
            packed: bytes = _pack(prefix, t, sf, tuple(arrays))
            return packed
        except (TypeError, ValueError, BufferError):
            pass  # channels of another dtype, or not contiguous: NumPy packs them
    parts = [np.ascontiguousarray(a, dtype="<f4").tobytes() for a in arrays]
    flags_bytes = bytes(4 * n) if sf is None else sf.tobytes()
    return b"".join((prefix, t.tobytes(), flags_bytes, *parts))


def peek(buf: bytes | memoryview) -> tuple[int, int, int, int, int]:
    """(first seq, sample count, first stamp, last stamp, lost before) of an encoded batch, read
    from its header and stamps alone: how the daemon follows each stream without decoding it.
    Stamps are 0 in a batch of no samples."""
    _, _, _, name_len, first_seq, n, _, lost, _ = HEADER.unpack_from(buf)
    if not n:
        return first_seq, 0, 0, 0, lost
    off = HEADER.size + name_len + (-name_len) % 8
    (first,) = _STAMP.unpack_from(buf, off)
    (last,) = _STAMP.unpack_from(buf, off + 8 * (n - 1))
    return first_seq, n, first, last, lost


def _header(buf: bytes) -> tuple[int, int, int, int, int, int, int, int]:
    """(kind, name_len, first_seq, count, flags, lost_before, mask, stamps' offset), the
    batch's size checked against them. Raises `WireError` naming what is wrong, and where."""
    if len(buf) < HEADER.size:
        raise WireError(f"batch too short: {len(buf)} bytes, the header alone is {HEADER.size}")
    magic, version, kind, name_len, first_seq, n, flags, lost, mask = HEADER.unpack_from(buf)
    if magic != MAGIC:
        raise WireError(f"bad magic {magic!r} at byte 0, expected {MAGIC!r}")
    if version != VERSION:
        raise WireError(
            f"wire version {version} at byte 4; this decoder reads version {VERSION} "
            "(docs/wire-format.md): upgrade the side that is older"
        )
    if mask & ~_KNOWN:
        raise WireError(
            f"channel mask 0x{mask:x} at byte 28 names channels this decoder does not know "
            f"(known: 0x{_KNOWN:x}): upgrade imud on the receiving side"
        )
    off = HEADER.size + name_len + (-name_len) % 8
    need = off + n * (8 + 4 + 4 * _widths(mask))
    if len(buf) != need:
        raise WireError(
            f"batch of {n} samples with mask 0x{mask:x} needs {need} bytes, got {len(buf)}"
        )
    return kind, name_len, first_seq, n, flags, lost, mask, off


@functools.lru_cache(maxsize=64)
def _widths(mask: int) -> int:
    return sum(w for _, bit, w in ORDER if mask & bit)


def decode(buf: bytes) -> Batch:
    """Zero-copy views into `buf`. Raises `WireError` naming what is wrong, and where."""
    kind, name_len, first_seq, n, flags, lost, mask, off = _header(buf)
    chans = [(c, w) for c, bit, w in ORDER if mask & bit]
    try:
        device = bytes(buf[HEADER.size : HEADER.size + name_len]).decode()
    except UnicodeDecodeError as e:
        raise WireError(f"device name at byte {HEADER.size + e.start} is not UTF-8") from None
    t = np.frombuffer(buf, "<i8", n, off)
    off += 8 * n
    sf = np.frombuffer(buf, "<u4", n, off)
    off += 4 * n
    out: dict[Channel, F32] = {}
    for c, width in chans:
        a = np.frombuffer(buf, "<f4", width * n, off)
        out[c] = a.reshape(n, width) if width > 1 else a
        off += 4 * width * n
    return Batch(device, kind, first_seq, flags, lost, t, sf, out)


Picks = tuple[tuple[Channel, int], ...]  # (channel, component) per column


def gather(buf: bytes, picks: Picks) -> tuple[int, int, npt.NDArray[np.int64], F32]:
    """(kind, first_seq, stamps, values) of a batch, its channels gathered into one (N, C)
    float32 matrix in a single copy: column j holds component `picks[j][1]` of channel
    `picks[j][0]`, NaN where the batch does not carry that channel. For a consumer that wants
    a sample's values side by side. Raises `WireError` as `decode` does."""
    kind, _, first_seq, n, _, _, mask, off = _header(buf)
    t = np.frombuffer(buf, "<i8", n, off)
    width = _widths(mask)
    values = np.frombuffer(buf, "<f4", width * n, off + 12 * n)
    index, complete = _gather_index(mask, n, picks)
    if not complete:  # the missing channels' columns index one NaN past the end
        values = np.concatenate((values, np.full(1, np.nan, np.float32)))
    return kind, first_seq, t, values[index]


@functools.lru_cache(maxsize=256)
def _gather_index(mask: int, n: int, picks: Picks) -> tuple[npt.NDArray[np.intp], bool]:
    start: dict[Channel, tuple[int, int]] = {}
    at = 0
    for c, bit, w in ORDER:
        if mask & bit:
            start[c] = (at, w)
            at += w * n
    rows = np.arange(n)
    index = np.empty((n, len(picks)), dtype=np.intp)
    for j, (c, comp) in enumerate(picks):
        if c in start:
            first, w = start[c]
            index[:, j] = first + rows * w + comp
        else:
            index[:, j] = at
    index.setflags(write=False)
    return index, all(c in start for c, _ in picks)
