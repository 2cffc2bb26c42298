"""The chips: one folder each (register map, config model, driver, simulator, spec).

`imud.chips.api` is the interface they implement; `imud.registry` lists them.
"""
