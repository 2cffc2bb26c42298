"""One 6-axis stream from two dies on two clocks (BMI088): accel interpolated onto gyro times.

The BMI088's gyro (up to 2 kHz) and accel (up to 1.6 kHz) are separate dies, each on its own
oscillator, so their samples never coincide and drift past each other. Each die's samples are
stamped on the host clock by its own `SampleClock`; the published stream runs at the gyro's
rate and times, and each gyro sample gets the accel value linearly interpolated at its time from
the two accel samples around it. Interpolation needs the accel sample *after* a gyro sample, so a
gyro sample newer than the newest accel sample waits for the next read (at most one accel
period plus one poll). A gyro sample whose two accel neighbours are not consecutive (accel
samples lost between them) gets no accel value, not a guess: it is published with its accel
invalid (the gyro measured it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]


@dataclass(slots=True)
class Paired:
    first_seq: int
    lost_before: int  # gyro samples missing between the previous pair batch and this one
    t_ns: I64
    gyro: npt.NDArray[np.int32]  # counts
    accel: F64  # counts, interpolated
    valid: npt.NDArray[np.bool_]  # False where no accel value could be interpolated

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])


class DiePairer:
    """Holds gyro samples until accel samples bracket them; stateful, O(batch) per read."""

    def __init__(self, max_wait_ns: int = 100_000_000) -> None:
        self.max_wait_ns = max_wait_ns  # gyro samples older than this never wait longer
        self.next_seq: int | None = None  # seq the next emitted sample should have
        self.reset()

    def reset(self) -> None:
        """Forget everything: pending gyro samples are dropped (counted as lost when the next
        batch's seq jumps past them) and the accel history restarts."""
        self._g_t = np.zeros(0, dtype=np.int64)
        self._g_seq = np.zeros(0, dtype=np.int64)
        self._g = np.zeros((0, 3), dtype=np.int32)
        self.restart()

    def restart(self) -> None:
        """The chip was reinitialised: the accel history restarts (no interpolation across the
        restart). Gyro samples already read stay: the gyro measured them, and those no accel
        sample read before the restart brackets are published with their accel invalid."""
        self._a_t = np.zeros(0, dtype=np.int64)
        self._a_seq = np.zeros(0, dtype=np.int64)
        self._a = np.zeros((0, 3), dtype=np.float64)

    @property
    def pending(self) -> int:
        return int(self._g_t.shape[0])

    def add_gyro(self, seq: I64, t_ns: I64, gyro: npt.NDArray[np.int32]) -> None:
        self._g_t = np.concatenate([self._g_t, t_ns])
        self._g_seq = np.concatenate([self._g_seq, seq])
        self._g = np.concatenate([self._g, gyro])

    def add_accel(self, seq: I64, t_ns: I64, accel: npt.NDArray[np.int32]) -> None:
        self._a_t = np.concatenate([self._a_t, t_ns])
        self._a_seq = np.concatenate([self._a_seq, seq])
        self._a = np.concatenate([self._a, accel.astype(np.float64)])

    def take(self) -> Paired | None:
        """The gyro samples that can be paired now: one run of consecutive seqs."""
        g_t, a_t = self._g_t, self._a_t
        if not g_t.size:
            return None
        covered = a_t[-1] if a_t.size >= 2 else np.iinfo(np.int64).min
        n = int(np.searchsorted(g_t, covered, side="right"))
        stale = int(np.searchsorted(g_t, g_t[-1] - self.max_wait_ns, side="right"))
        if self.next_seq is None and a_t.size < 2:
            self._drop_gyro(stale)  # no stream yet: what is too old to wait is not part of it
            return None
        n = max(n, stale)
        if n and self.next_seq is None and a_t.size >= 2:
            # before the stream starts, gyro samples older than the first accel one are dropped
            skip = int(np.searchsorted(g_t[:n], a_t[0], side="left"))
            self._drop_gyro(skip)
            g_t = self._g_t
            n -= skip
        if n == 0:
            return None
        seq = self._g_seq[:n]
        breaks = np.flatnonzero(np.diff(seq) != 1)
        if breaks.size:  # a gyro gap: this batch ends before it, the next starts after it
            n = int(breaks[0]) + 1
        t = g_t[:n]
        accel, valid = self._interpolate(t)
        first = int(self._g_seq[0])
        lost = 0 if self.next_seq is None else max(0, first - self.next_seq)
        out = Paired(first, lost, t.copy(), self._g[:n].copy(), accel, valid)
        self.next_seq = int(self._g_seq[n - 1]) + 1
        self._drop_gyro(n)
        return out

    def _interpolate(self, t: I64) -> tuple[F64, npt.NDArray[np.bool_]]:
        a_t = self._a_t
        if a_t.size < 2:
            return np.zeros((t.size, 3)), np.zeros(t.size, dtype=bool)
        j = np.searchsorted(a_t, t, side="right") - 1  # newest accel sample at or before t
        jj = np.clip(j, 0, a_t.size - 2)
        t0, t1 = a_t[jj], a_t[jj + 1]
        w = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)[:, None]
        accel = self._a[jj] + w * (self._a[jj + 1] - self._a[jj])
        valid = (j >= 0) & (t <= a_t[-1]) & (self._a_seq[jj + 1] - self._a_seq[jj] == 1)
        # accel samples wholly before the last gyro sample are no longer needed
        keep = int(max(jj[-1], 0))
        self._a_t, self._a_seq, self._a = a_t[keep:], self._a_seq[keep:], self._a[keep:]
        return accel, valid

    def _drop_gyro(self, n: int) -> None:
        self._g_t, self._g_seq, self._g = self._g_t[n:], self._g_seq[n:], self._g[n:]
