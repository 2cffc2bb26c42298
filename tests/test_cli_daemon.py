"""`imud echo` and `imud status` as real subprocesses against one real daemon (module fixture),
and `imud echo` against a Zenoh peer in this process that publishes hand-made batches (invalid
values, flags, a channel no shipped chip has)."""

from __future__ import annotations

import fcntl
import json
import math
import os
import pty
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zenoh

from imud.channels import Channel, SampleFlag
from imud.wire import encode
from tests.daemon_fixture import DaemonProc
from tests.helpers import free_port

G = 9.80665  # standard gravity, m/s^2
LONG_BUS = "/dev/i2c-imud-test-missing-bus-with-a-path-long-enough-to-overflow-eighty-columns"

CONFIG = f"""
[[device]]
name = "level"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simA", address = 0x68 }}
odr_hz = 200
[device.sim]
seed = 1
truth = true
errors = {{ ideal = true }}

[[device]]
name = "tumble"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simA", address = 0x69 }}
odr_hz = 200
[device.sim]
seed = 2
motion = {{ kind = "tumble", rate_dps = [0.0, 0.0, 100.0] }}
errors = {{ ideal = true }}

[[device]]
name = "absent"
chip = "mpu6050"
bus = {{ kind = "i2c", bus = "{LONG_BUS}", address = 0x68 }}
"""


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProc]:
    d = DaemonProc(tmp_path_factory.mktemp("cli"), CONFIG)
    try:
        d.wait_started()
        yield d
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()


def imud(
    *args: str, columns: int | None = None, timeout: float = 60.0
) -> tuple[subprocess.CompletedProcess[str], float]:
    """The real CLI; returns its result and how long it took."""
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    if columns is not None:
        env["COLUMNS"] = str(columns)
    t0 = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "imud", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )
    return r, time.monotonic() - t0


# --- 1: echo checks the device first ------------------------------------------------------------
def test_echo_unknown_device_fails_at_once_naming_the_devices(daemon: DaemonProc) -> None:
    r, _ = imud("echo", "nosuchdevice", "--connect", daemon.endpoint, timeout=60)
    assert r.returncode == 2, r.stderr
    assert "'nosuchdevice'" in r.stderr
    for name in ("level", "tumble", "absent"):
        assert name in r.stderr
    assert "did you mean" not in r.stderr  # nothing is close
    r, _ = imud("echo", "tumbel", "--connect", daemon.endpoint, timeout=60)
    assert r.returncode == 2
    assert "did you mean 'tumble'?" in r.stderr


def test_echo_truth_when_off_fails_at_once_saying_how_to_turn_it_on(daemon: DaemonProc) -> None:
    r, _ = imud("echo", "tumble", "--truth", "--connect", daemon.endpoint, timeout=60)
    assert r.returncode == 2, r.stderr
    assert "truth is off" in r.stderr
    assert "truth = true" in r.stderr and "[device.sim]" in r.stderr
    r, _ = imud("echo", "absent", "--truth", "--connect", daemon.endpoint, timeout=60)
    assert r.returncode == 2
    assert "real hardware" in r.stderr and LONG_BUS in r.stderr


def test_echo_without_daemon_fails_like_status() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    echo, _ = imud("echo", "level", "--connect", endpoint, timeout=60)
    status, _ = imud("status", "--connect", endpoint, timeout=60)
    assert echo.returncode == status.returncode == 1
    assert echo.stderr == status.stderr
    assert endpoint in echo.stderr and "imud run" in echo.stderr


