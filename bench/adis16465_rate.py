"""The ADIS16465 driver against its simulator in real time: how many samples one Python thread
keeps, at 2 kHz with bursts only and with the delta outputs at lower rates.

For each case (DEC_RATE, deltas on or off) it wires one simulated ADIS16465 exactly as the daemon
does (`imud.wiring`, the simulator behind its own SPI framing), runs the device's
`DeviceRunner` on the host's monotonic clock in a loop shaped like a bus worker's (step, then
wait until the next poll is due), and after the start sequence counts for `--seconds`:
samples published, samples lost (the pipeline's count, from DATA_CNTR), the chip's output
samples meanwhile (the simulator's count: published + lost must equal it), polls that found no
new sample, samples whose deltas a new sample overtook (published as invalid), DIAG_STAT
datapath overruns, and the process CPU time per second. The driver's 16 us chip-select stall
is spun, so CPU includes it; the simulator's own cost is included (it answers every frame).

Deltas at DEC_RATE 0 are refused by the config (14 register reads per sample where the
datasheet allows 12): that case is built past the check, to show what it would do.

The simulator answers a frame at once, where a real bus takes its bits / SCLK (176 us for a burst
at 1 MHz, 8 us for a register frame at 2 MHz). `--bus-time` makes each frame take that long
(spun, so it counts as CPU, where spidev's ioctl would leave the CPU free).

    .venv/bin/python bench/adis16465_rate.py                     # 10 s per case
    .venv/bin/python bench/adis16465_rate.py --seconds 30 --rt   # SCHED_FIFO 20 (root)
    .venv/bin/python bench/adis16465_rate.py --cases 0:off,1:on --speed-hz 1000000
    .venv/bin/python bench/adis16465_rate.py --rt --bus-time
"""

from __future__ import annotations

import argparse
import gc
import os
import shlex
import sys
import threading
import time
from typing import Any

from imud.clock import MonotonicClock
from imud.config import parse_config
from imud.device import DeviceRunner
from imud.status import DeviceState
from imud.wiring import connect


def device(dec_rate: int, deltas: bool, speed_hz: int, seed: int) -> Any:
    """The config of one simulated device; deltas at DEC_RATE 0 past the config's check."""
    d = {
        "name": "adis", "chip": "adis16465", "model": 2, "dec_rate": dec_rate,
        "deltas": deltas and dec_rate > 0,
        "bus": {"kind": "sim", "transport": "spi", "speed_hz": speed_hz},
        "sim": {"seed": seed, "clock_error": 0.02,
                "motion": {"kind": "tumble", "rate_dps": [0.0, 0.0, 100.0]}},
    }  # fmt: skip
    cfg = parse_config({"device": [d]}).device[0]
    return cfg.model_copy(update={"deltas": deltas}) if deltas and dec_rate == 0 else cfg


class TimedFrames:
    """A simulated chip select whose frames take their time on the bus, as on silicon."""

    def __init__(self, spi: Any) -> None:
        self.spi = spi
        self.mode, self.max_speed_hz = spi.mode, spi.max_speed_hz

    def xfer2(
        self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0, bits_per_word: int = 0
    ) -> list[int]:
        end = time.perf_counter_ns() + len(values) * 8_000_000_000 // (speed_hz or 1_000_000)
        rx: list[int] = self.spi.xfer2(values, speed_hz, delay_usecs, bits_per_word)
        while time.perf_counter_ns() < end:
            pass
        return rx

    def close(self) -> None:
        self.spi.close()


def run_case(
    dec_rate: int, deltas: bool, seconds: float, speed_hz: int, bus_time: bool
) -> dict[str, Any]:
    cfg = device(dec_rate, deltas, speed_hz, seed=dec_rate)
    clock = MonotonicClock()
    driver, sim = connect(cfg, None, clock)
    if bus_time:
        driver.spi = TimedFrames(driver.spi)  # type: ignore[attr-defined]
    runner = DeviceRunner(cfg, driver, None, lambda _: None, 0, sim=sim, now_ns=clock.now_ns)
    wake = threading.Event()  # the bus worker waits on an Event too

    def loop(until_ns: int, stop_when_running: bool = False) -> None:
        while clock.now_ns() < until_ns:
            runner.step()
            if stop_when_running and runner.state == DeviceState.RUNNING:
                return
            wait = runner.next_due_ns - clock.now_ns()
            if wait > 0:
                wake.wait(wait / 1e9)

    loop(clock.now_ns() + 5_000_000_000, stop_when_running=True)
    assert runner.state == DeviceState.RUNNING, runner.last_error
    loop(clock.now_ns() + 500_000_000)  # the rate estimate gets its baseline
    runner.emitter.flush()  # what the emitter holds to publish together (emit.MERGE_NS) counts
    st0 = dict(driver.chip_status())
    s0, l0, i0 = runner.samples, runner.lost_samples, runner.invalid_samples
    out0 = sim.outputs_produced  # type: ignore[union-attr]
    c0, t0 = time.process_time(), time.monotonic()
    loop(clock.now_ns() + int(seconds * 1e9))
    cpu, wall = time.process_time() - c0, time.monotonic() - t0
    runner.emitter.flush()
    st = driver.chip_status()
    overruns = st["diag_stat_counts"].get("datapath_overrun", 0)
    overruns -= st0["diag_stat_counts"].get("datapath_overrun", 0)
    return {
        "dec_rate": dec_rate,
        "odr_hz": cfg.odr_hz,
        "deltas": deltas,
        "low_words": st["gyro_accel_bits"] == 32,
        "chip_samples": sim.outputs_produced - out0,  # type: ignore[union-attr]
        "published": runner.samples - s0,
        "lost": runner.lost_samples - l0,
        "invalid": runner.invalid_samples - i0,
        "duplicate_polls": st["duplicate_reads"] - st0["duplicate_reads"],
        "delta_races": st["delta_races"] - st0["delta_races"],
        "overruns": overruns,
        "cpu_pct": 100 * cpu / wall,
        "state": str(runner.state),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--cases", default="0:off,0:on,1:on,3:on", help="dec_rate:on|off, ...")
    p.add_argument("--speed-hz", type=int, default=2_000_000, help="the SPI bus's clock")
    p.add_argument("--rt", action="store_true", help="SCHED_FIFO priority 20, like the daemon")
    p.add_argument("--bus-time", action="store_true", help="frames take bits / SCLK (spun)")
    args = p.parse_args()
    print("command:", shlex.join([sys.executable, *sys.argv]))
    if args.rt:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(20))
    gc.collect()
    gc.freeze()  # as the bus process does
    sys.setswitchinterval(0.0005)
    cols = ("dec_rate", "odr_hz", "deltas", "low_words", "chip_samples", "published", "lost",
            "invalid", "duplicate_polls", "delta_races", "overruns", "cpu_pct")  # fmt: skip
    print(" | ".join(cols))
    for case in args.cases.split(","):
        dec, on = case.split(":")
        r = run_case(int(dec), on == "on", args.seconds, args.speed_hz, args.bus_time)
        print(" | ".join(f"{r[c]:.1f}" if isinstance(r[c], float) else str(r[c]) for c in cols))
        assert r["published"] + r["lost"] - r["chip_samples"] in (-2, -1, 0, 1, 2), r
    return 0


if __name__ == "__main__":
    sys.exit(main())
