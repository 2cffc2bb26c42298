"""`imud plot`: a recording at a glance, one picture a device: accelerometer, gyro and magnetometer
axes over time, the sample rate a second, gaps marked where samples were lost, the temperature.
From an MCAP recording (its native batches: gaps where a batch said it followed lost samples) or
a CSV recording (gaps where the time steps by more than 1.5 periods). Needs the `plot` extra
(matplotlib); imported only when asked for.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only
import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass
class Series:
    """A device's samples for the plot: stamps, each sensor (None when absent), gap instants."""

    name: str
    t_ns: npt.NDArray[np.int64]
    accel: F64 | None
    gyro: F64 | None
    mag: F64 | None
    temp: F64 | None
    gaps_ns: npt.NDArray[np.int64]  # where samples were lost (the stamp after each gap)
    lost: int


def draw(s: Series, path: Path) -> None:
    t = (s.t_ns - s.t_ns[0]).astype(np.float64) * 1e-9
    rows: list[tuple[str, F64 | None, str]] = [
        ("accel [m/s²]", s.accel, "xyz"),
        ("gyro [rad/s]", s.gyro, "xyz"),
        ("mag [µT]", None if s.mag is None else s.mag * 1e6, "xyz"),
    ]
    rows = [r for r in rows if r[1] is not None and np.isfinite(r[1]).any()]
    extra = 1 + (s.temp is not None and bool(np.isfinite(s.temp).any()))
    fig, axes = plt.subplots(
        len(rows) + extra, 1, sharex=True, figsize=(12, 2.2 * (len(rows) + extra))
    )
    axes = np.atleast_1d(axes)
    step = max(1, t.size // 20000)  # enough points for the eye, not millions
    gaps = (s.gaps_ns - s.t_ns[0]).astype(np.float64) * 1e-9
    for ax, (label, data, names) in zip(axes, rows, strict=False):
        assert data is not None
        for k, axis in enumerate(names):
            ax.plot(t[::step], data[::step, k], lw=0.7, label=axis)
        ax.set_ylabel(label)
        # beside the panel, never over a trace (gravity sits at the top of the accel panel)
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize="small", frameon=False)
    ax = axes[len(rows)]
    seconds = np.floor(t).astype(np.int64)
    counts = np.bincount(seconds)
    full = counts[:-1] if counts.size > 1 else counts  # the last second is partial
    ax.step(np.arange(full.size + 1), np.r_[full, full[-1:]], where="post", lw=1.0)
    ax.set_ylim(0, 1.15 * max(1, int(full.max())))  # from zero: a dip reads as what it is
    ax.set_ylabel("samples/s")
    if s.temp is not None and extra == 2:
        axes[-1].plot(t[::step], s.temp[::step], lw=0.8, color="tab:purple")  # red marks gaps
        axes[-1].set_ylabel("temperature [°C]")
    for a in axes:
        for g in gaps:
            a.axvline(g, color="red", lw=0.8, alpha=0.6)
    axes[-1].set_xlabel("time [s] from the first sample")
    rate = t.size / t[-1] if t[-1] > 0 else 0.0
    lost = f"{s.lost:,} lost in {gaps.size} gap(s), marked in red" if gaps.size else "none lost"
    fig.suptitle(f"{s.name}: {t.size:,} samples over {t[-1]:.1f} s ({rate:.1f} Hz), {lost}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def gaps_from_time(t_ns: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], int]:
    """Where a CSV recording's time steps by more than 1.5 periods, and the samples missing."""
    if t_ns.size < 3:
        return np.zeros(0, np.int64), 0
    dt = np.diff(t_ns)
    period = float(np.median(dt))
    at = np.flatnonzero(dt > 1.5 * period)
    lost = int(np.sum(np.round(dt[at] / period) - 1)) if period > 0 else 0
    return t_ns[at + 1], lost
