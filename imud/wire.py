"""The batch wire format (version 1), shared by the daemon and `imud.client`.

Little-endian. A 32-byte header, the UTF-8 device name padded with zeros to a multiple of 8 bytes,
then four arrays of N samples each: int64 t_ns, float32 accel[N][3] (m/s^2), float32 gyro[N][3]
(rad/s), float32 temperature (deg C). See docs/wire-format.md.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

MAGIC = b"IMUD"
VERSION = 1
KIND_SAMPLES = 0
KIND_TRUTH = 1
FLAG_CALIBRATED = 1 << 0
FLAG_RESYNC = 1 << 1
HEADER = struct.Struct("<4sBBHQIIII")  # magic, version, kind, name_len, first_seq, count,
#                                        flags, lost_before, reserved
assert HEADER.size == 32


@dataclass(frozen=True, slots=True)
class Batch:
    device: str
    kind: int
    first_seq: int
    flags: int
    lost_before: int
    t_ns: npt.NDArray[np.int64]
    accel: npt.NDArray[np.float32]  # (N, 3)
    gyro: npt.NDArray[np.float32]  # (N, 3)
    temperature_c: npt.NDArray[np.float32]

    @property
    def count(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def seq(self) -> npt.NDArray[np.int64]:
        return self.first_seq + np.arange(self.count, dtype=np.int64)


class WireError(ValueError):
    pass


def encode(
    device: str,
    first_seq: int,
    t_ns: npt.ArrayLike,
    accel: npt.ArrayLike,
    gyro: npt.ArrayLike,
    temperature_c: npt.ArrayLike,
    *,
    kind: int = KIND_SAMPLES,
    flags: int = 0,
    lost_before: int = 0,
) -> bytes:
    name = device.encode()
    t = np.ascontiguousarray(t_ns, dtype="<i8")
    n = t.shape[0]
    pad = (-len(name)) % 8
    head = HEADER.pack(MAGIC, VERSION, kind, len(name), first_seq, n, flags, lost_before, 0)
    return b"".join(
        (
            head,
            name,
            b"\0" * pad,
            t.tobytes(),
            np.ascontiguousarray(accel, dtype="<f4").reshape(n, 3).tobytes(),
            np.ascontiguousarray(gyro, dtype="<f4").reshape(n, 3).tobytes(),
            np.ascontiguousarray(temperature_c, dtype="<f4").reshape(n).tobytes(),
        )
    )


def decode(buf: bytes) -> Batch:
    """Zero-copy views into `buf`. Raises `WireError` naming what is wrong."""
    if len(buf) < HEADER.size:
        raise WireError(f"batch too short: {len(buf)} bytes, the header alone is {HEADER.size}")
    magic, version, kind, name_len, first_seq, n, flags, lost, _ = HEADER.unpack_from(buf)
    if magic != MAGIC:
        raise WireError(f"bad magic {magic!r} at byte 0, expected {MAGIC!r}")
    if version != VERSION:
        raise WireError(f"wire version {version} at byte 4; this decoder reads {VERSION}")
    off = HEADER.size + name_len + (-name_len) % 8
    need = off + n * (8 + 12 + 12 + 4)
    if len(buf) != need:
        raise WireError(f"batch of {n} samples needs {need} bytes, got {len(buf)}")
    try:
        device = bytes(buf[HEADER.size : HEADER.size + name_len]).decode()
    except UnicodeDecodeError as e:
        raise WireError(f"device name at byte {HEADER.size + e.start} is not UTF-8") from None
    t = np.frombuffer(buf, "<i8", n, off)
    off += 8 * n
    acc = np.frombuffer(buf, "<f4", 3 * n, off).reshape(n, 3)
    off += 12 * n
    gyr = np.frombuffer(buf, "<f4", 3 * n, off).reshape(n, 3)
    off += 12 * n
    temp = np.frombuffer(buf, "<f4", n, off)
    return Batch(device, kind, first_seq, flags, lost, t, acc, gyr, temp)
