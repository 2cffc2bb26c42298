"""Config reload: what changed between two configs, and noticing that the file changed.

`plan_reload` is pure: it compares the running config with a newly loaded one and says, bus by
bus, what the daemon must do. A device is *unchanged* when its whole table (bus, chip settings,
calibration path, simulator) is equal: it keeps streaming through the reload, its chip never
touched, so its stream has no sequence gap. A changed device is restarted with its new settings
on its bus's worker (the bus's other devices go on), an added one started, a removed one put to
sleep. A bus that loses all its devices is stopped; a new bus gets a worker. `[zenoh]` changes
reopen the session; `[daemon]` settings (worker processes, real-time priority) shape the workers
themselves and take effect at the next restart, which status says.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from imud.chips.api import DeviceBase
from imud.config import ImudConfig


def by_bus(cfg: ImudConfig) -> dict[str, list[DeviceBase]]:
    """The config's devices grouped by the bus they are on (its worker's key), in config order."""
    out: dict[str, list[DeviceBase]] = {}
    for d in cfg.device:
        out.setdefault(d.bus.key, []).append(d)
    return out


class Action(StrEnum):
    KEEP = "keep"  # unchanged: it goes on streaming, its chip untouched
    RESTART = "restart"  # changed: restarted with its new settings, its seq continuing
    START = "start"  # added


@dataclass(frozen=True)
class Slot:
    """One device of a bus's new list: what happens to it, and its index in the old list."""

    device: DeviceBase
    action: Action
    was: int | None = None


@dataclass
class BusPlan:
    """What a reload does on one bus: the new device list, slot by slot, and the old indices
    no slot takes over (removed devices). The daemon's relay and the bus worker both apply this
    one plan, by index."""

    slots: list[Slot]
    removed: list[int] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"slots": [[s.action.value, s.was] for s in self.slots], "removed": self.removed}

    @classmethod
    def from_json(cls, body: dict[str, Any], devices: list[DeviceBase]) -> BusPlan:
        """The plan the daemon sent, over the new config's `devices` on this bus."""
        slots = [
            Slot(d, Action(action), was)
            for d, (action, was) in zip(devices, body["slots"], strict=True)
        ]
        return cls(slots, list(body["removed"]))

    @property
    def changes_nothing(self) -> bool:
        return not self.removed and all(
            s.action is Action.KEEP and s.was == i for i, s in enumerate(self.slots)
        )


def plan_bus(old: list[DeviceBase], new: list[DeviceBase]) -> BusPlan:
    """Keep a device whose whole table is unchanged, restart one whose table changed (matched
    by name), start one that is new; the old ones not matched are removed."""
    before = {d.name: i for i, d in enumerate(old)}
    slots = []
    for d in new:
        i = before.pop(d.name, None)
        if i is None:
            slots.append(Slot(d, Action.START))
        else:
            slots.append(Slot(d, Action.KEEP if old[i] == d else Action.RESTART, i))
    return BusPlan(slots, sorted(before.values()))


@dataclass
class ReloadPlan:
    """What a reload does: buses to start (with their devices), to stop, and to change."""

    start: dict[str, list[DeviceBase]] = field(default_factory=dict)  # new buses
    stop: list[str] = field(default_factory=list)  # buses with no device left
    reconfigure: dict[str, BusPlan] = field(default_factory=dict)  # changed buses
    added: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)
    unchanged: list[str] = field(default_factory=list)
    zenoh_changed: bool = False
    daemon_changed: bool = False

    @property
    def empty(self) -> bool:
        return not (
            self.start or self.stop or self.reconfigure or self.zenoh_changed or self.daemon_changed
        )

    def describe(self) -> str:
        parts = [
            f"{what}: {', '.join(names)}"
            for what, names in (
                ("added", self.added),
                ("removed", self.removed),
                ("restarted with new settings", self.changed),
                ("unchanged", self.unchanged),
            )
            if names
        ]
        if self.zenoh_changed:
            parts.append("[zenoh] changed: session reopened")
        if self.daemon_changed:
            parts.append("[daemon] changed: takes effect at the next restart")
        return "; ".join(parts) or "nothing changed"


def plan_reload(old: ImudConfig, new: ImudConfig) -> ReloadPlan:
    plan = ReloadPlan(
        zenoh_changed=old.session_settings() != new.session_settings(),
        daemon_changed=old.daemon != new.daemon,
    )
    before = {d.name: d for d in old.device}
    for d in new.device:
        prev = before.get(d.name)
        if prev is None:
            plan.added.append(d.name)
        elif prev == d:
            plan.unchanged.append(d.name)
        else:
            plan.changed.append(d.name)
    names = {d.name for d in new.device}
    plan.removed = [d.name for d in old.device if d.name not in names]
    old_buses, new_buses = by_bus(old), by_bus(new)
    for key, devices in new_buses.items():
        if key not in old_buses:
            plan.start[key] = devices
            continue
        bus_plan = plan_bus(old_buses[key], devices)
        if not bus_plan.changes_nothing:  # a device added, removed, changed or moved in order
            plan.reconfigure[key] = bus_plan
    plan.stop = [key for key in old_buses if key not in new_buses]
    return plan


Signature = tuple[int, int, int]


class ConfigFile:
    """Whether the config file changed since it was last loaded: a stat each poll (cheap), and
    the content's hash when the stat moved, so a `touch` or an editor's save of the same text
    is not a reload. A file caught half-written fails to parse and is retried at the next poll
    (its stat moves again when the writer finishes)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._sig = self._stat()
        self._digest = self._hash()

    def _stat(self) -> Signature | None:
        try:
            st = os.stat(self.path)
        except OSError:
            return None
        return (st.st_mtime_ns, st.st_size, st.st_ino)

    def _hash(self) -> str | None:
        try:
            return hashlib.sha256(self.path.read_bytes()).hexdigest()
        except OSError:
            return None

    def changed(self) -> bool:
        """True once per change of the file's content (or its disappearance)."""
        sig = self._stat()
        if sig == self._sig:
            return False
        self._sig = sig
        digest = self._hash()
        if digest == self._digest:
            return False
        self._digest = digest
        return True