# --- 2: summary -----------------------------------------------------------------------------------
def test_summary_json_honours_count_and_has_every_channel_mean(daemon: DaemonProc) -> None:
    r, _ = imud(
        "echo", "level", "--summary", "--json", "--count", "2", "--connect", daemon.endpoint
    )
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(rows) == 2
    for row in rows:
        assert row["device"] == "level" and "truth" not in row
        # the chip's 200 Hz (an ideal chip: no clock error), counting what a busy machine lost
        produced = row["rate_hz"] * (row["samples"] + row["lost"]) / row["samples"]
        assert produced == pytest.approx(200.0, rel=0.02)
        assert row["invalid"] == 0
        assert set(row["mean"]) == {"accel", "gyro", "temperature_c"}
        assert row["units"] == {"accel": "m/s^2", "gyro": "rad/s", "temperature_c": "degC"}
        assert row["mean"]["accel"] == pytest.approx([0.0, 0.0, G], abs=0.02)
        assert row["mean"]["gyro"] == pytest.approx([0.0, 0.0, 0.0], abs=2e-3)
        assert row["mean"]["temperature_c"] == pytest.approx(25.0, abs=0.5)


def test_summary_text_shows_gyro_z_of_a_100_dps_turn(daemon: DaemonProc) -> None:
    r, _ = imud("echo", "tumble", "--summary", "--count", "1", "--connect", daemon.endpoint)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 1
    line = lines[0]
    assert "samples/s" in line and "lost 0" in line
    gyro = re.search(r"gyro \[(\S+) (\S+) (\S+)\] rad/s", line)
    assert gyro, line
    assert float(gyro.group(3)) == pytest.approx(math.radians(100.0), abs=3e-3)  # 1.745
    assert re.search(r"accel \[\S+ \S+ \S+\] m/s\^2", line)
    assert re.search(r"temperature_c \S+ degC", line)


# --- 3: sample output -----------------------------------------------------------------------------
def test_echo_prints_a_header_with_units_then_the_samples(daemon: DaemonProc) -> None:
    r, _ = imud("echo", "level", "--count", "3", "--connect", daemon.endpoint)
    assert r.returncode == 0, r.stderr
    header, *rows = r.stdout.splitlines()
    assert header.startswith("#")
    for label in (
        "seq",
        "t [s]",
        "accel x y z [m/s^2]",
        "gyro x y z [rad/s]",
        "temperature_c [degC]",
        "flags",
    ):
        assert label in header
    assert "TRUTH" not in header
    assert len(rows) == 3
    for row in rows:
        values = [float(v) for v in row.split()]
        assert len(values) == 9  # seq, t, accel xyz, gyro xyz, temperature; no flags
        # white noise only (ideal): 400 ug/sqrt(Hz) at 200 Hz is sigma = 0.0555 m/s^2 per
        # sample; 0.35 is 6 sigma (0.2 was 3.6 sigma: one run in a thousand failed)
        assert values[4] == pytest.approx(G, abs=0.35)
        assert abs(values[1] - time.time()) < 30
    seqs = [int(row.split()[0]) for row in rows]
    assert seqs == list(range(seqs[0], seqs[0] + 3))


def test_truth_is_marked_on_the_header_and_every_line(daemon: DaemonProc) -> None:
    r, _ = imud("echo", "level", "--truth", "--count", "3", "--connect", daemon.endpoint)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "TRUTH" in lines[0]
    rows = [ln for ln in lines if not ln.startswith("#")]
    assert len(rows) == 3 and all(ln.startswith("truth ") for ln in rows)
    r, _ = imud("echo", "level", "--truth", "--json", "--count", "2", "--connect", daemon.endpoint)
    assert r.returncode == 0, r.stderr
    rows_json = [json.loads(ln) for ln in r.stdout.splitlines()]
    assert len(rows_json) == 2 and all(x["truth"] is True for x in rows_json)
    r, _ = imud("echo", "level", "--json", "--count", "2", "--connect", daemon.endpoint)
    assert all("truth" not in json.loads(ln) for ln in r.stdout.splitlines())


