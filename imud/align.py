"""One stream from a chip whose dies sample on clocks of their own (the BMI088's accel and gyro):
the pipeline stage that merges the dies onto one die's sample times.

Each die's samples are stamped on the host clock by its own sample clock first. The stream runs
at the primary die's rate and times; every other die's channels are interpolated linearly at
each primary sample's time from that die's two samples around it. Interpolation needs a sample
*after* the primary one, so a primary sample newer than some other die's newest waits for the
next read (at most `max_wait_ns`: then it goes out without that die's values). A primary sample
whose two neighbours on another die are not consecutive (samples lost between them), or either
of them invalid, gets no value for that channel, not a guess: it is published with the channel
invalid (the other channels measured it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.channels import Channel
from imud.chips.api import RawChannel
from imud.compiled import load

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]
_NONE_I64 = np.zeros(0, dtype=np.int64)
_kernels = load("imud._kernels")  # _Follower.at in two calls, when built


@dataclass(slots=True)
class Aligned:
    """A run of consecutive primary samples with every die's channels at their times."""

    first_seq: int
    lost_before: int  # primary samples missing between the previous run and this one
    t_ns: I64
    channels: dict[Channel, RawChannel]

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])


class _Samples:
    """One die's recent samples: times, seqs and each channel's values, in arrival order.

    A channel a read did not carry is padded for the samples before it: as valid zeros for the
    primary (its samples go out whatever they carry), as invalid for a follower (no value to
    interpolate from)."""

    def __init__(self, as_float: bool, padding_invalid: bool) -> None:
        self._as_float = as_float
        self._padding_invalid = padding_invalid
        self.restart()

    def restart(self) -> None:
        self.t = _NONE_I64
        self.seq = _NONE_I64
        self.data: dict[Channel, npt.NDArray[np.generic]] = {}
        self.invalid: dict[Channel, Mask] = {}
        self.meta: dict[Channel, RawChannel] = {}

    def add(self, seq: I64, t: I64, channels: dict[Channel, RawChannel]) -> None:
        n_old = self.t.size
        self.t = np.concatenate([self.t, t])
        self.seq = np.concatenate([self.seq, seq])
        for ch, rc in channels.items():
            self.meta[ch] = rc
            v = rc.data.astype(np.float64) if self._as_float else rc.data
            old = self.data.get(ch)
            if old is None or not old.size:
                old = np.zeros((n_old, *v.shape[1:]), dtype=v.dtype)
            self.data[ch] = np.concatenate([old, v]) if n_old else v
            inv = rc.invalid if rc.invalid is not None else np.zeros(t.size, dtype=bool)
            pad = np.full(n_old, self._padding_invalid, dtype=bool)
            self.invalid[ch] = np.concatenate([self.invalid.get(ch, pad), inv])

    def drop(self, n: int) -> None:
        """Let the oldest `n` samples go."""
        self.t, self.seq = self.t[n:], self.seq[n:]
        for ch in self.data:
            self.data[ch], self.invalid[ch] = self.data[ch][n:], self.invalid[ch][n:]


