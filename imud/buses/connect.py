"""A configured device on an open bus: its transports (one per die), its simulator, its driver.

The daemon and the tests wire devices through this one function, so a test rig is the daemon's
wiring: simulated chips sit behind the same `smbus2`/`spidev` interfaces the drivers use on
silicon.
"""

from __future__ import annotations

from typing import Any

from imud.buses.models import SimBus, SpiBus
from imud.chips import CHIPS
from imud.chips.base import ChipSim, DeviceBase, Driver
from imud.clock import Clock


def _transport(d: DeviceBase, bus: Any, die: ChipSim | None, shared: Any) -> Any:
    from imud.buses.spi import open_spidev
    from imud.sim.spi import SimSpiDev

    faults = d.sim.nak_rate if d.sim else 0.0
    if isinstance(bus, SimBus):
        assert die is not None
        if bus.transport == "spi":
            seed = d.sim.seed if d.sim else 0
            return SimSpiDev(die, faults, seed + bus.cs, getattr(die, "spi_dummy_bytes", 0))
        shared.attach(bus.address, die, faults)
        return shared
    if isinstance(bus, SpiBus):
        return open_spidev(bus)
    return shared


def connect(d: DeviceBase, shared: Any, clock: Clock) -> tuple[Driver, ChipSim | None]:
    """Device on an open bus (`shared`: the I2C bus object; unused for SPI) -> (driver,
    simulator or None). A chip of several dies gets a tuple of transports, one per die."""
    spec = CHIPS[d.chip]
    buses = d.die_buses()
    sim = spec.make_sim(d, clock) if isinstance(d.bus, SimBus) else None
    dies: list[Any] = getattr(sim, "dies", [sim])
    transports = [_transport(d, b, die, shared) for b, die in zip(buses, dies, strict=True)]
    transport = transports[0] if len(transports) == 1 else tuple(transports)
    return spec.make_driver(d, transport, clock), sim