# --- 4: status ------------------------------------------------------------------------------------
def test_status_fits_80_columns_with_errors_below_the_table(daemon: DaemonProc) -> None:
    st = daemon.status()
    full_error = next(d for d in st["devices"] if d["name"] == "absent")["last_error"]
    assert LONG_BUS in full_error and len(full_error) > 80  # the full text is in --json
    r, _ = imud("status", "--connect", daemon.endpoint, columns=80)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert all(len(ln) <= 80 for ln in lines), r.stdout
    head = next(i for i, ln in enumerate(lines) if ln.split()[:1] == ["device"])
    assert {"state", "rate", "lost"} <= set(lines[head].split())
    rows = {ln.split()[0]: ln.split() for ln in lines[head + 2 : head + 5]}
    assert set(rows) == {"level", "tumble", "absent"}  # one line per device: nothing folded
    for cells in rows.values():
        numbers = [c for c in cells if re.fullmatch(r"-?[\d.]+", c)]
        assert len(numbers) >= 3, cells  # rate, samples, lost... each whole
    below = [ln for ln in lines[head + 5 :] if ln.startswith("absent:")]
    assert len(below) == 1
    assert "last error" in below[0] and " ago: " in below[0] and below[0].endswith("…")
    # a wide terminal gets more columns and the whole error
    r, _ = imud("status", "--connect", daemon.endpoint, columns=400)
    wide = r.stdout.splitlines()
    assert {"bus", "odr"} <= set(next(ln for ln in wide if ln.startswith("device")).split())
    assert any(ln.startswith("absent:") and full_error in ln for ln in wide)


def _wait_for(proc: subprocess.Popen[bytes], read: Any, want: int, seconds: float) -> bytes:
    out = b""
    end = time.monotonic() + seconds
    while time.monotonic() < end and out.count(b"devices running") < want:  # a bound, no more
        chunk = read()
        if chunk:
            out += chunk
        else:
            time.sleep(0.02)  # (a pipe's read does not wait)
        assert proc.poll() is None, out.decode(errors="replace")
    return out


def _watch(daemon: DaemonProc) -> list[str]:
    return [sys.executable, "-m", "imud", "status", "--watch", "--interval", "0.3",
            "--connect", daemon.endpoint]  # fmt: skip


def test_status_loads_no_chip_and_nothing_numeric(daemon: DaemonProc) -> None:
    """What `imud status` imports to draw its table from a live daemon: its view, Zenoh, click
    and rich; no chip, no config model, no NumPy or pydantic (its answer is the daemon's JSON).
    How long those imports take is docs/performance.md's business."""
    r = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "imud", "status", "--connect", daemon.endpoint],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    loaded = {ln.rsplit("|", 1)[-1].strip() for ln in r.stderr.splitlines() if "|" in ln}
    assert "imud.cli.status_view" in loaded and "zenoh" in loaded  # the list is the real one
    for forbidden in ("imud.chips", "imud.registry", "imud.config", "numpy", "pydantic"):
        assert not {m for m in loaded if m == forbidden or m.startswith(forbidden + ".")}, forbidden


