"""The chip registry: every chip reaches imud through the `imud.chips` entry-point group.

imud's own chips are entry points of its own distribution (pyproject.toml); a chip installed as a
plugin is one of another distribution's, found the same way by the daemon, by every bus process
(a fresh interpreter that re-reads the entry points) and by the config loader. `register` adds a
chip at run time too (a tool or a test in one process); the config loader builds its model from
whatever is registered when it runs.
"""

from __future__ import annotations

import logging
from importlib.metadata import EntryPoint, entry_points
from typing import Any, get_args

from imud.channels import Channel
from imud.chips.api import ChipSpec, DeviceBase

log = logging.getLogger("imud.registry")

GROUP = "imud.chips"
CHIPS: dict[str, ChipSpec[Any]] = {}
# entry points that would not load: their name -> why (the config loader says so for a device
# that names one, instead of "unknown chip")
BROKEN: dict[str, str] = {}
generation = 0  # bumped by every registration: config models built before are stale


def _check(spec: ChipSpec[Any]) -> None:
    fields = spec.config_model.model_fields
    if "odr_hz" not in fields:
        raise TypeError(f"{spec.name}: its config model must declare odr_hz, the published rate")
    chip = fields.get("chip")
    if chip is None or get_args(chip.annotation) != (spec.name,):
        raise TypeError(f"{spec.name}: its config model must declare chip: Literal[{spec.name!r}]")


def device_channels(cfg: DeviceBase) -> Channel:
    """What a device publishes: its chip's channels, and the orientation's when imud's filter
    runs on it."""
    channels = Channel(CHIPS[cfg.chip].channels)
    if cfg.orientation.enabled:
        channels |= Channel.ORIENTATION | Channel.ORIENTATION_COVARIANCE
    return channels


def register(spec: ChipSpec[Any]) -> None:
    """Add a chip. Its config model must narrow `chip` to its name and declare `odr_hz`."""
    global generation
    _check(spec)
    CHIPS[spec.name] = spec
    generation += 1


def unregister(name: str) -> None:
    global generation
    del CHIPS[name]
    generation += 1


def _load_one(ep: EntryPoint) -> None:
    where = f"entry point {ep.name!r} = {ep.value!r} of {ep.dist.name if ep.dist else '?'}"
    try:
        spec = ep.load()
    except Exception as e:  # a broken plugin must not take the other chips with it
        BROKEN[ep.name] = f"{where} failed to load: {type(e).__name__}: {e}"
        log.error("%s", BROKEN[ep.name])
        return
    if not isinstance(spec, ChipSpec):
        BROKEN[ep.name] = f"{where} is a {type(spec).__name__}, not an imud.chips.api.ChipSpec"
    elif spec.name != ep.name:
        BROKEN[ep.name] = f"{where} names the chip {spec.name!r}: the two must be equal"
    elif spec.name in CHIPS:
        BROKEN[ep.name] = f"{where}: a chip {spec.name!r} is already registered"
    else:
        try:
            register(spec)
        except TypeError as e:
            BROKEN[ep.name] = f"{where}: {e}"
    if ep.name in BROKEN:
        log.error("%s", BROKEN[ep.name])


def load_entry_points() -> None:
    """Register every chip of the `imud.chips` group (done once, when this module loads)."""
    found = sorted(entry_points(group=GROUP), key=lambda ep: ep.name)
    if not found:
        log.error(
            "no chips: no distribution declares the %r entry points; install imud "
            "(`pip install -e .` in a checkout) rather than running it from its source tree",
            GROUP,
        )
    for ep in found:
        _load_one(ep)


load_entry_points()