class _Follower(_Samples):
    """Another die's recent samples, as floats, kept for interpolation."""

    def __init__(self) -> None:
        super().__init__(as_float=True, padding_invalid=True)

    def at(self, t: I64) -> dict[Channel, RawChannel]:
        """Each channel at the times `t` (ascending), with where it has no value; the history
        wholly before `t[-1]` is let go."""
        a_t, n = self.t, t.size
        out: dict[Channel, RawChannel] = {}
        if a_t.size < 2:
            for ch, rc in self.meta.items():
                shape = (n, *self.data[ch].shape[1:])
                out[ch] = RawChannel(np.zeros(shape), rc.scale, rc.full_scale, np.ones(n, bool))
            return out
        if _kernels is not None:
            return self._at_compiled(t)
        j = np.searchsorted(a_t, t, side="right") - 1  # newest sample at or before t
        jj = np.clip(j, 0, a_t.size - 2)
        t0, t1 = a_t[jj], a_t[jj + 1]
        w = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
        base = (j >= 0) & (t <= a_t[-1]) & (self.seq[jj + 1] - self.seq[jj] == 1)
        for ch, rc in self.meta.items():
            v = self.data[ch].astype(np.float64, copy=False)  # floats since add()
            ww = w.reshape(n, *([1] * (v.ndim - 1)))
            values = v[jj] + ww * (v[jj + 1] - v[jj])
            inv = self.invalid[ch]
            valid = base & ~inv[jj] & ~inv[jj + 1]
            out[ch] = RawChannel(values, rc.scale, rc.full_scale, None if valid.all() else ~valid)
        self.drop(int(max(jj[-1], 0)))  # samples wholly before the newest time: no longer needed
        return out

    def _at_compiled(self, t: I64) -> dict[Channel, RawChannel]:
        """`at` (two samples or more) in one kernel call to place the times and one a channel:
        the same values, to the bit (tests/test_compiled.py)."""
        assert _kernels is not None
        n = t.size
        jj = np.empty(n, dtype=np.int64)
        w = np.empty(n, dtype=np.float64)
        base = np.empty(n, dtype=bool)
        last = _kernels.bracket(self.t, self.seq, t, jj, w, base)
        out: dict[Channel, RawChannel] = {}
        for ch, rc in self.meta.items():
            v = np.ascontiguousarray(self.data[ch], dtype=np.float64)  # (floats since add())
            values = np.empty((n, *v.shape[1:]), dtype=np.float64)
            bad = np.empty(n, dtype=bool)
            inv = np.ascontiguousarray(self.invalid[ch])
            any_bad = _kernels.lerp(v, inv, jj, w, base, values, bad)
            out[ch] = RawChannel(values, rc.scale, rc.full_scale, bad if any_bad else None)
        self.drop(max(last, 0))
        return out


class Aligner:
    """Holds primary samples until every other die has a sample after them; stateful, O(batch)
    per read."""

    def __init__(self, primary: int, dies: int, max_wait_ns: int) -> None:
        self.primary = primary
        self.max_wait_ns = max_wait_ns  # primary samples older than this never wait longer
        self.next_seq: int | None = None  # seq the next run should start at
        self._p = _Samples(as_float=False, padding_invalid=False)
        self._others = {d: _Follower() for d in range(dies) if d != primary}

    def restart(self) -> None:
        """The chip was re-initialised: the other dies' histories restart (no interpolation
        across it). Primary samples already read stay: they were measured, and those no later
        sample brackets go out without the other dies' values."""
        for f in self._others.values():
            f.restart()

    @property
    def pending(self) -> int:
        return int(self._p.t.size)

    def add(self, die: int, seq: I64, t_ns: I64, channels: dict[Channel, RawChannel]) -> None:
        if die == self.primary:
            self._p.add(seq, t_ns, channels)
        else:
            self._others[die].add(seq, t_ns, channels)

    def take(self) -> Aligned | None:
        """The primary samples that can go out now: one run of consecutive seqs."""
        p = self._p
        g_t = p.t
        if not g_t.size:
            return None
        others = list(self._others.values())
        ready = all(f.t.size >= 2 for f in others)
        covered = min((int(f.t[-1]) for f in others), default=int(g_t[-1])) if ready else None
        n = 0 if covered is None else int(np.searchsorted(g_t, covered, side="right"))
        stale = int(np.searchsorted(g_t, g_t[-1] - self.max_wait_ns, side="right"))
        if self.next_seq is None and not ready:
            p.drop(stale)  # no stream yet: what is too old to wait is not part of it
            return None
        n = max(n, stale)
        if n and self.next_seq is None:
            # before the stream starts, primary samples older than the others' first are dropped
            first = max(int(f.t[0]) for f in others) if others else int(g_t[0])
            skip = int(np.searchsorted(g_t[:n], first, side="left"))
            p.drop(skip)
            g_t = p.t
            n -= skip
        if n == 0:
            return None
        breaks = np.flatnonzero(np.diff(p.seq[:n]) != 1)
        if breaks.size:  # a gap: this run ends before it, the next starts after it
            n = int(breaks[0]) + 1
        t = g_t[:n].copy()
        channels = {
            ch: RawChannel(
                p.data[ch][:n],
                rc.scale,
                rc.full_scale,
                p.invalid[ch][:n] if p.invalid[ch][:n].any() else None,
            )
            for ch, rc in p.meta.items()
        }
        for f in others:
            channels.update(f.at(t))
        first = int(p.seq[0])
        lost = 0 if self.next_seq is None else max(0, first - self.next_seq)
        self.next_seq = int(p.seq[n - 1]) + 1
        p.drop(n)
        return Aligned(first, lost, t, channels)
