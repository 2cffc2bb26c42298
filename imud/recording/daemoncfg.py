"""The config a daemon ran, rebuilt elsewhere (a recorder, a replay) with its calibration files as
the daemon read them: each device's calibration copied into a private directory and the config
pointed there, so what is computed from them (the ROS 2 covariances from measured noise) is the
daemon's, on any machine."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from imud.config import ImudConfig, parse_config

PREFIX = "imud-config-"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's
        return True
    return True


def sweep_stale(tmp: Path) -> list[Path]:
    """Remove the copies of processes that died without `close()` (killed): this user's
    `imud-config-<pid>-*` directories whose process is gone. Returns what it removed."""
    gone = []
    for d in tmp.glob(f"{PREFIX}*-*"):
        pid = d.name[len(PREFIX) :].split("-", 1)[0]
        try:
            if not pid.isdigit() or d.stat().st_uid != os.getuid() or _alive(int(pid)):
                continue
        except OSError:
            continue
        shutil.rmtree(d, ignore_errors=True)
        gone.append(d)
    return gone


class DaemonConfig:
    """`raw`: the config as a table (the daemon's JSON, or its TOML file read); `calibration`:
    device name -> the calibration file's text. `config` is the ImudConfig, or None with
    `error` saying why it does not load here. Call `close()` to remove the copies."""

    def __init__(self, raw: dict[str, Any], calibration: dict[str, str]) -> None:
        # named by this process, so a later one can tell a killed process's copies from a live
        # one's and remove them (a recorder stopped with SIGKILL cannot)
        sweep_stale(Path(tempfile.gettempdir()))
        self._tmp = tempfile.TemporaryDirectory(prefix=f"{PREFIX}{os.getpid()}-")
        raw = dict(raw)
        devices = []
        for d in raw.get("device", []):
            d = dict(d)
            text = calibration.get(str(d.get("name")))
            if text is not None:
                copy = Path(self._tmp.name) / f"{d['name']}.cal.toml"
                copy.write_text(text)
                d["calibration"] = str(copy)
            elif d.get("calibration") is not None and not Path(str(d["calibration"])).is_absolute():
                d["calibration"] = None  # a path relative to a config file that is not here
            devices.append(d)
        raw["device"] = devices
        self.config: ImudConfig | None = None
        self.error: str | None = None
        try:
            self.config = parse_config(raw)
        except Exception as e:
            self.error = f"the daemon's config does not load here ({e})"

    def close(self) -> None:
        self._tmp.cleanup()
