"""A recording: what every calibration procedure reads, live or from a CSV file.

One type for both so a procedure cannot tell (and cannot behave differently) whether its samples
came from the daemon's raw stream or from a file another tool wrote.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Recording:
    """Samples in SI units, REP-103 body axes, uncorrected (as the chip measured them).

    t_ns: (N,) strictly increasing; accel (N, 3) m/s^2; gyro (N, 3) rad/s; temp (N,) degC or
    None; mag (N, 3) tesla or None; saturated: (N,) True where a sensor read full scale, or None
    when the source did not say."""

    t_ns: I64
    accel: F64
    gyro: F64
    temp: F64 | None = None
    mag: F64 | None = None
    saturated: npt.NDArray[np.bool_] | None = None
    source: str = ""  # a file name or "live <device>", for messages

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def rate_hz(self) -> float:
        """Mean sample rate from the stamps (median period: robust to gaps)."""
        if self.n < 2:
            return 0.0
        return 1e9 / float(np.median(np.diff(self.t_ns)))

    def slice(self, start: int, end: int) -> Recording:
        def cut(a: F64 | None) -> F64 | None:
            return None if a is None else a[start:end]

        return Recording(
            self.t_ns[start:end],
            self.accel[start:end],
            self.gyro[start:end],
            cut(self.temp),
            cut(self.mag),
            None if self.saturated is None else self.saturated[start:end],
            self.source,
        )
