"""A configured device on an open bus: one link per die, its simulator, its driver.

The daemon and the tests wire devices through this one function, so a test rig is the daemon's
wiring: simulated chips sit behind the same `smbus2`/`spidev`/`pyserial` interfaces the drivers
use on silicon (a serial chip behind a real pseudo-terminal). What differs between chips (how many
dies, SPI dummy bytes, an SPI framing of their own) comes from the chip's spec.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from imud import registry
from imud.buses.models import Bus, SerialBus, SimBus, SpiBus
from imud.buses.registers import register_device
from imud.chips.api import ChipSpec, DeviceBase, Die, Driver
from imud.clock import Clock
from imud.sim.api import SimChip, SimDie, SpiFrameDie, StreamDie

if TYPE_CHECKING:
    from imud.chips.api import Link

SimAny = SimDie | SpiFrameDie | StreamDie


def _sim_link(
    d: DeviceBase,
    bus: SimBus,
    spec: ChipSpec[Any],
    die: Die,
    sim: SimAny,
    shared: Any,
    clock: Clock,
) -> Link:
    from imud.buses.serial import open_serial
    from imud.sim.faults import TransferFaults
    from imud.sim.pty import PtyLink
    from imud.sim.spi import SimSpiDev
    from imud.sim.spiframe import SimSpiFrames

    seed = d.sim.seed if d.sim else 0
    # one fault stream per die link (its chip select or address salts the draws)
    salt = bus.cs if bus.transport == "spi" else bus.address
    faults = TransferFaults(d.sim, clock, salt) if d.sim else None
    if bus.transport == "serial":
        if not isinstance(sim, StreamDie):
            raise TypeError(f"{spec.name}: its simulator has no serial side")
        pty = PtyLink(sim, clock)
        try:
            port = open_serial(pty.path, bus.baud)
        except Exception:
            pty.close()
            raise
        pty.release()
        return port
    if bus.transport == "spi" and spec.raw_spi:
        if not isinstance(sim, SpiFrameDie):
            raise TypeError(f"{spec.name}: its simulator does not take SPI frames")
        return SimSpiFrames(sim, 0.0, seed + bus.cs, faults)
    if not isinstance(sim, SimDie):
        raise TypeError(f"{spec.name}: its simulator has no byte registers")
    if bus.transport == "spi":
        spi = SimSpiDev(sim, 0.0, seed + bus.cs, die.spi_dummy_bytes, faults=faults)
        return register_device(bus, spi, die.spi_dummy_bytes)
    shared.attach(bus.address, sim, faults=faults)
    return register_device(bus, shared)


def _link(
    d: DeviceBase,
    bus: Bus,
    spec: ChipSpec[Any],
    die: Die,
    sim: SimAny | None,
    shared: Any,
    clock: Clock,
) -> Link:
    from imud.buses.serial import open_serial
    from imud.buses.spi import open_spidev

    if isinstance(bus, SimBus):
        assert sim is not None
        return _sim_link(d, bus, spec, die, sim, shared, clock)
    if isinstance(bus, SerialBus):
        return open_serial(bus.port, bus.baud)
    if isinstance(bus, SpiBus):
        spi = open_spidev(bus)
        return spi if spec.raw_spi else register_device(bus, spi, die.spi_dummy_bytes)
    return register_device(bus, shared)


def connect(d: DeviceBase, shared: Any, clock: Clock) -> tuple[Driver, SimChip | None]:
    """Device on an open bus (`shared`: the I2C bus object; unused for SPI and serial) ->
    (driver, simulator or None)."""
    spec = registry.CHIPS[d.chip]
    buses = d.die_buses()
    if len(buses) != len(spec.dies):
        raise TypeError(
            f"{spec.name}: the config names {len(buses)} die bus(es), the spec {len(spec.dies)}"
        )
    sim = spec.make_sim(d, clock) if d.bus.simulated else None
    sims: list[SimAny | None] = list(sim.dies) if sim is not None else [None] * len(buses)
    if len(sims) != len(buses):
        raise TypeError(f"{spec.name}: its simulator has {len(sims)} dies, the spec {len(buses)}")
    links = [
        _link(d, b, spec, die, s, shared, clock)
        for b, die, s in zip(buses, spec.dies, sims, strict=True)
    ]
    return spec.make_driver(d, links, clock), sim
