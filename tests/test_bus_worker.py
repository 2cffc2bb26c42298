"""A bus worker at virtual time: a bus that will not open, a device that will not connect, a
driver that raises anything at all. Each is retried with backoff, counted and shown in that
device's status, logged once with its traceback, and never stops the bus's other devices."""

from __future__ import annotations

import errno
import itertools
import logging
from collections.abc import Iterator
from typing import Any

import pytest

from imud.busworker import BusWorker, connector
from imud.chips.api import DeviceBase, Driver, RawBatch
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.device import DeviceRunner
from imud.sim.api import SimChip
from imud.sim.i2c import SimI2CBus
from imud.wiring import connect


def devices(*names: str) -> list[DeviceBase]:
    """MPU6050s at 500 Hz on one simulated I2C bus, 0x68, 0x69..."""
    return parse_config(
        {
            "device": [
                {
                    "name": n,
                    "chip": "mpu6050",
                    "odr_hz": 500,
                    "bus": {"kind": "sim", "address": 0x68 + i},
                    "sim": {"errors": {"ideal": True}},
                }
                for i, n in enumerate(names)
            ]
        }
    ).device


def worker(
    cfgs: list[DeviceBase], clock: VirtualClock, opener: Any = None, connectors: Any = None
) -> tuple[BusWorker, dict[str, list[bytes]]]:
    out: dict[str, list[bytes]] = {d.name: [] for d in cfgs}
    runners = [
        DeviceRunner(d, None, None, out[d.name].append, 0, now_ns=clock.now_ns) for d in cfgs
    ]
    w = BusWorker(
        "sim:sim0",
        runners,
        connectors or [connector(d, clock) for d in cfgs],
        opener or SimI2CBus,
        clock,
    )
    return w, out


def run(w: BusWorker, clock: VirtualClock, seconds: float) -> None:
    """What `BusWorker.run` does, at virtual time."""
    end = clock.now_ns() + int(seconds * 1e9)
    while clock.now_ns() < end:
        wait = w.run_once()
        if wait:
            clock.advance(wait)


def test_bus_reopened_with_backoff_then_devices_start() -> None:
    (cfg,) = devices("a")
    clock = VirtualClock()
    attempts: list[int] = []

    def opener() -> Any:
        attempts.append(clock.now_ns())
        if len(attempts) < 4:
            raise OSError(errno.ENOENT, "No such file or directory: '/dev/i2c-1'")
        return SimI2CBus()

    w, out = worker([cfg], clock, opener)
    r = w.runners[0]
    run(w, clock, 0.2)
    assert r.state == "error" and "/dev/i2c-1" in (r.last_error or "")
    run(w, clock, 10.0)
    gaps = [b - a for a, b in itertools.pairwise(attempts)]
    assert len(attempts) == 4
    assert gaps == [500_000_000, 1_000_000_000, 2_000_000_000]  # 0.5 s doubling
    assert r.state == "running" and r.samples > 0 and out["a"]
    assert not w.reopen.pending  # the backoff is over once the bus opened


def test_poll_lateness_is_measured_after_a_bus_recovered() -> None:
    """The reopen deadline of a failed bus must not linger and hide how late polls come."""
    (cfg,) = devices("a")
    clock = VirtualClock()
    tries = iter([OSError(errno.ENOENT, "no bus"), None])

    def opener() -> Any:
        e = next(tries)
        if e:
            raise e
        return SimI2CBus()

    w, _ = worker([cfg], clock, opener)
    run(w, clock, 2.0)
    r = w.runners[0]
    assert r.state == "running"
    while r.next_due_ns <= clock.now_ns():
        w.run_once()
    clock.advance(r.next_due_ns - clock.now_ns() + 3_000_000)  # the worker wakes 3 ms late
    assert w.run_once() == 0
    assert r.status().poll_late_max_ms == pytest.approx(3.0)


def test_a_bus_that_opens_with_an_unexpected_error_is_retried() -> None:
    (cfg,) = devices("a")
    clock = VirtualClock()
    calls = 0

    def opener() -> Any:
        nonlocal calls
        calls += 1
        if calls < 3:
            raise RuntimeError("adapter firmware says no")
        return SimI2CBus()

    w, out = worker([cfg], clock, opener)
    run(w, clock, 0.1)
    st = w.runners[0].status().to_json()
    assert st["state"] == "error" and "RuntimeError: adapter firmware says no" in st["last_error"]
    run(w, clock, 5.0)
    assert w.runners[0].status().unexpected_errors == 2
    assert w.runners[0].state == "running" and out["a"]


