"""What the CLI says when things go wrong, run as real subprocesses: no daemon, a malformed
`--connect`, the daemon's listen port taken, a Zenoh option Zenoh refuses. No message may carry
Zenoh's Rust source locations or a traceback."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers import free_port

DEVICE = '[[device]]\nname = "imu0"\nchip = "mpu6050"\nbus = { kind = "sim" }\n'


def imud(*args: str, timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", *args], capture_output=True, text=True, timeout=timeout
    )


def no_internals(text: str) -> None:
    assert "Traceback" not in text
    assert ".rs:" not in text and ".cargo" not in text, text


@pytest.mark.parametrize("command", [["status"], ["echo", "imu0"]])
@pytest.mark.parametrize(
    ("endpoint", "says"),
    [
        ("foo", "PROTOCOL/HOST:PORT"),
        ("tcp/127.0.0.1:99999", "1-65535"),
        ("tcp/127.0.0.1", "HOST:PORT"),
        ("127.0.0.1:7450", "PROTOCOL/HOST:PORT"),
    ],
)
def test_malformed_connect_is_a_usage_error(command: list[str], endpoint: str, says: str) -> None:
    r = imud(*command, "--connect", endpoint)
    assert r.returncode == 2, r.stderr
    assert f"'{endpoint}'" in r.stderr and "--connect" in r.stderr
    assert says in r.stderr
    assert "no daemon" not in r.stderr and "reachable" not in r.stderr
    no_internals(r.stderr)


def test_no_daemon_message_is_clean() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    r = imud("status", "--connect", endpoint)
    assert r.returncode == 1
    assert endpoint in r.stderr and "imud run" in r.stderr
    no_internals(r.stderr)


def test_status_json_without_daemon_prints_a_json_error() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    r = imud("status", "--json", "--connect", endpoint)
    assert r.returncode == 1
    doc = json.loads(r.stdout)
    assert set(doc) == {"error"} and endpoint in doc["error"]
    no_internals(r.stdout + r.stderr)


@pytest.fixture
def taken_port() -> Iterator[int]:
    """A loopback port something else already listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield int(s.getsockname()[1])


def _error_lines(stderr: str) -> list[str]:
    """The CLI's own lines (log lines start with a time or a <priority>)."""
    return [ln for ln in stderr.splitlines() if ln.startswith("imud:")]


def test_run_with_listen_port_taken_says_which_and_what_to_do(
    tmp_path: Path, taken_port: int
) -> None:
    endpoint = f"tcp/127.0.0.1:{taken_port}"
    config = tmp_path / "imud.toml"
    config.write_text(f'[zenoh]\nlisten = ["{endpoint}"]\n' + DEVICE)
    r = imud("run", "--config", str(config))
    assert r.returncode == 1, r.stderr
    no_internals(r.stderr)
    lines = _error_lines(r.stderr)
    assert len(lines) == 1, r.stderr
    assert endpoint in lines[0] and "already in use" in lines[0]
    assert "another imud" in lines[0] and "[zenoh] listen" in lines[0]


def test_run_with_an_option_zenoh_refuses_names_it(tmp_path: Path) -> None:
    config = tmp_path / "imud.toml"
    config.write_text(
        f'[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\noptions = {{"no/such/key" = 1}}\n'
        + DEVICE
    )
    r = imud("run", "--config", str(config))
    assert r.returncode == 1, r.stderr
    no_internals(r.stderr)
    lines = _error_lines(r.stderr)
    assert len(lines) == 1 and "zenoh.options" in lines[0] and "'no/such/key'" in lines[0]
    r = imud("check-config", str(config))  # caught before the daemon runs, too
    assert r.returncode == 2 and "'no/such/key'" in r.stderr
