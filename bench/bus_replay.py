"""imud's own CPU a sample with no simulator in the process: a bus's traffic captured from its
simulators, then replayed to the same driver, pipeline and emitter with no physics behind it.

Why: `bench/bus_stages.py` subtracts the simulators' CPU, but not what their work does to
imud's: the simulators run in the bus worker's own thread between its reads, and what they touch
(100 ms of physics a block, their register models) leaves imud's next read with cold caches. On
silicon nothing runs there. So this runs the bus twice, each paced in real time as a bus
process runs it (`build_worker`, the worker's loop, batches sent on a socket another thread
drains):

1. **capture**: with the simulators, as the daemon runs them; every transfer on the device's
   link (an SPI frame, an I2C read or write) is recorded with what came back;
2. **replay**: the same config and worker, its links answered from the recording in order (a
   transfer matching the next recorded one of the same request gets its answer; one the capture
   never saw, the last answer to that request). The simulators are built but never called.

imud's own CPU is the worker thread's CPU less the tape's own (counted as the simulators'
are, `imud.sim.cpu`); the tape's is printed so the split can be checked to add up. Ground truth
is off in both runs (it is the simulators' output, published by the runner). Serial chips
(BNO055, STIM300) are not taped: their simulators run in a pty pump thread, not in the worker's.

    .venv/bin/python bench/bus_replay.py --config configs/sim.toml --bus sim:spi0
    PYTHONPATH=/tmp/before .venv/bin/python bench/bus_replay.py ...   # another tree

Scheduler-dependent: a measurement, never a test (docs/performance.md).
"""

from __future__ import annotations

import argparse
import ctypes
import sys
import threading
import time
from collections.abc import Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bus_stages import paced_worker

import imud.sim.cpu as simcpu
import imud.sim.spiframe
import imud.wiring
from imud.buses.models import SimBus
from imud.config import load_config

WINDOW = 64  # how far ahead of its place a replayed transfer's match is looked for
_REGISTER_DEVICE = imud.wiring.register_device
_FRAMES = imud.sim.spiframe.SimSpiFrames


@dataclass
class Tape:
    """One link's transfers in order: (request, answer)."""

    calls: list[tuple[Hashable, Any]] = field(default_factory=list)
    pos: int = 0
    last: dict[Hashable, Any] = field(default_factory=dict)
    played: int = 0
    unmatched: int = 0  # requests answered with their last answer, not in order

    def play(self, key: Hashable) -> Any:
        for i in range(self.pos, min(self.pos + WINDOW, len(self.calls))):
            if self.calls[i][0] == key:
                self.pos = i + 1
                self.played += 1
                self.last[key] = self.calls[i][1]
                return self.calls[i][1]
        self.unmatched += 1
        if key not in self.last:  # a request whose answer comes only later in the capture
            self.last[key] = next(a for k, a in self.calls if k == key)
        return self.last[key]


