"""STIM300 normal-mode datagrams: their layout, the CRC, finding them in a byte stream, and
decoding a batch of them at once.

A serial stream has no framing of its own: a datagram is found by its identifier byte and proven
by its CRC (a random match is a 2^-32 event). After damage (a corrupted, dropped or inserted
byte) the framer looks for the next identifier whose CRC holds, so it resynchronises within one
datagram of the damage and never publishes a datagram whose CRC fails.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import anycrc
import numpy as np
import numpy.typing as npt

from imud.chips.stim300.registers import (
    AXIS_BYTES,
    CONTENT,
    COUNTER_BYTES,
    CRC_BYTES,
    CRC_INIT,
    CRC_POLY,
    CRC_WORD_BYTES,
    ID_BYTES,
    LATENCY_BYTES,
    STATUS_BYTES,
    TEMP_BYTES,
    TERMINATION,
    DatagramId,
)

U8 = npt.NDArray[np.uint8]
I32 = npt.NDArray[np.int32]
_CRC = anycrc.CRC(32, CRC_POLY, CRC_INIT, False, False, 0)  # CRC-32/MPEG-2


def crc32(message: bytes) -> int:
    """The STIM300's CRC of a datagram's identifier and data: CRC-32/MPEG-2 (polynomial
    0x04C11DB7, seed 0xFFFFFFFF, MSB first, no final XOR) over the bytes zero-padded to a whole
    number of 32-bit words (the padding is never sent)."""
    pad = -len(message) % CRC_WORD_BYTES
    return int(_CRC.calc(message + bytes(pad)))


@dataclass(frozen=True, slots=True)
class Layout:
    """Byte offsets of one datagram type's fields (reduced datagrams drop whole clusters)."""

    ident: DatagramId
    terminated: bool  # CR LF after the CRC
    gyro: int
    gyro_status: int
    acc: int | None
    acc_status: int | None
    incl: int | None
    incl_status: int | None
    temps: tuple[int, ...]  # first byte of each temperature cluster (gyro, acc, incl order)
    counter: int
    latency: int
    crc: int  # = bytes the CRC covers
    size: int  # bytes on the wire


@cache
def layout(ident: DatagramId, terminated: bool = False) -> Layout:
    """Offsets of `ident`'s fields: ID, gyro cluster, [acc], [incl], [temperature cluster per
    sensor cluster present], counter, latency, CRC, [CR LF]."""
    acc, incl, temp = CONTENT[ident]
    pos = ID_BYTES
    cluster = 3 * AXIS_BYTES + STATUS_BYTES
    gyro, pos = pos, pos + cluster
    acc_at = incl_at = None
    if acc:
        acc_at, pos = pos, pos + cluster
    if incl:
        incl_at, pos = pos, pos + cluster
    temps: list[int] = []
    if temp:
        for _ in range(1 + acc + incl):
            temps.append(pos)
            pos += 3 * TEMP_BYTES + STATUS_BYTES
    counter, pos = pos, pos + COUNTER_BYTES
    latency, pos = pos, pos + LATENCY_BYTES
    crc_at, pos = pos, pos + CRC_BYTES
    return Layout(
        ident,
        terminated,
        gyro,
        gyro + 3 * AXIS_BYTES,
        acc_at,
        None if acc_at is None else acc_at + 3 * AXIS_BYTES,
        incl_at,
        None if incl_at is None else incl_at + 3 * AXIS_BYTES,
        tuple(temps),
        counter,
        latency,
        crc_at,
        pos + (len(TERMINATION) if terminated else 0),
    )


def valid(lay: Layout, frame: bytes | bytearray | memoryview) -> bool:
    """Whether `frame` (exactly `lay.size` bytes) is a datagram of this type whose CRC holds."""
    if frame[0] != lay.ident:
        return False
    if lay.terminated and bytes(frame[lay.crc + CRC_BYTES :]) != TERMINATION:
        return False
    sent = int.from_bytes(frame[lay.crc : lay.crc + CRC_BYTES], "big")
    return crc32(bytes(frame[: lay.crc])) == sent


