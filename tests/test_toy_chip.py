"""The structure's proof: a chip defined outside imud (tests/toychip.py: register map, config
model with a check of its own, driver, register-level simulator, spec) is installed as a plugin
through the `imud.chips` entry point, and streams through the real daemon, in its default bus
process, to a Zenoh subscriber, with no imud module changed for it.

Its FIFO overflows (the bus stalls longer than the FIFO lasts), and every gap is counted exactly,
as each sample's own value shows (the simulated field turns with the chip's sample count); a
brown-out resets its registers, which the daemon's periodic register re-check finds, and the chip
is re-initialised and streams again. A config its own check refuses fails
`imud check-config` with its message.
"""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import imud.client as ic
from imud.channels import Channel
from imud.wire import FLAG_GAP_UNCERTAIN, Batch
from tests.daemon_fixture import DaemonProc

ROOT = Path(__file__).resolve().parent.parent

TOY = """
[[device]]
name = "toy0"
chip = "toy"
odr_hz = 400
bus = { kind = "sim", bus = "spiT", transport = "spi", cs = 0, speed_hz = 4_000_000 }
[device.sim]
# seed 4: its first stall comes ~3 s in. An overflow in the stream's first second, before the
# reads have pinned the sample grid, can miscount its gap by one (docs/timestamps.md)
seed = 4
# a transfer in 50 blocks the bus for 300 ms: longer than the 64-sample FIFO lasts (158 ms)
faults = { stall_rate = 0.02, stall_ms = 300.0, resets = [{ at_s = 4.0 }] }
"""


@pytest.fixture(scope="module")
def plugin(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The toy installed as a plugin distribution would be: metadata declaring the entry
    point, on the interpreter's path."""
    site = tmp_path_factory.mktemp("site")
    info = site / "imud_toy-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: imud-toy\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[imud.chips]\ntoy = tests.toychip:SPEC\n")
    return {"PYTHONPATH": f"{site}:{ROOT}"}


def test_imud_itself_does_not_know_the_toy() -> None:
    """Without the plugin on the path, the same config names an unknown chip."""
    from imud.config import parse_config
    from imud.errors import ConfigError

    with pytest.raises(ConfigError, match="toy"):
        parse_config({"device": [{"name": "t", "chip": "toy", "bus": {"kind": "sim"}}]})


def test_the_toys_own_config_check_speaks_through_check_config(
    tmp_path: Path, plugin: dict[str, str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[[device]]\nname = "toy0"\nchip = "toy"\n'
        'bus = { kind = "sim", transport = "spi", speed_hz = 20_000_000 }\n'
    )
    run = [sys.executable, "-m", "imud", "check-config"]
    env = {"PATH": "/usr/bin:/bin", **plugin}
    r = subprocess.run([*run, str(bad)], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2, r.stderr
    assert "toy0" in r.stderr and "the toy's SPI runs at most at 8 MHz" in r.stderr, r.stderr
    assert "bus.speed_hz is 20 MHz" in r.stderr


def _sample_index(mag: np.ndarray) -> np.ndarray:
    """The simulator's own index of each sample since the chip was enabled, read back from the
    sample itself: the field turns at 30 deg/s on the chip's clock (400 Hz, 1 % fast), so its
    direction names the sample (0.074 deg apart; a count is 0.011 deg at 50 uT)."""
    yaw = np.unwrap(np.arctan2(-mag[:, 1], mag[:, 0]))
    return np.rint(yaw / (math.radians(30.0) / (400 * 1.01))).astype(np.int64)


def test_the_toy_streams_through_the_daemons_bus_process(
    tmp_path: Path, plugin: dict[str, str]
) -> None:
    d = DaemonProc(tmp_path, TOY, env=plugin)
    data: list[Batch] = []
    try:
        with d.answering_session() as s:
            end = time.monotonic() + 60  # a bound for a broken daemon
            for b in ic.batches(s, "toy0", timeout=10.0):
                data.append(b)
                dev = ic.get_status(s, device="toy0") if len(data) % 20 == 0 else {}
                seen = dev.get("resets", 0) >= 1 and dev.get("fifo_overflows", 0) >= 1
                if seen and sum(x.count for x in data) > 3000:
                    break
                assert time.monotonic() < end, dev
            # the bus process reports status periodically: wait for its snapshot to count the
            # samples already received, or its counters lag the batches compared with them
            got_n = sum(x.count for x in data)
            while (dev := ic.get_status(s, device="toy0"))["samples"] < got_n:
                assert time.monotonic() < end + 20, dev
                time.sleep(0.05)
            pid = ic.get_status(s)["buses"][0]["pid"]
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    got = data
    assert pid is not None and pid != d.proc.pid  # its worker runs in a process of its own
    # continuous, or every gap announced in the batch after it
    for prev, b in itertools.pairwise(got):
        assert b.first_seq - (prev.first_seq + prev.count) == b.lost_before
    # the FIFO overflowed, the register re-check found the brown-out, and it streams again
    assert dev["fifo_overflows"] >= 1 and dev["lost_samples"] > 0, dev
    assert dev["resets"] >= 1 and dev["bad_registers"] >= 1 and dev["state"] == "running", dev
    assert dev["fifo_resets"] >= dev["fifo_overflows"] + dev["resets"], dev
    # every gap counted exactly, or flagged as an estimate: until the brown-out restarts the
    # chip's count, each sample's seq is the chip's own index of it plus a constant, which
    # changes only across a gap the daemon said it could not pin (a host too loaded to time
    # the FIFO's restart within a period: the toy has no sample counter to settle it)
    seq = np.concatenate([b.seq for b in got])
    index = _sample_index(np.concatenate([b.channels[Channel.MAG] for b in got]))
    (restart,) = np.flatnonzero(np.diff(index) < 0)[:1] + 1  # the brown-out
    lost = np.concatenate([np.r_[b.lost_before, np.zeros(b.count - 1, int)] for b in got])
    estimated = np.concatenate(
        [np.r_[bool(b.flags & FLAG_GAP_UNCERTAIN), np.zeros(b.count - 1, bool)] for b in got]
    )
    assert lost[:restart].sum() > 0  # overflows before it
    offset = (seq - index)[:restart]
    moved = np.flatnonzero(np.diff(offset)) + 1
    assert estimated[moved].all(), (moved, offset[moved - 1], offset[moved])
    assert dev["uncertain_gaps"] >= int(estimated.sum()), dev
    # what its spec declares, scaled to SI by its driver's scales
    assert set(got[0].channels) == {Channel.GYRO, Channel.MAG}
    gyro = np.concatenate([b.channels[Channel.GYRO] for b in got])
    mag = np.concatenate([b.channels[Channel.MAG] for b in got])
    assert gyro[:, 2] == pytest.approx(math.radians(30.0), abs=1e-6)  # rad/s
    assert np.linalg.norm(mag, axis=1) == pytest.approx(50e-6, rel=1e-3)  # tesla
    t_ns = np.concatenate([b.t_ns for b in got])
    assert np.all(np.diff(t_ns) > 0)
    assert dev["odr_hz"] == 400 and dev["channels"] == ["gyro", "mag"]
    assert dev["chip_status"]["reads"] > 0
    assert dev["chip_rate_hz"] == pytest.approx(404, rel=5e-3)  # its clock runs 1 % fast
