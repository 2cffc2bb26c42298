"""Pipeline stages: pure functions on NumPy batches, bytes-to-SI in order.

raw counts --to_si--> SI units --calibrate--> corrected --(timestamps from SampleClock)--> Batch
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.calibration import Calibration
from imud.chips.base import RawBatch
from imud.timestamps import SampleClock
from imud.wire import FLAG_CALIBRATED, FLAG_RESYNC

F64 = npt.NDArray[np.float64]


def to_si(raw: RawBatch) -> tuple[F64, F64]:
    """Counts to m/s^2 and rad/s for the configured ranges."""
    return (
        raw.accel.astype(np.float64) * raw.accel_scale,
        raw.gyro.astype(np.float64) * raw.gyro_scale,
    )


def calibrate(cal: Calibration | None, accel: F64, gyro: F64) -> tuple[F64, F64]:
    return (accel, gyro) if cal is None else cal.apply(accel, gyro)


@dataclass(slots=True)
class SampleBatch:
    first_seq: int
    lost_before: int
    flags: int
    t_ns: npt.NDArray[np.int64]
    accel: F64
    gyro: F64
    temperature_c: F64
    valid: npt.NDArray[np.bool_] | None = None

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])


class Pipeline:
    """Holds the only state a batch needs (the sample-clock fit); everything else is pure."""

    def __init__(self, clock: SampleClock, cal: Calibration | None, epoch_offset_ns: int) -> None:
        self.clock = clock
        self.cal = cal
        self.epoch_offset_ns = epoch_offset_ns

    def process(self, raw: RawBatch) -> SampleBatch:
        st = raw.stamps
        if st is None:  # the usual case: one die, stamped from its reads
            st = self.clock.update(
                raw.n,
                raw.t_before_ns,
                raw.t_after_ns,
                raw.resync,
                restart=raw.restart_ns,
                full=raw.fifo_full,
                ticks=raw.chip_ticks,
                ticks_modulo=raw.ticks_modulo,
            )
        accel, gyro = calibrate(self.cal, *to_si(raw))
        flags = (FLAG_CALIBRATED if self.cal is not None else 0) | (
            FLAG_RESYNC if st.lost_before else 0
        )
        return SampleBatch(
            st.first_seq,
            st.lost_before,
            flags,
            st.t_ns + self.epoch_offset_ns,
            accel,
            gyro,
            raw.temperature_c,
            raw.valid,
        )
