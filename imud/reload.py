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
from pathlib import Path

from imud.chips.api import DeviceBase
from imud.config import ImudConfig


def _by_bus(cfg: ImudConfig) -> dict[str, list[DeviceBase]]:
    out: dict[str, list[DeviceBase]] = {}
    for d in cfg.device:
        out.setdefault(d.bus.key, []).append(d)
    return out


@dataclass
class ReloadPlan:
    """What a reload does. Bus keys map to the new config's devices on that bus."""

    start: dict[str, list[DeviceBase]] = field(default_factory=dict)  # new buses
    stop: list[str] = field(default_factory=list)  # buses with no device left
    reconfigure: dict[str, list[DeviceBase]] = field(default_factory=dict)  # changed buses
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
        zenoh_changed=old.zenoh != new.zenoh,
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
    old_buses, new_buses = _by_bus(old), _by_bus(new)
    for key, devices in new_buses.items():
        if key not in old_buses:
            plan.start[key] = devices
        elif old_buses[key] != devices:  # a device added, removed, changed or moved in order
            plan.reconfigure[key] = devices
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
