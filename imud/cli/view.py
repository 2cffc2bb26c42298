"""`imud view [FILE.mcap] [--port 8765] [--layout LAYOUT.json]`: a Foxglove WebSocket server on
127.0.0.1 (imud/recording/foxglove_out.py) with a running daemon's devices (their ROS 2
messages, /diagnostics, /imud/status), or a recording's messages at their pace, until Ctrl-C.
Open it in Foxglove: Open connection, Foxglove WebSocket, ws://localhost:8765; `--layout` writes
a layout for the devices to import there (Layouts, Import from file). Needs the `view` extra
(foxglove-sdk)."""

from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path
from typing import Any

import click

from imud.cli.common import (
    EXIT_USAGE,
    _ask_status,
    _connect,
    _fail,
    _lean_runtime,
    _prefix,
    _session,
)

LIVE_SETTLE_S = 0.5  # how long a live view gathers the devices' channels before it serves


@click.command()
@click.argument("path", required=False, type=click.Path(dir_okay=False, exists=True))
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True)
@click.option(
    "--layout",
    "layout_path",
    type=click.Path(dir_okay=False),
    help="write a Foxglove layout for the devices (plots of accel, gyro, temperature, health)",
)
@click.option("--loop", is_flag=True, help="a recording: play it again and again")
@_connect
@_prefix
def view(
    path: str | None,
    port: int,
    layout_path: str | None,
    loop: bool,
    endpoint: str,
    prefix: str,
) -> None:
    """Serve a running daemon's devices (or FILE.mcap) to Foxglove over WebSocket."""
    from imud.recording.foxglove_out import FoxgloveOut

    try:
        import foxglove  # noqa: F401
    except ImportError as e:
        _fail(f"imud view needs foxglove-sdk: pip install 'imud[view]' ({e})", EXIT_USAGE)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    out = FoxgloveOut()
    try:
        if path is None:
            _live(out, port, stop, layout_path, endpoint, prefix)
        else:
            _file(out, port, stop, Path(path), layout_path, loop)
    finally:
        out.close()


def _serve(out: Any, port: int, what: str) -> None:
    """Start the server and say where (tests and users read the address from this line)."""
    try:
        out.serve(port)
    except Exception as e:  # the port is taken
        _fail(f"cannot serve on 127.0.0.1:{port}: {e}; give --port", EXIT_USAGE)
    click.echo(
        f"serving {what} to Foxglove on ws://127.0.0.1:{out.port} (Ctrl-C to stop)", err=True
    )


def _write_layout(path: str | None, devices: list[dict[str, Any]], namespace: str) -> None:
    if path is None:
        return
    from imud.recording.foxglove_out import layout

    Path(path).write_text(json.dumps(layout(devices, namespace), indent=2))
    click.echo(f"{path}: a layout for {', '.join(d['name'] for d in devices)}", err=True)


def _live(
    out: Any,
    port: int,
    stop: threading.Event,
    layout_path: str | None,
    endpoint: str,
    prefix: str,
) -> None:
    from imud.recording.recorder import Recorder
    from imud.session import NoDaemon, get_config, get_status

    _lean_runtime()  # every stream subscribed; signals only set a flag
    with _session(endpoint) as s:
        st = _ask_status(s, endpoint, prefix, 2.0)
        devices = st.get("devices", [])
        if not devices:
            _fail(f"the daemon at {endpoint} runs no devices", EXIT_USAGE)
        try:
            cfg: dict[str, Any] | None = get_config(s, prefix, timeout=2.0)
        except NoDaemon:
            cfg = None
        namespace = ((cfg or {}).get("config", {}).get("ros2") or {}).get("namespace", "")
        _write_layout(layout_path, devices, namespace)

        def status(devs: list[dict[str, Any]], now_ns: int) -> None:
            out.status({"devices": devs}, now_ns)

        names = [d["name"] for d in devices]
        rec = Recorder(s, prefix, names, cfg, out, native=False, on_status=status, hold_ms=20.0)
        rec.start()
        # the devices' first messages make their channels, so a client's first advertisement
        # holds them (see FoxgloveOut)
        first = time.monotonic() + LIVE_SETTLE_S
        while not stop.is_set() and time.monotonic() < first:
            rec.drain(0.05)
        _serve(out, port, f"{', '.join(names)} from {endpoint}")
        next_status = time.monotonic()
        try:
            while not stop.is_set():
                rec.drain(0.05)
                if time.monotonic() >= next_status:
                    next_status = time.monotonic() + 1.0
                    try:
                        devs = get_status(s, prefix, timeout=0.5).get("devices", [])
                        rec.status(devs, time.time_ns())
                    except NoDaemon:
                        pass
        finally:
            rec.stop()