def test_status_watch_refreshes_until_sigint_in_a_pipe(daemon: DaemonProc) -> None:
    proc = subprocess.Popen(
        _watch(daemon),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None
    os.set_blocking(proc.stdout.fileno(), False)
    out = _wait_for(proc, lambda: proc.stdout.read() if proc.stdout else b"", 2, 60.0)  # type: ignore[union-attr]
    proc.send_signal(signal.SIGINT)
    rest, err = proc.communicate(timeout=60)  # a bound for a hung one, not a pace
    assert proc.returncode == 0, err
    assert b"Traceback" not in err
    ups = re.findall(rb"up (\d+) s", out + (rest or b""))
    assert len(ups) >= 2


def test_status_watch_in_a_terminal_fits_its_width_and_exits_0_on_ctrl_c(
    daemon: DaemonProc,
) -> None:
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    env["TERM"] = "xterm"
    proc = subprocess.Popen(
        _watch(daemon),
        stdin=slave,
        stdout=slave,
        stderr=slave,
        env=env,
    )
    os.close(slave)

    def read() -> bytes:
        ready, _, _ = select.select([master], [], [], 0.1)
        try:
            return os.read(master, 65536) if ready else b""
        except OSError:  # EIO: the CLI exited and closed the terminal (checked by the caller)
            return b""

    try:
        out = _wait_for(proc, read, 2, 60.0)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 0  # a bound for a hung one, not a pace
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", out.decode(errors="replace"))
    lines = [ln for ln in text.replace("\r", "\n").split("\n") if ln]
    assert lines and max(len(ln) for ln in lines) <= 80
    assert any(ln.startswith("absent:") and ln.endswith("…") for ln in lines)


# --- echo against hand-made batches ---------------------------------------------------------------
@pytest.fixture
def fake_daemon() -> Iterator[str]:
    """A Zenoh peer answering the status query for one device "fake" (accel, gyro and a
    magnetometer) and publishing a 3-sample batch every 20 ms: sample 1 has invalid accel, sample
    2 saturated gyro."""
    port = free_port()
    conf = {
        "mode": "peer",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}},
    }
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
    status = {
        "version": "test",
        "uptime_s": 1.0,
        "ready": True,
        "buses": [],
        "devices": [
            {"name": "fake", "state": "running", "truth": False, "bus": "sim-spi:spi0@cs0"}
        ],
    }

    def answer(q: zenoh.Query) -> None:
        with q:
            q.reply(q.key_expr, json.dumps(status))

    queryable = session.declare_queryable("imud/daemon/status", answer)
    stop = threading.Event()

    def publish() -> None:
        seq = 0
        while not stop.is_set():
            accel = np.array([[0.0, 0.0, G], [np.nan] * 3, [0.1, 0.2, G]], np.float32)
            flags = [0, int(SampleFlag.ACCEL_INVALID), int(SampleFlag.GYRO_SATURATED)]
            channels = {
                Channel.ACCEL: accel,
                Channel.GYRO: np.full((3, 3), 0.5, np.float32),
                Channel.MAG: np.full((3, 3), 4.5e-5, np.float32),
            }
            t = time.time_ns() + np.arange(3) * 1_000_000
            session.put("imud/fake/imu", encode("fake", seq, t, channels, flags))
            seq += 3
            stop.wait(0.02)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        yield f"tcp/127.0.0.1:{port}"
    finally:
        stop.set()
        thread.join()
        queryable.undeclare()  # type: ignore[no-untyped-call]
        session.close()  # type: ignore[no-untyped-call]


def test_echo_shows_invalid_values_and_flags(fake_daemon: str) -> None:
    r, _ = imud("echo", "fake", "--count", "3", "--connect", fake_daemon)
    assert r.returncode == 0, r.stderr
    header, *rows = [ln for ln in r.stdout.splitlines() if not ln.startswith("# lost")]
    assert "mag x y z [T]" in header
    assert len(rows) == 3
    seqs = [int(row.split()[0]) % 3 for row in rows]
    by = dict(zip(seqs, rows, strict=True))
    assert "invalid" not in by[0] and "nan" not in by[0].lower()
    assert by[0].split()[-1] == "+4.500e-05"  # no flags column when they are 0
    assert "invalid" in by[1] and "nan" not in by[1].lower() and by[1].endswith("ACCEL_INVALID")
    assert by[2].endswith("GYRO_SATURATED")
    r, _ = imud("echo", "fake", "--count", "3", "--json", "--connect", fake_daemon)
    assert r.returncode == 0, r.stderr
    js = {x["seq"] % 3: x for x in map(json.loads, r.stdout.splitlines())}
    assert js[1]["accel"] is None and js[1]["flags"] == int(SampleFlag.ACCEL_INVALID)
    assert js[0]["accel"] == pytest.approx([0.0, 0.0, G]) and js[0]["flags"] == 0
    assert js[0]["mag"] == pytest.approx([4.5e-5] * 3)
    assert "NaN" not in r.stdout  # valid JSON