class Flaky:
    """Wraps a real driver; raises `exc` from start/read on the calls listed."""

    def __init__(
        self,
        inner: Driver,
        exc: Exception,
        start_fails: int = 0,
        reads: frozenset[int] = frozenset(),
    ) -> None:
        self.inner, self.exc = inner, exc
        self.start_fails, self.reads = start_fails, reads
        self.read_calls = 0
        self.nominal_period_ns = inner.nominal_period_ns
        self.poll_interval_ns = inner.poll_interval_ns
        self.fifo_capacity = inner.fifo_capacity
        self.group_delay_ns = inner.group_delay_ns
        self.counters = inner.counters

    @property
    def next_poll_ns(self) -> int | None:
        return self.inner.next_poll_ns

    def start(self) -> Iterator[int]:
        if self.start_fails:
            self.start_fails -= 1
            raise self.exc
        return self.inner.start()

    def read(self) -> RawBatch:
        self.read_calls += 1
        if self.read_calls in self.reads:
            raise self.exc
        return self.inner.read()

    def stop(self) -> None:
        self.inner.stop()

    def chip_status(self) -> dict[str, Any]:
        return self.inner.chip_status()


def flaky_connector(d: DeviceBase, clock: VirtualClock, **kw: Any) -> Any:
    def make(shared: Any) -> tuple[Driver, SimChip | None]:
        driver, sim = connect(d, shared, clock)
        return Flaky(driver, **kw), sim

    return make


def test_a_driver_raising_value_error_in_start_is_retried_and_logged_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    a, b = devices("a", "b")
    clock = VirtualClock()
    exc = ValueError("chip answered 0x5a, a value no table has")
    conns = [flaky_connector(a, clock, exc=exc, start_fails=3), connector(b, clock)]
    w, _ = worker([a, b], clock, connectors=conns)
    with caplog.at_level(logging.ERROR, logger="imud.device"):
        run(w, clock, 6.0)
    st = w.runners[0].status().to_json()
    assert st["unexpected_errors"] == 3
    assert st["state"] == "running"  # the fourth start worked
    assert "ValueError: chip answered 0x5a" in (st["last_error"] or "")
    traced = [r for r in caplog.records if r.exc_info and "0x5a" in r.getMessage()]
    assert len(traced) == 1  # once, with its traceback, not on every retry
    assert w.runners[1].samples > 2500  # the bus-mate never stopped: 6 s at 500 Hz


def test_a_driver_raising_in_read_is_counted_and_the_stream_goes_on() -> None:
    a, b = devices("a", "b")
    clock = VirtualClock()
    conns = [
        flaky_connector(a, clock, exc=ValueError("garbled"), reads=frozenset({5, 9, 10})),
        connector(b, clock),
    ]
    w, out = worker([a, b], clock, connectors=conns)
    run(w, clock, 3.0)
    st = w.runners[0].status().to_json()
    assert st["unexpected_errors"] == 3 and st["state"] == "running"
    assert st["restarts"] == 0  # three failures, never more than ten in a row
    # the FIFO kept the samples of the failed reads: nothing is lost, the stream is seamless
    from imud.wire import decode

    seqs = [decode(p) for p in out["a"]]
    assert all(y.first_seq == x.first_seq + x.count for x, y in itertools.pairwise(seqs))
    assert st["lost_samples"] == 0


def test_eleven_failed_reads_in_a_row_reinitialise_the_chip() -> None:
    (a,) = devices("a")
    clock = VirtualClock()
    conns = [flaky_connector(a, clock, exc=KeyError("x"), reads=frozenset(range(5, 16)))]
    w, _ = worker([a], clock, connectors=conns)
    run(w, clock, 4.0)
    st = w.runners[0].status().to_json()
    assert st["unexpected_errors"] == 11
    assert st["restarts"] == 1 and st["state"] == "running"


def test_a_connect_raising_a_type_error_is_retried_while_the_bus_mate_streams() -> None:
    a, b = devices("a", "b")
    clock = VirtualClock()
    calls = 0

    def bad(shared: Any) -> Any:
        nonlocal calls
        calls += 1
        if calls <= 2:
            raise TypeError("a driver bug")
        return connect(a, shared, clock)

    w, _ = worker([a, b], clock, connectors=[bad, connector(b, clock)])
    run(w, clock, 0.3)
    assert w.runners[0].state == "error" and "TypeError: a driver bug" in (
        w.runners[0].last_error or ""
    )
    run(w, clock, 4.0)
    assert calls == 3 and w.runners[0].state == "running"
    assert w.runners[0].status().unexpected_errors == 2
    assert w.runners[1].samples > 2000