class TapedSpi:
    """An SPI link (register frames or a chip's own): records, or answers from, its tape."""

    def __init__(self, inner: Any, tape: Tape, replay: bool) -> None:
        self.inner, self.tape, self.replay = inner, tape, replay
        self.mode = getattr(inner, "mode", 0)
        self.max_speed_hz = getattr(inner, "max_speed_hz", 0)

    def xfer2(
        self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0, bits_per_word: int = 0
    ) -> list[int]:
        key = tuple(values)
        if self.replay:
            return list(simcpu.counted(self.tape.play)(key))
        rx = self.inner.xfer2(values, speed_hz, delay_usecs, bits_per_word)
        self.tape.calls.append((key, list(rx)))
        return rx

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class TapedI2C:
    """One device's view of a shared I2C bus: its calls recorded, or answered from its tape."""

    def __init__(self, inner: Any, tape: Tape, replay: bool) -> None:
        self.inner, self.tape, self.replay = inner, tape, replay

    def _call(self, key: Hashable, fn: Any) -> Any:
        if self.replay:
            return simcpu.counted(self.tape.play)(key)
        out = fn()
        self.tape.calls.append((key, out))
        return out

    def read_byte_data(self, addr: int, register: int, force: bool | None = None) -> int:
        return int(
            self._call(("rb", addr, register), lambda: self.inner.read_byte_data(addr, register))
        )

    def write_byte_data(
        self, addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        self._call(
            ("wb", addr, register, value),
            lambda: self.inner.write_byte_data(addr, register, value),
        )

    def read_i2c_block_data(
        self, addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        return list(
            self._call(
                ("rblk", addr, register, length),
                lambda: self.inner.read_i2c_block_data(addr, register, length),
            )
        )

    def i2c_rdwr(self, *msgs: Any) -> None:
        key = tuple((int(m.addr), int(m.flags), int(m.len), b"" if m.flags & 1 else bytes(m))
                    for m in msgs)  # fmt: skip

        def run() -> list[bytes]:
            self.inner.i2c_rdwr(*msgs)
            return [bytes(m) for m in msgs if m.flags & 1]

        reads = self._call(("rdwr", key), run)
        if self.replay:
            for m, data in zip((m for m in msgs if m.flags & 1), reads, strict=True):
                ctypes.memmove(m.buf, data, len(data))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def install(tapes: dict[str, Tape], replay: bool) -> None:
    """Tape every register link and SPI frame link the wiring makes from here on."""
    register_device, frames, made = _REGISTER_DEVICE, _FRAMES, [0]

    def taped_register_device(bus: Any, transport: Any, dummy: int = 0) -> Any:
        if isinstance(bus, SimBus) and bus.transport == "spi":
            tape = tapes.setdefault(f"{bus.bus} cs{bus.cs}", Tape())
            return register_device(bus, TapedSpi(transport, tape, replay), dummy)
        if isinstance(bus, SimBus) and bus.transport == "i2c":
            tape = tapes.setdefault(f"{bus.bus} 0x{bus.address:02x}", Tape())
            return register_device(bus, TapedI2C(transport, tape, replay))
        return register_device(bus, transport, dummy)

    def taped_frames(sim: Any, *args: Any, **kwargs: Any) -> Any:
        inner = frames(sim, *args, **kwargs)
        made[0] += 1
        tape = tapes.setdefault(f"SPI frames {made[0]}", Tape())
        return TapedSpi(inner, tape, replay)

    imud.wiring.register_device = taped_register_device  # type: ignore[assignment]
    imud.sim.spiframe.SimSpiFrames = taped_frames  # type: ignore[misc,assignment]


def run(config: Path, bus: str, seconds: float, tapes: dict[str, Tape], replay: bool) -> str:
    cfg = load_config(config)
    devices = []
    for d in cfg.device:
        if d.bus.key == bus:
            if d.sim is not None:
                d = d.model_copy(update={"sim": d.sim.model_copy(update={"truth": False})})
            devices.append(d)
    if not devices:
        raise SystemExit(f"no device on bus {bus!r}")
    install(tapes, replay)
    w, stop = paced_worker(bus, devices, cfg.daemon.realtime_priority)
    threading.Timer(seconds, stop.set).start()
    t0, s0 = time.thread_time_ns(), simcpu.total_ns()
    w.run()
    cpu, sim = time.thread_time_ns() - t0, simcpu.total_ns() - s0
    n = max(1, sum(r.samples for r in w.runners))
    lost = sum(r.lost_samples for r in w.runners)
    what = "the tape" if replay else "simulators"
    return (
        f"{'replay ' if replay else 'capture'}: {n} samples, {lost} lost; worker thread "
        f"{cpu / 1e6:.0f} ms = {what} {sim / 1e6:.0f} + imud's own {(cpu - sim) / 1e6:.0f} ms: "
        f"{(cpu - sim) / n / 1e3:.2f} us a sample"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", type=Path, required=True)
    p.add_argument("--bus", required=True, help="the bus key, as `imud status` names it")
    p.add_argument("--seconds", type=float, default=15.0)
    args = p.parse_args()
    tapes: dict[str, Tape] = {}
    print(" ".join(sys.argv))
    print(run(args.config, args.bus, args.seconds, tapes, replay=False))
    for tape in tapes.values():
        tape.last = {}
    print(run(args.config, args.bus, args.seconds, tapes, replay=True))
    for name, t in tapes.items():
        print(f"  {name}: {len(t.calls)} transfers taped, {t.played} replayed in order, "
              f"{t.unmatched} answered out of order")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
