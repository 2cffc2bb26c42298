"""One device of an MCAP recording as arrays: for `imud export --csv` (the documented CSV,
docs/recording-csv.md) and for every offline `imud calibrate ... --from FILE.mcap --device NAME`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from imud.channels import INVALID_MASK, Channel
from imud.recording.reader import McapInputError, Recording
from imud.wire import FLAG_CALIBRATED, decode

F64 = npt.NDArray[np.float64]


@dataclass
class DeviceData:
    """A device's samples, in time order, with what the batches said of them."""

    t_ns: npt.NDArray[np.int64]
    accel: F64 | None
    gyro: F64 | None
    temp: F64 | None
    mag: F64 | None
    flags: npt.NDArray[np.uint32]
    calibrated: bool  # the daemon applied a calibration (the corrected stream)
    lost: int  # samples the daemon lost between the recorded batches
    invalid: int  # samples a chip marked invalid (left out)
    gaps_ns: npt.NDArray[np.int64]  # the first stamp after each of those losses


def device_data(rec: Recording, device: str, raw: bool = False) -> DeviceData:
    """All of `device`'s valid samples (`raw`: its uncorrected stream, when recorded).
    McapInputError when it has none."""
    if device not in rec.devices:
        raise McapInputError(
            f"{rec.path} has no device {device!r} (it holds {', '.join(sorted(rec.devices))})"
        )
    batches = [decode(w) for _, _, w in rec.batches([device], raw=raw)]
    batches = [b for b in batches if b.count]
    if not batches:
        raise McapInputError(f"{rec.path}: {device} has no samples")
    # the seq gaps: what the daemon announced (lost_before), and a hole between parts too
    lost = sum(
        max(0, b.first_seq - (a.first_seq + a.count)) for a, b in itertools.pairwise(batches)
    )
    calibrated = any(b.flags & FLAG_CALIBRATED for b in batches)
    flags = np.concatenate([b.sample_flags for b in batches])
    ok = (flags & np.uint32(INVALID_MASK)) == 0

    def column(ch: Channel) -> F64 | None:
        parts = [b.get(ch) for b in batches]
        if all(p is None for p in parts):
            return None
        width = next(p for p in parts if p is not None).shape[1:]
        full = [
            np.full((b.count, *width), np.nan, np.float32) if p is None else p
            for b, p in zip(batches, parts, strict=True)
        ]
        out: F64 = np.concatenate(full).astype(np.float64)[ok]
        return out

    return DeviceData(
        np.concatenate([b.t_ns for b in batches])[ok],
        column(Channel.ACCEL),
        column(Channel.GYRO),
        column(Channel.TEMPERATURE),
        column(Channel.MAG),
        flags[ok],
        calibrated,
        lost,
        int(np.count_nonzero(~ok)),
        np.array([b.t_ns[0] for b in batches[1:] if b.lost_before], np.int64),
    )


def to_csv(rec: Recording, device: str, out: Path) -> DeviceData:
    """`device`'s samples as imud's CSV recording (docs/recording-csv.md)."""
    from imud.calib.csvio import CsvWriter
    from imud.calib.file import now_iso

    d = device_data(rec, device)
    if d.accel is None or d.gyro is None:
        raise McapInputError(f"{rec.path}: {device} has no accelerometer and gyro to write")
    info = rec.info.get(device, {})
    comments = {
        "device": device,
        "chip": str(info.get("chip", "?")),
        "samples": "corrected" if d.calibrated else "raw (uncorrected)",
        "exported": now_iso(),
        "source": str(rec.path),
    }
    mag = d.mag
    if mag is not None and np.isnan(mag).any():  # a magnetometer slower than the stream
        mag = None
    with CsvWriter(
        out, has_temp=d.temp is not None, has_mag=mag is not None, has_flags=True,
        comments=comments,
    ) as w:  # fmt: skip
        w.write(d.t_ns, d.accel, d.gyro, d.temp, mag, d.flags)
    return d
