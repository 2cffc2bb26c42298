"""The sample-clock estimator against a synthetic chip grid whose every instant is known."""

from __future__ import annotations

import numpy as np
import pytest

from imud.timestamps import SampleClock


class Grid:
    """A chip sampling at period `p` from `origin`; reads at host times with a bus latency."""

    def __init__(self, p: float, seed: int, latency: float = 50_000.0) -> None:
        self.p = p
        self.rng = np.random.default_rng(seed)
        self.origin = 1e9 + self.rng.uniform(0, p)
        self.latency = latency
        self.t = 1e9
        self.k = -1  # newest sample already read
        self.k0: int | None = None  # true index of seq 0

    def newest(self, t: float) -> int:
        return int((t - self.origin) // self.p)

    def read(self, sc: SampleClock, interval: float, reset: bool = False) -> tuple[object, int]:
        self.t += interval + self.rng.uniform(0, self.p)
        restart = None
        resync = False
        if reset:  # FIFO reset now: everything up to here is discarded
            r0 = self.t
            self.k = self.newest(r0)
            restart = (int(r0 - self.latency), int(r0))
            self.t += interval + self.rng.uniform(0, self.p)
            resync = True
        tb = self.t
        kn = self.newest(tb + self.rng.uniform(0, self.latency))  # latched during the read
        ta = tb + self.latency
        n = kn - self.k
        st = sc.update(n, int(tb), int(ta), resync, restart=restart)
        if self.k0 is None:
            self.k0 = kn - n + 1
        self.k = kn
        return st, kn


def _true_times(g: Grid, st: object) -> np.ndarray:
    assert g.k0 is not None
    seq = st.first_seq + np.arange(len(st.t_ns))  # type: ignore[attr-defined]
    return g.origin + (seq + g.k0) * g.p


@pytest.mark.parametrize("error", [-0.02, -0.004, 0.0, 0.013, 0.02])
def test_period_and_stamps_converge(error: float) -> None:
    g = Grid(1e6 / (1 + error), seed=1)
    sc = SampleClock(1e6)
    errs = []
    for i in range(600):
        st, _ = g.read(sc, 21e6)
        if i > 100:
            errs.append(np.abs(st.t_ns - _true_times(g, st)).max())  # type: ignore[attr-defined]
    assert sc.period == pytest.approx(g.p, rel=5e-5)
    assert sc.rate_hz == pytest.approx(1e9 / g.p, rel=5e-5)
    assert max(errs) < 0.15 * g.p + g.latency


def test_stamps_strictly_increase_and_seq_is_contiguous() -> None:
    g = Grid(1e6 * 1.01, seed=2)
    sc = SampleClock(1e6)
    last_t, next_seq = -1, 0
    for _ in range(300):
        st, _ = g.read(sc, 5e6)
        if len(st.t_ns):  # type: ignore[attr-defined]
            assert st.first_seq == next_seq  # type: ignore[attr-defined]
            assert np.all(np.diff(st.t_ns) > 0) and st.t_ns[0] > last_t  # type: ignore[attr-defined]
            last_t = int(st.t_ns[-1])  # type: ignore[attr-defined]
            next_seq += len(st.t_ns)  # type: ignore[attr-defined]


@pytest.mark.parametrize("seed", range(6))
def test_gaps_after_fifo_resets_are_counted_exactly(seed: int) -> None:
    g = Grid(1e6 * 0.987, seed=seed)
    sc = SampleClock(1e6)
    rng = np.random.default_rng(seed + 100)
    lost_reported = 0
    for i in range(500):
        st, kn = g.read(sc, 21e6, reset=i > 60 and rng.random() < 0.05)
        lost_reported += st.lost_before  # type: ignore[attr-defined]
        assert g.k0 is not None
        # the newest sample's seq is its true index minus the first one's: nothing miscounted
        assert st.first_seq + len(st.t_ns) - 1 == kn - g.k0  # type: ignore[attr-defined]
    assert lost_reported > 0


def test_rebase_counts_the_outage_of_a_reinitialised_chip() -> None:
    g = Grid(1e6, seed=3, latency=0.0)
    sc = SampleClock(1e6)
    for _ in range(100):
        st, _ = g.read(sc, 20e6)
    last = st.first_seq + len(st.t_ns) - 1  # type: ignore[attr-defined]
    sc.rebase()
    # the chip restarts 300 ms later on a new grid
    g2 = Grid(1e6, seed=4, latency=0.0)
    g2.t = g.t + 300e6
    g2.origin = g2.t + 0.2e6
    g2.k = g2.newest(g2.t)
    st2, _ = g2.read(sc, 20e6)
    # 300 ms without samples at 1 kHz is a 300-sample hole in the stream
    assert st2.lost_before == pytest.approx(300, abs=2)  # type: ignore[attr-defined]
    assert st2.first_seq > last  # type: ignore[attr-defined]
    assert st2.t_ns[0] > st.t_ns[-1]  # type: ignore[attr-defined]


def test_a_counter_read_one_sample_at_a_time_counts_a_gap_exactly() -> None:
    """A chip without a FIFO (a data counter, one sample per read): the counter's ticks per sample
    are learnt across reads, so a gap is counted from the counter, not from host time. Here the
    host brackets after the gap are a period off (the read was late by 1.4 periods), yet the
    counter says 5 samples are missing, and 5 it is."""
    p = 500_000  # 2 kHz
    clock = SampleClock(p)
    tick = 65_530  # about to wrap at 2**16
    t = 1_000_000_000
    for _ in range(50):
        t += p
        clock.update(1, t - 100_000, t + 50_000, ticks=np.array([tick]), ticks_modulo=65_536)
        tick = (tick + 1) % 65_536
    tick = (tick + 5) % 65_536  # samples 50..54 never read
    t += 6 * p + int(1.4 * p)
    st = clock.update(
        1, t - 100_000, t + 50_000, resync=True, ticks=np.array([tick]), ticks_modulo=65_536
    )
    assert st.lost_before == 5
