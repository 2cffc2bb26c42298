"""Calibration files picked up while the daemon runs.

A bus worker's watcher thread looks at each of its devices' files twice a second (a stat: no
reading unless it changed) and hands the device a new model, or the reason it cannot have one.
The device swaps the model between two batches, so a new file never makes a sequence gap, and a
file being written is never seen half-written (`imud calibrate` renames a complete file into
place). A bad or missing file leaves the device running uncalibrated, saying why in status.
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from imud import registry
from imud.calib.file import CalibrationError, load_calibration
from imud.calib.model import CalibrationModel
from imud.chips.api import DeviceBase

if TYPE_CHECKING:
    from imud.config import ImudConfig

log = logging.getLogger("imud.calibration")
CHECK_EVERY_S = 0.5
Signature = tuple[int, int, int] | None


class Calibrated(Protocol):
    cfg: DeviceBase

    def set_calibration(self, model: CalibrationModel | None, error: str | None) -> None: ...


def _signature(path: Path) -> Signature:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_mtime_ns, st.st_size, st.st_ino)


def load_for(cfg: DeviceBase) -> tuple[CalibrationModel | None, str | None]:
    """The device's calibration model, or why there is none (None, None: none configured)."""
    if cfg.calibration is None:
        return None, None
    spec = registry.CHIPS[cfg.chip]
    try:
        return load_calibration(cfg.calibration, cfg.chip, spec.channels), None
    except CalibrationError as e:
        return None, str(e)


def calibration_problems(cfg: ImudConfig) -> tuple[list[str], list[str]]:
    """(errors, notes): why a device's calibration file cannot be applied, one line per device;
    a file that does not exist yet is a note (it is written by `imud calibrate`, and picked up
    when it appears). Not part of `parse_config`: a bad calibration file must not stop the
    daemon (that device runs uncalibrated and says why in status, the others run normally);
    `imud check-config` and the daemon's start-up log report them."""
    errors: list[str] = []
    notes: list[str] = []
    for i, d in enumerate(cfg.device):
        _, error = load_for(d)
        if error is None:
            continue
        line = f"device[{i}] {d.name!r}: calibration: {error}"
        assert d.calibration is not None
        missing = not d.calibration.exists() and d.calibration.parent.is_dir()
        (notes if missing else errors).append(line)
    return errors, notes


class CalibrationWatcher:
    def __init__(self, devices: list[Calibrated]) -> None:
        self.devices = [d for d in devices if d.cfg.calibration is not None]
        self._seen: dict[str, Signature] = {}
        self._thread: threading.Thread | None = None
        self._stop: threading.Event | None = None
        self._lock = threading.Lock()

    def check(self) -> None:
        """Load every file that changed (or appeared, or went away) since the last check."""
        with self._lock:  # the watcher thread, and the worker when a reload changes devices
            self._check()

    def _check(self) -> None:
        for d in self.devices:
            path = d.cfg.calibration
            assert path is not None
            sig = _signature(path)
            first = d.cfg.name not in self._seen
            if not first and sig == self._seen[d.cfg.name]:
                continue
            self._seen[d.cfg.name] = sig
            model, error = load_for(d.cfg)
            d.set_calibration(model, error)
            if error is not None:
                # a file not written yet is where every device starts (`imud calibrate` writes
                # it); one that is there and refused is a fault
                level = logging.WARNING if sig is None else logging.ERROR
                log.log(level, "%s: %s; running uncalibrated", d.cfg.name, error)
            elif not first:
                log.info("%s: calibration reloaded from %s", d.cfg.name, path)

    def watch(self, devices: list[Calibrated]) -> None:
        """A reloaded config's devices: a new or restarted device's file is loaded now (before
        its first sample), a kept device's model stays as it is."""
        devices = [d for d in devices if d.cfg.calibration is not None]
        kept = {id(d) for d in self.devices}
        for d in devices:
            if id(d) not in kept:
                self._seen.pop(d.cfg.name, None)
        self.devices = devices
        self.check()
        if self._stop is not None:
            self.start(self._stop)

    def start(self, stop: threading.Event) -> None:
        """Check in a thread of its own until `stop` is set (loading never delays a poll)."""
        self._stop = stop
        if not self.devices or self._thread is not None:
            return

        def loop() -> None:
            while not stop.wait(CHECK_EVERY_S):
                try:
                    self.check()
                except Exception:  # a bug here must not end the watching
                    log.exception("checking calibration files failed")

        self._thread = threading.Thread(target=loop, name="calibration watcher", daemon=True)
        self._thread.start()
