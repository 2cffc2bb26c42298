"""`imud replay FILE.mcap... [--rate X] [--loop] [--device NAME ...] [--restamp]`: a recording
published as the live daemon publishes it (imud/recording/replay.py), on a Zenoh listener of its
own (`--listen`, the daemon's default endpoint unless told), until the file ends (or Ctrl-C)."""

from __future__ import annotations

import json
import signal
import threading
from pathlib import Path
from typing import Any

import click

from imud.cli.common import EXIT_USAGE, _fail, _named, _prefix
from imud.recording.reader import Recording


@click.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "--rate", type=click.FloatRange(min=0.01, max=1000.0), default=1.0, show_default=True,
    help="times real time",
)  # fmt: skip
@click.option("--loop", is_flag=True, help="play it again and again (stamps and seqs go on)")
@click.option(
    "--device", "--devices", "devices", multiple=True,
    help="only these devices (repeat it, or name them with commas: --devices a,b)",
)  # fmt: skip
@click.option("--restamp", is_flag=True, help="move the stamps so the first sample is now")
@click.option(
    "--ros2/--no-ros2",
    default=None,
    help="the ROS 2 output as the recorded config has it (default: on if its [ros2] was)",
)
@click.option(
    "--wait",
    is_flag=True,
    help="start once every device's stream has a subscriber (start a recorder or echo then)",
)
@click.option(
    "--listen",
    default="tcp/127.0.0.1:7450",
    show_default=True,
    help="Zenoh endpoint to listen on (where clients --connect)",
)
@_prefix
def replay(
    paths: tuple[str, ...],
    rate: float,
    loop: bool,
    devices: tuple[str, ...],
    restamp: bool,
    ros2: bool | None,
    wait: bool,
    listen: str,
    prefix: str,
) -> None:
    """Publish a recording's devices as the daemon does, at its pace."""
    import zenoh

    from imud.recording.reader import McapInputError, open_recordings
    from imud.recording.replay import Replay, first_samples
    from imud.zerrors import clean

    try:
        rec = open_recordings([Path(p) for p in paths])
    except McapInputError as e:
        _fail(str(e), EXIT_USAGE)
    path = _named(rec)
    if rec.warning:
        click.echo(f"imud: {rec.warning}", err=True)
    names = [n for d in devices for n in d.split(",") if n] or sorted(rec.devices)
    unknown = [d for d in names if d not in rec.devices]
    if unknown:
        _fail(
            f"{path} has no device {', '.join(map(repr, unknown))} (it holds "
            f"{', '.join(sorted(rec.devices))})",
            EXIT_USAGE,
        )
    conf = {
        "mode": "peer",
        "listen": {"endpoints": [listen]},
        "scouting": {"multicast": {"enabled": False}},
    }
    try:
        session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
    except Exception as e:  # the endpoint is taken (a daemon runs there), or not an endpoint
        why = clean(str(e))
        taken = "address already in use" in why.lower() or "os error 98" in why.lower()
        _fail(
            f"cannot listen on {listen}: "
            + ("it is taken (a daemon runs there?)" if taken else why)
            + "; give --listen tcp/127.0.0.1:PORT with a free port",
            EXIT_USAGE,
        )
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    out, daemon_cfg = _ros2_output(rec, session, ros2)
    player = Replay(
        rec, session, prefix, names, rate, restamp or loop,
        on_batch=None if out is None else out.batch,
    )  # fmt: skip
    player.config_view = _config_view(rec, daemon_cfg)
    player.start()
    ticker = None if out is None else _ticker(out, player, stop)
    click.echo(f"replaying {', '.join(names)} from {path} on {listen} at {rate:g}x", err=True)
    first = first_samples(rec, names) if loop else {}
    passes = 0
    damaged: str | None = None
    try:
        if wait:
            click.echo("waiting for a subscriber of every device (Ctrl-C to stop)", err=True)
            while not stop.is_set() and not player.subscribed():
                stop.wait(0.05)
        while not stop.is_set():
            try:
                done = player.run_pass(stop)
            except McapInputError as e:  # damage past the summary: said, what was sent stands
                damaged = str(e)
                break
            passes += 1
            if not loop or done.batches == 0:
                break
            player.next_loop(first, _period_ns(rec, names))
    finally:
        stop.set()
        if ticker is not None:
            ticker.join()
        if out is not None:
            out.close()
        if daemon_cfg is not None:
            daemon_cfg.close()
        player.stop()
        session.close()  # type: ignore[no-untyped-call]
    sent = ", ".join(f"{d} {n:,}" for d, n in player.sent.items())
    if damaged is not None:  # what was sent before it stands; the exit says it did not end well
        _fail(f"{damaged}; replayed up to there: {sent} samples", 1)
    click.echo(f"replayed {passes} pass(es): {sent} samples", err=True)


def _config_view(rec: Recording, cfg: Any) -> dict[str, Any] | None:
    """What the daemon's config queryable answered, from the recording (None: none kept)."""
    found = rec.daemon_config()
    if cfg is None or cfg.config is None or found is None:
        return None
    _, calibration = found
    name = next((n for n in rec.attachments if ": " not in n and n.endswith(".toml")), None)
    return {
        "path": name,
        "text": None if name is None else rec.attachments[name].decode("utf-8", "replace"),
        "config": cfg.config.model_dump(mode="json"),
        "calibration": {d: {"path": f"{d}.cal.toml", "text": t} for d, t in calibration.items()},
    }


def _ros2_output(rec: Recording, session: Any, wanted: bool | None) -> tuple[Any, Any]:
    """The recorded config (a DaemonConfig) and its ROS 2 output on the replay's session (None
    when it is off)."""
    from imud.recording.daemoncfg import DaemonConfig

    found = rec.daemon_config()
    if found is None:
        if wanted:
            _fail(f"{rec.path} kept no config: --ros2 has nothing to build from", EXIT_USAGE)
        return None, None
    cfg = DaemonConfig(*found)
    if cfg.config is None or not (wanted or (wanted is None and cfg.config.ros2.enabled)):
        if wanted and cfg.error:
            _fail(f"{rec.path}: {cfg.error}", EXIT_USAGE)
        return None, cfg
    from imud.ros2.output import Ros2Output

    out = Ros2Output(cfg.config, session)
    topics = ", ".join(out.topics())
    click.echo(f"ROS 2 output ({', '.join(cfg.config.ros2.profiles)}): {topics}", err=True)
    return out, cfg


def _ticker(out: Any, player: Any, stop: threading.Event) -> threading.Thread:
    """/diagnostics once a second from the replay's status, as the daemon's output has it."""

    def run() -> None:
        while not stop.wait(1.0):
            out.tick(player.status()["devices"])

    t = threading.Thread(target=run, name="ros2-tick", daemon=True)
    t.start()
    return t


def _period_ns(rec: Recording, names: list[str]) -> int:
    """One sample period of the fastest device (a loop's gap between passes), from the info."""
    info = rec.info
    rates = [float(info.get(d, {}).get("odr_hz") or 0) for d in names]
    fastest = max(rates, default=0.0)
    return int(1e9 / fastest) if fastest > 0 else 1_000_000