def _file(
    out: Any, port: int, stop: threading.Event, path: Path, layout_path: str | None, loop: bool
) -> None:
    from imud.recording.reader import McapInputError, open_recording

    try:
        rec = open_recording(path)
    except McapInputError as e:
        _fail(str(e), EXIT_USAGE)
    if rec.warning:
        click.echo(f"imud: {rec.warning}", err=True)
    devices = [rec.info.get(d, {"name": d}) for d in sorted(rec.devices)]
    found = rec.daemon_config()
    namespace = str(((found[0] if found else {}).get("ros2") or {}).get("namespace", ""))
    _write_layout(layout_path, devices, namespace)
    try:
        out.announce(_topics(rec))
    except Exception as e:  # a summary that open_recording took and the reader does not
        _fail(f"{path}: damaged: {e}; `imud record --recover {path}` saves the rest", 1)
    _serve(out, port, str(path))
    click.echo("it plays once a client subscribes", err=True)
    while not stop.is_set():
        try:
            _play(out, stop, rec)
        except Exception as e:
            _fail(f"{path}: damaged: {e}; `imud record --recover {path}` saves the rest", 1)
        if not loop:
            click.echo("the recording ended (Ctrl-C to stop serving)", err=True)
            stop.wait()


def _topics(rec: Any) -> list[tuple[str, str]]:
    """(topic, message type) of an indexed recording's channels, less the native batches: every
    topic there to subscribe to before it plays. An unindexed one's come as it plays."""
    from mcap.reader import make_reader

    if not rec.indexed:
        return []
    native = set(rec.devices.values())
    with open(rec.path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None:
        return []
    return [
        (c.topic, summary.schemas[c.schema_id].name)
        for c in summary.channels.values()
        if c.topic not in native and c.schema_id in summary.schemas
    ]


def _play(out: Any, stop: threading.Event, rec: Any) -> None:
    """The file's messages (less the native batches) to `out` at their pace, once, from when a
    client first subscribes; from the native batches, /imud/status each second of the file (its
    devices' rate, lost samples and temperature, as a daemon's status says them)."""
    from mcap.reader import NonSeekingReader, make_reader

    from imud.channels import Channel
    from imud.recording.schemas import batch_wire
    from imud.wire import decode

    native = {topic: name for name, topic in rec.devices.items()}
    while not stop.is_set() and not out.subscribed():
        stop.wait(0.05)
    counts = {
        name: {"name": name, "state": "running", "samples": 0, "lost_samples": 0,
               "measured_rate_hz": 0.0, "temperature_c": None}
        for name in rec.devices
    }  # fmt: skip
    second: dict[str, int] = dict.fromkeys(rec.devices, 0)
    with open(rec.path, "rb") as f:
        reader = make_reader(f) if rec.indexed else NonSeekingReader(f)
        t0_log: int | None = None
        next_status: int | None = None
        t0 = time.monotonic()
        for schema, channel, message in reader.iter_messages(log_time_order=rec.indexed):
            if stop.is_set():
                break
            t0_log = message.log_time if t0_log is None else t0_log
            next_status = message.log_time + 10**9 if next_status is None else next_status
            wait = t0 + (message.log_time - t0_log) / 1e9 - time.monotonic()
            if wait > 0:
                stop.wait(wait)
            device = native.get(channel.topic)
            if device is not None:
                b = decode(batch_wire(message.data))
                c = counts[device]
                c["lost_samples"] += b.lost_before if c["samples"] else 0
                c["samples"] += b.count
                second[device] += b.count
                temp = b.get(Channel.TEMPERATURE)
                if temp is not None and temp.size:
                    c["temperature_c"] = round(float(temp[-1]), 2)
            elif schema is not None:
                out.add(channel.topic, schema.name, message.log_time, message.data)
            if message.log_time >= next_status:
                for name, c in counts.items():
                    c["measured_rate_hz"] = float(second[name])
                    second[name] = 0
                out.status({"devices": list(counts.values())}, message.log_time)
                next_status += 10**9
