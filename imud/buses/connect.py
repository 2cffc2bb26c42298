"""A configured device on an open bus: one link per die, its simulator, its driver.

The daemon and the tests wire devices through this one function, so a test rig is the daemon's
wiring: simulated chips sit behind the same `smbus2`/`spidev` interfaces the drivers use on
silicon. What differs between chips (how many dies, SPI dummy bytes) comes from the chip's spec.
"""

from __future__ import annotations

from typing import Any

from imud import registry
from imud.buses.models import Bus, SimBus, SpiBus
from imud.buses.registers import RegisterDevice, register_device
from imud.chips.api import DeviceBase, Die, Driver, SimChip, SimDie
from imud.clock import Clock


def _link(d: DeviceBase, bus: Bus, die: Die, sim: SimDie | None, shared: Any) -> RegisterDevice:
    from imud.buses.spi import open_spidev
    from imud.sim.spi import SimSpiDev

    faults = d.sim.nak_rate if d.sim else 0.0
    if isinstance(bus, SimBus):
        assert sim is not None
        if bus.transport == "spi":
            seed = d.sim.seed if d.sim else 0
            spi = SimSpiDev(sim, faults, seed + bus.cs, die.spi_dummy_bytes)
            return register_device(bus, spi, die.spi_dummy_bytes)
        shared.attach(bus.address, sim, faults)
        return register_device(bus, shared)
    if isinstance(bus, SpiBus):
        return register_device(bus, open_spidev(bus), die.spi_dummy_bytes)
    return register_device(bus, shared)


def connect(d: DeviceBase, shared: Any, clock: Clock) -> tuple[Driver, SimChip | None]:
    """Device on an open bus (`shared`: the I2C bus object; unused for SPI) -> (driver,
    simulator or None)."""
    spec = registry.CHIPS[d.chip]
    buses = d.die_buses()
    if len(buses) != len(spec.dies):
        raise TypeError(
            f"{spec.name}: the config names {len(buses)} die bus(es), the spec {len(spec.dies)}"
        )
    sim = spec.make_sim(d, clock) if isinstance(d.bus, SimBus) else None
    sims: list[SimDie | None] = list(sim.dies) if sim is not None else [None] * len(buses)
    if len(sims) != len(buses):
        raise TypeError(f"{spec.name}: its simulator has {len(sims)} dies, the spec {len(buses)}")
    links = [_link(d, b, die, s, shared) for b, die, s in zip(buses, spec.dies, sims, strict=True)]
    return spec.make_driver(d, links, clock), sim
