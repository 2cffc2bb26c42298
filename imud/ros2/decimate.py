"""Fewer messages than samples, by averaging, never by dropping.

A chip faster than the ROS 2 rate gives `k` samples a message, `k` the smallest integer that
brings its rate to `rate_hz` or below. Samples are grouped by their sequence number (`seq // k`),
so groups do not depend on how reads split the stream, and a gap leaves its group with fewer
members (averaged over those it has). A message's stamp is its members' mean instant; its values
their means: for the gyro the mean rate over the interval (what integrating it over the interval
gives, divided by its length), for the accelerometer and magnetometer their box-filtered value,
for an orientation the normalised mean of its quaternions taken on one hemisphere. A value the
chip marked invalid (NaN) is left out of its channel's mean; a channel with none left in a group
is NaN. `k = 1` passes every sample through.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


def factor(odr_hz: float, rate_hz: float) -> int:
    """Samples a message: the smallest k with odr_hz / k <= rate_hz."""
    return max(1, math.ceil(odr_hz / rate_hz - 1e-9))


@dataclass
class Decimated:
    t_ns: I64
    channels: dict[str, F64]
    members: npt.NDArray[np.int64]  # samples each message averages

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass
class _Open:
    """The newest group, still waiting for members."""

    group: int
    seq: I64
    t_ns: I64
    channels: dict[str, F64] = field(default_factory=dict)


class Decimator:
    def __init__(self, k: int) -> None:
        self.k = k
        self._open: _Open | None = None

    def feed(self, seq: I64, t_ns: I64, channels: dict[str, F64]) -> Decimated:
        """The messages this batch completes (a group is complete when its last seq arrived or
        a later group began). `channels`: name -> (N,) or (N, w) float arrays."""
        if self.k == 1:
            return Decimated(t_ns, channels, np.ones(t_ns.shape[0], dtype=np.int64))
        o = self._open
        if o is not None:
            seq = np.concatenate((o.seq, seq))
            t_ns = np.concatenate((o.t_ns, t_ns))
            channels = {c: np.concatenate((o.channels[c], a)) for c, a in channels.items()}
        self._open = None
        n = seq.shape[0]
        if n == 0:
            return Decimated(t_ns, channels, np.zeros(0, dtype=np.int64))
        groups = seq // self.k
        edge = np.empty(n, dtype=np.bool_)
        edge[0] = True
        np.not_equal(groups[1:], groups[:-1], out=edge[1:])
        starts = np.flatnonzero(edge)
        ends = np.empty_like(starts)
        ends[:-1], ends[-1] = starts[1:], n
        done = len(starts)
        if seq[-1] % self.k != self.k - 1:  # the last group may get more members
            last = int(starts[-1])
            self._open = _Open(
                int(groups[-1]),
                seq[last:].copy(),
                t_ns[last:].copy(),
                {c: a[last:].copy() for c, a in channels.items()},
            )
            done -= 1
        if done == 0:
            return Decimated(np.zeros(0, np.int64), {}, np.zeros(0, dtype=np.int64))
        starts, ends = starts[:done], ends[:done]
        members = ends - starts
        cut = int(ends[-1])
        base = t_ns[starts]
        rel = t_ns[:cut] - np.repeat(base, members)  # small: no int64 overflow in the sum
        t_out = base + np.add.reduceat(rel, starts) // members
        out = {c: _mean(c, a[:cut], starts, members) for c, a in channels.items()}
        return Decimated(t_out, out, members)


def _mean(name: str, a: F64, starts: I64, members: I64) -> F64:
    if name == "orientation":
        a = _one_hemisphere(a, starts, members)
    nan = np.isnan(a)
    if not nan.any():  # the usual case: a plain mean
        count: npt.NDArray[np.int64] = members if a.ndim == 1 else members[:, None]
        mean: F64 = np.add.reduceat(a, starts, axis=0) / count
    else:
        total = np.add.reduceat(np.where(nan, 0.0, a), starts, axis=0)
        valid = np.add.reduceat((~nan).astype(np.int64), starts, axis=0)
        mean = np.divide(total, valid, out=np.full_like(total, np.nan), where=valid > 0)
    if name == "orientation":
        norm = np.linalg.norm(mean, axis=1, keepdims=True)
        mean = np.divide(mean, norm, out=np.full_like(mean, np.nan), where=norm > 0)
    return mean


def _one_hemisphere(q: F64, starts: I64, members: I64) -> F64:
    """Each quaternion with the sign that puts it nearest its group's first (q and -q are one
    orientation; their plain mean would be nothing)."""
    ref = np.repeat(q[starts], members, axis=0)
    flip = np.sum(q * ref, axis=1) < 0
    out: F64 = np.where(flip[:, None], -q, q)
    return out
