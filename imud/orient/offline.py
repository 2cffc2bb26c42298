"""The orientation stage run on a recording's samples: what `imud orient FILE` does. The same stage
the daemon runs, fed the same way (batches of the daemon's size, the lost samples between them
bridged), so a recording gives the orientation the daemon would have published."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.channels import Channel
from imud.orient.stage import OrientationStage

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

BATCH = 32  # samples a step: a 1 kHz FIFO chip's batch in the daemon


@dataclass(frozen=True)
class Oriented:
    t_ns: I64
    orientation: F64  # (N, 4) w, x, y, z; NaN before the filter's start
    covariance: F64  # (N, 6) xx, xy, xz, yy, yz, zz, rad^2
    period_s: float
    lost: int  # samples missing between the recorded ones (bridged or restarted over)


def sample_period(t_ns: I64) -> float:
    """The stream's period: the median step (a lost sample doubles a step, rarely the median)."""
    if t_ns.shape[0] < 2:
        raise ValueError("fewer than two samples: no rate to integrate the gyro at")
    step = float(np.median(np.diff(t_ns)))
    if not step > 0:
        raise ValueError("the samples' stamps do not increase: no rate to integrate at")
    return step / 1e9


def orient(
    stage: OrientationStage,
    t_ns: I64,
    gyro: F64,
    accel: F64 | None,
    mag: F64 | None = None,
    batch: int = BATCH,
) -> Oriented:
    """Run `stage` over a device's samples in time order. A step of over 1.5 periods between two
    samples is a loss of that many periods less one, bridged as the daemon bridges it."""
    n = int(t_ns.shape[0])
    period = sample_period(t_ns)
    steps = np.diff(t_ns) / (period * 1e9)
    gaps = np.flatnonzero(steps > 1.5) + 1  # the first sample after each loss
    counts = (np.rint(steps[gaps - 1]) - 1).astype(int).tolist()
    lost_at = dict(zip(gaps.tolist(), counts, strict=True))
    q = np.empty((n, 4))
    cov = np.empty((n, 6))
    bounds = sorted({0, n, *gaps.tolist(), *range(0, n, batch)})
    for i, j in itertools.pairwise(bounds):
        channels: dict[Channel, F64] = {Channel.GYRO: gyro[i:j]}
        if accel is not None:
            channels[Channel.ACCEL] = accel[i:j]
        if mag is not None:
            channels[Channel.MAG] = mag[i:j]
        out = stage.run(channels, period, lost_at.get(i, 0))
        q[i:j] = out[Channel.ORIENTATION]
        cov[i:j] = out[Channel.ORIENTATION_COVARIANCE]
    return Oriented(t_ns, q, cov, period, int(sum(lost_at.values())))
