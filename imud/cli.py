"""The `imud` command: run the daemon, ask it how it is doing, watch its data, check configs."""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import click

from imud.config import DEFAULT_ENDPOINT
from imud.errors import ConfigError

_connect = click.option(
    "--connect",
    "endpoint",
    default=DEFAULT_ENDPOINT,
    show_default=True,
    help="Zenoh endpoint of the daemon",
)
_prefix = click.option("--prefix", default="imud", show_default=True, help="key prefix")


def _load(path: str) -> Any:
    from imud.config import load_config

    try:
        return load_config(path)
    except ConfigError as e:
        click.echo(f"{path}: invalid config:", err=True)
        for m in e.messages:
            click.echo(f"  {m}", err=True)
        sys.exit(2)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="imud")
def main() -> None:
    """imud: IMU acquisition daemon publishing over Eclipse Zenoh."""


@main.command()
@click.option(
    "--config",
    "config_path",
    required=True,
    type=click.Path(dir_okay=False),
    help="TOML config file",
)
@click.option(
    "--log-level",
    default="info",
    show_default=True,
    type=click.Choice(["debug", "info", "warning", "error"]),
)
def run(config_path: str, log_level: str) -> None:
    """Run the daemon in the foreground until SIGTERM/SIGINT."""
    import anyio

    from imud.daemon import Daemon
    from imud.logsetup import setup_logging

    cfg = _load(config_path)
    setup_logging(log_level)
    try:
        code = anyio.run(Daemon(cfg).run)
    except Exception as e:  # e.g. the Zenoh listener port is taken
        click.echo(f"imud: {type(e).__name__}: {e}", err=True)
        sys.exit(1)
    sys.exit(code)


@main.command("check-config")
@click.argument("file", type=click.Path(dir_okay=False))
def check_config(file: str) -> None:
    """Validate FILE; print the resolved config (exit 0) or the errors (exit 2)."""
    cfg = _load(file)
    click.echo(json.dumps(cfg.model_dump(mode="json"), indent=2))


@main.command("config-schema")
def config_schema() -> None:
    """Print the config file's JSON Schema."""
    from imud.config import config_model

    click.echo(json.dumps(config_model().model_json_schema(), indent=2))


def _session(endpoint: str) -> Any:
    from imud.client import NoDaemon, open_session

    try:
        return open_session(endpoint)
    except NoDaemon as e:
        click.echo(f"imud: {e}; is `imud run` running? (--connect to point elsewhere)", err=True)
        sys.exit(1)


def _fmt(v: Any, spec: str = "") -> str:
    return "-" if v is None else format(v, spec)


@main.command()
@_connect
@_prefix
@click.option("--json", "as_json", is_flag=True, help="print the daemon's JSON answer")
@click.option("--timeout", default=2.0, show_default=True, help="seconds to wait for an answer")
def status(endpoint: str, prefix: str, as_json: bool, timeout: float) -> None:
    """Show the daemon's devices and their health."""
    from imud.client import NoDaemon, get_status

    with _session(endpoint) as s:
        try:
            st = get_status(s, prefix, timeout=timeout)
        except NoDaemon as e:
            click.echo(f"imud: {e}: no daemon answered at {endpoint}", err=True)
            sys.exit(1)
    if as_json:
        click.echo(json.dumps(st, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"imud {st['version']}, up {st['uptime_s']:.0f} s")
    for col in (
        "device",
        "chip",
        "bus",
        "state",
        "odr Hz",
        "rate Hz",
        "samples",
        "lost",
        "overflows",
        "bus err",
        "temp °C",
        "calibration",
        "last error",
    ):
        t.add_column(col, overflow="fold")
    for d in st["devices"]:
        colour = {"running": "green", "error": "red"}.get(d["state"], "yellow")
        t.add_row(
            d["name"],
            d["chip"],
            d["bus"],
            f"[{colour}]{d['state']}[/]",
            _fmt(d["odr_hz"], "g"),
            _fmt(d["measured_rate_hz"], ".1f"),
            str(d["samples"]),
            str(d["lost_samples"]),
            str(d["fifo_overflows"]),
            str(d["bus_errors"]),
            _fmt(d["temperature_c"], ".1f"),
            d["calibration"] or "-",
            d["last_error"] or "-",
        )
    import shutil

    Console(width=max(shutil.get_terminal_size((160, 24)).columns, 120)).print(t)


@main.command()
@click.argument("device")
@_connect
@_prefix
@click.option("--count", type=click.IntRange(min=1), help="stop after N samples")
@click.option("--json", "as_json", is_flag=True, help="one JSON object per sample")
@click.option("--summary", is_flag=True, help="a once-a-second rate summary instead of samples")
@click.option("--truth", is_flag=True, help="the simulator's ground truth instead of the samples")
def echo(
    device: str,
    endpoint: str,
    prefix: str,
    count: int | None,
    as_json: bool,
    summary: bool,
    truth: bool,
) -> None:
    """Print DEVICE's decoded samples as they arrive."""
    from imud.client import batches

    printed = 0
    window_start, window_n, lost, next_seq = time.monotonic(), 0, 0, None
    with _session(endpoint) as s:
        try:
            for b in batches(s, device, prefix, truth=truth):
                if summary:
                    window_n += b.count
                    if next_seq is not None and b.first_seq > next_seq:
                        lost += b.first_seq - next_seq
                    next_seq = b.first_seq + b.count
                    now = time.monotonic()
                    if now - window_start >= 1.0 and b.accel is not None:
                        a = b.accel.mean(axis=0)
                        click.echo(
                            f"{device}: {window_n / (now - window_start):8.1f} samples/s  "
                            f"lost {lost}  accel [{a[0]:+.3f} {a[1]:+.3f} {a[2]:+.3f}] m/s²"
                        )
                        window_start, window_n = now, 0
                    continue
                for i in range(b.count):
                    _print_sample(b, i, as_json)
                    printed += 1
                    if count is not None and printed >= count:
                        return
        except KeyboardInterrupt:
            return


def _print_sample(b: Any, i: int, as_json: bool) -> None:
    from imud.channels import CHANNELS

    if as_json:
        row: dict[str, Any] = {"device": b.device, "seq": int(b.first_seq + i),
                               "t_ns": int(b.t_ns[i]), "flags": int(b.sample_flags[i])}  # fmt: skip
        for ch, arr in b.channels.items():
            v = arr[i]
            row[CHANNELS[ch].key] = float(v) if arr.ndim == 1 else [float(x) for x in v]
        click.echo(json.dumps(row))
        return
    parts = [f"{b.first_seq + i:>10} {int(b.t_ns[i]):>20}"]
    for ch, arr in b.channels.items():
        v = arr[i]
        vals = f"{float(v):8.3f}" if arr.ndim == 1 else " ".join(f"{float(x):+9.4f}" for x in v)
        parts.append(f"{CHANNELS[ch].key} {vals}")
    click.echo("  ".join(parts))


if __name__ == "__main__":  # pragma: no cover
    main()
