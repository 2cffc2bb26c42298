"""Fewer messages than samples, by averaging, never by dropping.

A chip faster than the ROS 2 rate gives `k` samples a message, `k` the smallest integer that
brings its rate to `rate_hz` or below. Samples are grouped by their sequence number (`seq // k`),
so groups do not depend on how reads split the stream, and a gap leaves its group with fewer
members (averaged over those it has). A message's stamp is its members' mean instant; its values
their means: for the gyro the mean rate over the interval (what integrating it over the interval
gives, divided by its length), for the accelerometer and magnetometer their box-filtered value,
for an orientation the normalised mean of its quaternions taken on one hemisphere. A value the
chip marked invalid (NaN) is left out of its column's mean; a column with none left in a group
is NaN. `k = 1` passes every sample through.

A device's channels come as one (N, W) float64 matrix, so a batch costs the same few array
operations whatever the chip has; a group still open at a batch's end is kept as running sums,
not samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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
    values: F64  # (n, W)
    members: I64  # samples each message averages

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass
class _Sums:
    """Groups as running sums: stamps relative to each group's first member."""

    group: I64
    base: I64  # the first member's stamp
    rel: I64  # sum of (stamp - base)
    members: I64
    total: F64  # (g, W) sums of valid values
    valid: F64  # (g, W) valid values counted (float: divided by)

    def take(self, sl: slice) -> _Sums:
        return _Sums(
            self.group[sl], self.base[sl], self.rel[sl], self.members[sl], self.total[sl],
            self.valid[sl],
        )  # fmt: skip


class Decimator:
    """`quat`: the columns holding a quaternion (averaged on one hemisphere, normalised)."""

    def __init__(self, k: int, quat: slice | None = None) -> None:
        self.k = k
        self.quat = quat
        self._open: _Sums | None = None  # one group, waiting for more members
        self._ref: F64 | None = None  # the open group's first quaternion

    def feed(self, seq: I64, t_ns: I64, values: F64) -> Decimated:
        """The messages this batch completes (a group is complete when its last seq arrived or
        a later group began). `seq` rises through the batch; `values` is (N, W)."""
        n = seq.shape[0]
        if self.k == 1:
            return Decimated(t_ns, values, np.ones(n, dtype=np.int64))
        if n == 0:
            return _empty(values.shape[1])
        k = self.k
        groups = seq // k
        if groups[0] == groups[-1]:  # the usual case when k exceeds a batch: one group
            starts = np.zeros(1, dtype=np.intp)
            members = np.array([n], dtype=np.int64)
        else:
            starts = np.flatnonzero(np.concatenate(([True], groups[1:] != groups[:-1])))
            members = np.empty(starts.shape[0], dtype=np.int64)
            members[:-1] = starts[1:] - starts[:-1]
            members[-1] = n - starts[-1]
        o = self._open
        merge = o is not None and o.group[0] == groups[0]
        if self.quat is not None:
            values = self._hemisphere(values, starts, members, merge)
        base = t_ns[starts]
        rel = np.add.reduceat(t_ns - np.repeat(base, members), starts)
        nan = np.isnan(values)
        if nan.any():
            total = np.add.reduceat(np.where(nan, 0.0, values), starts, axis=0)
            valid = np.add.reduceat((~nan).astype(np.float64), starts, axis=0)
        else:
            total = np.add.reduceat(values, starts, axis=0)
            valid = np.repeat(members.astype(np.float64)[:, None], values.shape[1], axis=1)
        s = _Sums(groups[starts], base, rel, members, total, valid)
        if o is not None:
            if merge:
                s.rel[0] += o.rel[0] + int(s.members[0]) * (int(s.base[0]) - int(o.base[0]))
                s.base[0] = o.base[0]
                s.members[0] += o.members[0]
                s.total[0] += o.total[0]
                s.valid[0] += o.valid[0]
            else:  # a later group began: the open one is complete
                s = _concat(o, s)
        self._open = None
        if seq[-1] % k != k - 1:  # the last group may get more members
            self._open = s.take(slice(-1, None))
            s = s.take(slice(None, -1))
        return _mean(s, self.quat)

    def _hemisphere(self, v: F64, starts: npt.NDArray[np.intp], members: I64, merge: bool) -> F64:
        """Each quaternion with the sign that puts it nearest its group's first (q and -q are
        one orientation; their plain mean would be nothing)."""
        q = v[:, self.quat]
        ref = q[starts]
        if merge and self._ref is not None:
            ref[0] = self._ref
        self._ref = ref[-1].copy()
        flip = np.sum(q * np.repeat(ref, members, axis=0), axis=1) < 0
        if not flip.any():
            return v
        v = v.copy()
        v[flip, self.quat] *= -1.0
        return v


def _empty(width: int) -> Decimated:
    return Decimated(np.zeros(0, np.int64), np.zeros((0, width)), np.zeros(0, dtype=np.int64))


def _concat(a: _Sums, b: _Sums) -> _Sums:
    return _Sums(*(np.concatenate((x, y)) for x, y in zip(_fields(a), _fields(b), strict=True)))


def _fields(s: _Sums) -> tuple[npt.NDArray[np.generic], ...]:
    return (s.group, s.base, s.rel, s.members, s.total, s.valid)


def _mean(s: _Sums, quat: slice | None) -> Decimated:
    if not s.members.shape[0]:
        return _empty(s.total.shape[1])
    t = s.base + s.rel // s.members
    if s.valid.all():
        mean: F64 = s.total / s.valid
    else:  # a column with no valid member in a group: NaN
        mean = np.divide(s.total, s.valid, out=np.full_like(s.total, np.nan), where=s.valid > 0)
    if quat is not None:
        q = mean[:, quat]
        norm = np.linalg.norm(q, axis=1, keepdims=True)
        mean[:, quat] = np.divide(q, norm, out=np.full_like(q, np.nan), where=norm > 0)
    return Decimated(t, mean, s.members)
