"""Suite-wide: bytecode is cached, and the slowest files start first, so that on a few workers
(pytest-xdist, one file per worker at a time) none of them is left to run alone at the end."""

from __future__ import annotations

import os
import sys

import pytest

# The suite starts hundreds of interpreters (daemons, bus processes, CLI runs), each importing
# imud, NumPy, pydantic, matplotlib: where the environment turns bytecode caching off
# (PYTHONDONTWRITEBYTECODE), every one of them would compile those modules from source again,
# and pytest its rewritten test modules. Written once, the cached bytecode is what they all read.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # for the processes the tests start

# the files that take longest, longest first (`pytest --durations=0`, docs/testing.md)
SLOW_FIRST = (
    "test_daemon_e2e.py",
    "test_daemon_bno055.py",
    "test_adis16465_sim.py",
    "test_sim_faults.py",
    "test_toy_chip.py",
    "test_timestamp_accuracy.py",
    "test_calib_foreign.py",
    "test_bus_process.py",
    "test_cli_daemon.py",
    "test_bmi088_driver.py",
    "test_reload.py",
    "test_cli_calibrate.py",
    "test_cli_config.py",
    "test_icm42688p_sim.py",
    "test_stim300_sim.py",
    "test_sim_resets.py",
    "test_daemon_stim300.py",
    "test_daemon_icm.py",
    "test_daemon_adis16465.py",
    "test_daemon_bmi088.py",
    # the slow tier (`-m slow`)
    "test_daemon_calibrate.py",
    "test_daemon_faults.py",
    "test_watchdog.py",
    "test_atomic_writes.py",
    "test_bus_hang.py",
)


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """One worker more than the machine has cores (`-n auto`): many tests wait on real time
    (a daemon streaming), and the extra worker fills the cores meanwhile (measured on 2 cores:
    164 s with 2 workers, 152 s with 3, the cores then idle 18 s instead of 51)."""
    return (os.cpu_count() or 1) + 1


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: order within