def find_any(buf: bytes, terminated: bool = False) -> DatagramId | None:
    """The normal-mode datagram type a stream carries, if any valid datagram is in `buf`: used to
    tell a user whose config names another type which one the unit really sends."""
    for ident in DatagramId:
        lay = layout(ident, terminated)
        start = buf.find(bytes([ident]))
        while 0 <= start <= len(buf) - lay.size:
            if valid(lay, buf[start : start + lay.size]):
                return ident
            start = buf.find(bytes([ident]), start + 1)
    return None


@dataclass(slots=True)
class FramerStats:
    datagrams: int = 0
    crc_errors: int = 0  # datagrams that began where one was due but failed their CRC
    resyncs: int = 0  # times the framer lost the boundary and searched for it
    skipped_bytes: int = 0  # bytes that belonged to no valid datagram


@dataclass
class Framer:
    """Finds datagrams of one type in a byte stream, however the reads split it."""

    lay: Layout
    stats: FramerStats = field(default_factory=FramerStats)
    _buf: bytearray = field(default_factory=bytearray)
    _synced: bool = False  # the buffer starts where the last valid datagram ended

    def feed(self, data: bytes) -> U8:
        """Add received bytes; return every whole valid datagram found, (k, size) uint8."""
        self._buf += data
        size, buf, pos = self.lay.size, self._buf, 0
        starts: list[int] = []
        ident = self.lay.ident
        while len(buf) - pos >= size:
            if valid(self.lay, memoryview(buf)[pos : pos + size]):
                starts.append(pos)
                pos += size
                self._synced = True
                continue
            if self._synced:  # damage where a datagram was due
                self.stats.resyncs += 1
                if buf[pos] == ident:
                    self.stats.crc_errors += 1
                self._synced = False
            nxt = buf.find(bytes([ident]), pos + 1)
            if nxt < 0:
                nxt = len(buf)
            self.stats.skipped_bytes += nxt - pos
            pos = nxt
        if starts:
            frames = np.frombuffer(bytes(buf[:pos]), dtype=np.uint8)
            out: U8 = frames[np.asarray(starts)[:, None] + np.arange(size)]
        else:
            out = np.zeros((0, size), dtype=np.uint8)
        del buf[:pos]
        self.stats.datagrams += len(starts)
        return out

    @property
    def pending(self) -> int:
        """Bytes held for the next read (a datagram not yet complete)."""
        return len(self._buf)

    @property
    def damaged_tail(self) -> bool:
        """Whether a damaged datagram may have come after the last valid one: damage seen since
        it, held bytes that cannot begin a datagram, or nearly a whole one (a byte dropped)."""
        buf, lay = self._buf, self.lay
        return not self._synced or (
            len(buf) > 0 and (buf[0] != lay.ident or len(buf) >= lay.size - 2)
        )


def int24(rows: U8, at: int, axes: int = 3) -> I32:
    """`axes` 24-bit big-endian two's complement values from byte `at` of every row."""
    b = rows[:, at : at + AXIS_BYTES * axes].reshape(-1, axes, AXIS_BYTES).astype(np.int32)
    v = (b[..., 0] << 16) | (b[..., 1] << 8) | b[..., 2]
    out: I32 = np.where(v >= 1 << 23, v - (1 << 24), v).astype(np.int32)
    return out


def int16(rows: U8, at: int, n: int = 3) -> I32:
    b = rows[:, at : at + 2 * n].reshape(-1, n, 2).astype(np.int32)
    v = (b[..., 0] << 8) | b[..., 1]
    out: I32 = np.where(v >= 1 << 15, v - (1 << 16), v).astype(np.int32)
    return out


def uint16(rows: U8, at: int) -> I32:
    out: I32 = (rows[:, at].astype(np.int32) << 8) | rows[:, at + 1]
    return out
