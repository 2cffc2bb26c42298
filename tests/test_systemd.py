"""Checks for the shipped systemd unit (systemd/imud.service).

The unit is verified with ``systemd-analyze verify`` and scored with
``systemd-analyze security --offline=yes``; both work without systemd running as PID 1.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
UNIT_SOURCE = REPO / "systemd" / "imud.service"
UNIT_NAME = "imud.service"
INSTALLED_EXE = "/opt/imud/bin/imud"
MAX_EXPOSURE = 1.5  # issue 10: `systemd-analyze security --offline=yes` stays <= 1.5

Unit = dict[str, list[tuple[str, str]]]


def parse_unit(text: str) -> Unit:
    """Parse a unit file into ``{section: [(key, value), ...]}``, keeping repeated keys."""
    sections: Unit = {}
    current: list[tuple[str, str]] | None = None
    pending = ""
    for raw in text.splitlines():
        line = pending + raw.strip()
        pending = ""
        if not line or line[0] in "#;":
            continue
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], [])
            continue
        assert current is not None, f"assignment outside a section: {line!r}"
        key, sep, value = line.partition("=")
        assert sep, f"not a KEY=VALUE line: {line!r}"
        current.append((key.strip(), value.strip()))
    return sections


def values(unit: Unit, section: str, key: str) -> list[str]:
    return [v for k, v in unit.get(section, []) if k == key]


def last(unit: Unit, section: str, key: str) -> str | None:
    found = values(unit, section, key)
    return found[-1] if found else None


def seconds(value: str) -> float:
    """Parse the simple systemd time spans used in the unit ("5s", "500ms", "1min", "5")."""
    units = {"": 1.0, "s": 1.0, "sec": 1.0, "ms": 1e-3, "msec": 1e-3, "m": 60.0, "min": 60.0}
    match = re.fullmatch(r"(\d+(?:\.\d+)?)\s*([a-z]*)", value)
    assert match and match.group(2) in units, f"unexpected time span {value!r}"
    return float(match.group(1)) * units[match.group(2)]


@pytest.fixture(scope="module")
def systemd_analyze() -> str:
    exe = shutil.which("systemd-analyze")
    if exe is None:
        pytest.fail("systemd-analyze not found on PATH; install it with `apt-get install systemd`")
    return exe


@pytest.fixture(scope="module")
def imud_exe() -> Path:
    """The console script of the installed imud package (the one /opt/imud/bin/imud stands for)."""
    candidates = [Path(sys.executable).parent / "imud"]
    on_path = shutil.which("imud")
    if on_path is not None:
        candidates.append(Path(on_path))
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    pytest.fail(
        f"imud console script not found (looked in {candidates[0].parent} and on PATH); "
        "install the package first, e.g. `pip install -e .`"
    )


@pytest.fixture(scope="module")
def unit_text() -> str:
    return UNIT_SOURCE.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def unit(unit_text: str) -> Unit:
    return parse_unit(unit_text)


@pytest.fixture(scope="module")
def local_unit(unit_text: str, imud_exe: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the unit whose ExecStart points at the locally installed console script."""
    assert INSTALLED_EXE in unit_text, f"{UNIT_SOURCE} no longer refers to {INSTALLED_EXE}"
    path = tmp_path_factory.mktemp("unit") / UNIT_NAME
    path.write_text(unit_text.replace(INSTALLED_EXE, str(imud_exe)), encoding="utf-8")
    return path


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=60, check=False)


def test_verify_is_clean(systemd_analyze: str, local_unit: Path) -> None:
    result = run(systemd_analyze, "verify", "--man=no", str(local_unit))
    output = result.stdout + result.stderr
    complaints = [line for line in output.splitlines() if UNIT_NAME in line]
    assert result.returncode == 0, f"systemd-analyze verify failed:\n{output}"
    assert not complaints, "systemd-analyze verify complained:\n" + "\n".join(complaints)


def test_security_exposure(systemd_analyze: str, local_unit: Path) -> None:
    result = run(systemd_analyze, "security", "--no-pager", "--offline=yes", str(local_unit))
    output = result.stdout + result.stderr
    match = re.search(rf"Overall exposure level for {re.escape(UNIT_NAME)}: (\d+\.\d+)", output)
    assert match, f"no overall exposure line in systemd-analyze security output:\n{output}"
    exposure = float(match.group(1))
    assert exposure <= MAX_EXPOSURE, f"exposure {exposure} > {MAX_EXPOSURE}:\n{output}"


def test_service_type_and_watchdog(unit: Unit) -> None:
    assert last(unit, "Service", "Type") == "notify"
    assert last(unit, "Service", "NotifyAccess") == "main"
    watchdog = last(unit, "Service", "WatchdogSec")
    assert watchdog is not None, "WatchdogSec is not set"
    assert seconds(watchdog) > 0, "WatchdogSec must be a positive time span"


def test_reload_sends_sighup(unit: Unit) -> None:
    reload = last(unit, "Service", "ExecReload")
    assert reload is not None, "ExecReload is not set"
    argv = reload.split()
    assert Path(argv[0]).name == "kill", reload
    assert "-HUP" in argv or "-SIGHUP" in argv, reload
    assert argv[-1] in ("$MAINPID", "${MAINPID}"), reload


def test_restart_policy(unit: Unit) -> None:
    assert last(unit, "Service", "Restart") == "on-failure"
    assert last(unit, "Unit", "StartLimitBurst") is not None, "no start limit"


def test_runs_as_imud_with_device_groups(unit: Unit) -> None:
    assert last(unit, "Service", "User") == "imud"
    groups = {g for v in values(unit, "Service", "SupplementaryGroups") for g in v.split()}
    missing = {"i2c", "spi", "dialout"} - groups
    assert not missing, f"SupplementaryGroups lacks {sorted(missing)}"


def test_devices_stay_reachable(unit: Unit) -> None:
    private_devices = last(unit, "Service", "PrivateDevices")
    assert private_devices is None or private_devices.lower() in ("no", "false", "off", "0"), (
        "PrivateDevices=yes hides /dev/i2c-* and /dev/spidev* from the daemon"
    )
    allowed = {v.split()[0] for v in values(unit, "Service", "DeviceAllow")}
    assert {"char-i2c", "char-spi"} <= allowed, f"DeviceAllow lacks i2c/spi: {sorted(allowed)}"
