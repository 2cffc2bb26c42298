"""The `imud` command: run the daemon, ask it how it is doing, watch its data, check configs.

Exit codes: 0 done, 1 no daemon (or the daemon failed to start), 2 usage or config errors (a
malformed `--connect`, an unknown device, truth asked of a device that does not publish it).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import click

from imud.status import DeviceState

if TYPE_CHECKING:
    from rich.console import Console, RenderableType


from imud.cli.common import (
    EXIT_USAGE,
    _ask_status,
    _connect,
    _device,
    _load,
    _no_answer,
    _prefix,
    _session,
)
from imud.cli.config_view import config_summary
from imud.cli.echo_view import Samples, Summary, arrivals
from imud.cli.status_view import cut, status_view

ECHO_STATUS_TIMEOUT_S = 1.0  # echo's status question: a wrong name must fail within 2 s


def _calibrate() -> click.Command:
    from imud.cli.calibrate import calibrate

    return calibrate


def _record() -> click.Command:
    from imud.cli.record import record

    return record


def _export() -> click.Command:
    from imud.cli.export import export

    return export


def _view() -> click.Command:
    from imud.cli.view import view

    return view


def _plot() -> click.Command:
    from imud.cli.plot import plot

    return plot


def _replay() -> click.Command:
    from imud.cli.replay import replay

    return replay


def _noise() -> click.Command:
    from imud.cli.noise import noise

    return noise


def _orient() -> click.Command:
    from imud.cli.orient import orient

    return orient


class _Commands(click.Group):
    """The subcommands, the heavy ones (NumPy, the calibration code) loaded only when they run
    or show their help: `imud status` imports no more than it uses."""

    lazy: ClassVar[dict[str, Callable[[], click.Command]]] = {
        "calibrate": _calibrate,
        "record": _record,
        "replay": _replay,
        "export": _export,
        "view": _view,
        "plot": _plot,
        "noise": _noise,
        "orient": _orient,
    }

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted([*super().list_commands(ctx), *self.lazy])

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        load = self.lazy.get(name)
        return load() if load is not None else super().get_command(ctx, name)


@click.group(cls=_Commands, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="imud")
def main() -> None:
    """imud: IMU acquisition daemon publishing over Eclipse Zenoh."""


# --- run -----------------------------------------------------------------------------------------
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
    import logging

    import anyio

    from imud.daemon import Daemon
    from imud.logsetup import setup_logging
    from imud.zerrors import CleanZenohMessages, describe
    from imud.zygote import Zygote

    cfg = _load(config_path)
    setup_logging(log_level)
    for handler in logging.getLogger().handlers:
        handler.addFilter(CleanZenohMessages())
    # forked now, before the daemon starts a thread: its bus processes start in milliseconds
    zygote = Zygote() if cfg.daemon.bus_processes and Zygote.fork_safe() else None
    daemon = Daemon(cfg, config_path=Path(config_path).resolve(), zygote=zygote)
    try:
        code = anyio.run(daemon.run)
    except KeyboardInterrupt:  # before the daemon's own signal handling is in place
        sys.exit(130)
    except Exception as e:  # e.g. the Zenoh listen port is taken: one line, no traceback
        logging.getLogger("imud").debug("the daemon failed", exc_info=True)
        what = "stopped on an error" if daemon.ready else "cannot start"
        click.echo(f"imud: {what}: {describe(e, cfg.zenoh.listen)}", err=True)
        sys.exit(1)
    sys.exit(code)


# --- check-config, config-schema ---------------------------------------------------------------
@main.command("check-config")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="print the full resolved config as JSON")
def check_config(file: str, as_json: bool) -> None:
    """Validate FILE: a short summary (or the full config with --json), exit 0; or the errors,
    one line each, exit 2."""
    cfg = _load(file)
    from imud.zerrors import ZenohSetupError
    from imud.zsession import daemon_config

    try:  # `options` are Zenoh's to judge: build the session config as the daemon will
        daemon_config(cfg.zenoh)
    except ZenohSetupError as e:
        click.echo(f"{file}: invalid config:\n  {e}", err=True)
        sys.exit(EXIT_USAGE)
    from imud.calib.watch import calibration_problems

    problems, notes = calibration_problems(cfg)
    if problems:  # the daemon would run these devices uncalibrated: say so, and fail the check
        click.echo(f"{file}: invalid config:\n  " + "\n  ".join(problems), err=True)
        sys.exit(EXIT_USAGE)
    for note in notes:  # not yet calibrated: the daemon runs it uncalibrated until the file exists
        click.echo(f"note: {note}", err=True)
    if as_json:
        click.echo(json.dumps(cfg.model_dump(mode="json"), indent=2))
        return
    for line in config_summary(cfg, file):
        click.echo(line)


@main.command("config-schema")
def config_schema() -> None:
    """Print the config file's JSON Schema."""
    from imud.config import config_model

    click.echo(json.dumps(config_model().model_json_schema(), indent=2))


# --- status --------------------------------------------------------------------------------------
@main.command()
@_connect
@_prefix
@click.option("--json", "as_json", is_flag=True, help="print the daemon's JSON answer")
@click.option("--timeout", default=2.0, show_default=True, help="seconds to wait for an answer")
@click.option("--watch", is_flag=True, help="refresh until Ctrl-C")
@click.option(
    "--interval",
    default=1.0,
    show_default=True,
    type=click.FloatRange(min=0.1),
    help="seconds between refreshes with --watch",
)
def status(
    endpoint: str, prefix: str, as_json: bool, timeout: float, watch: bool, interval: float
) -> None:
    """Show the daemon's devices and their health (exit 1 when no daemon answers)."""
    from rich.console import Console

    console = Console(highlight=False, soft_wrap=False)
    with _session(endpoint, as_json) as s:
        if not watch:
            st = _ask_status(s, endpoint, prefix, timeout, as_json)
            if as_json:
                click.echo(json.dumps(st, indent=2))
            else:
                for r in status_view(st, endpoint, console):
                    console.print(r)
            return
        # Ctrl-C (SIGINT) is how --watch ends, also when a shell that started it in the
        # background left SIGINT ignored (a non-interactive `cmd &`, nohup): as `imud record`
        signal.signal(signal.SIGINT, signal.default_int_handler)
        with contextlib.suppress(KeyboardInterrupt):
            _watch(s, endpoint, prefix, timeout, interval, as_json, console)


def _watch(
    s: Any,
    endpoint: str,
    prefix: str,
    timeout: float,
    interval: float,
    as_json: bool,
    console: Console,
) -> None:
    """Refresh every `interval` s: in place on a terminal (rich Live); elsewhere (a pipe, a log
    file) one full view after another, so each refresh stays readable. A daemon that goes away
    is shown as such and asked again; it does not end the watch."""
    from rich.console import Group
    from rich.live import Live
    from rich.text import Text

    from imud.session import NoDaemon, get_status

    def frames() -> Iterator[tuple[dict[str, Any] | None, str | None]]:
        while True:
            t0 = time.monotonic()
            try:
                yield get_status(s, prefix, timeout=timeout), None
            except NoDaemon as e:
                yield None, _no_answer(endpoint, prefix, e) + f"; asking again every {interval:g} s"
            time.sleep(max(0.0, interval - (time.monotonic() - t0)))

    live = console.is_terminal and not console.is_dumb_terminal and not as_json
    if not live:
        for st, err in frames():
            if as_json:
                click.echo(json.dumps(st if st is not None else {"error": err}))
            elif st is None:
                console.print(cut(Text(f"imud: {err}"), console.width))
            else:
                for r in status_view(st, endpoint, console):
                    console.print(r)
                console.print()
            sys.stdout.flush()
        return
    with Live(console=console, auto_refresh=False) as view:
        for st, err in frames():
            body: RenderableType
            if st is None:
                body = cut(Text(f"imud: {err}", style="red"), console.width)
            else:
                body = Group(*status_view(st, endpoint, console))
            view.update(body, refresh=True)


# --- echo ----------------------------------------------------------------------------------------
@main.command()
@click.argument("device")
@_connect
@_prefix
@click.option("--count", type=click.IntRange(min=1), help="stop after N samples (N summaries)")
@click.option("--json", "as_json", is_flag=True, help="one JSON object per sample (per summary)")
@click.option("--summary", is_flag=True, help="once a second: rate, lost, channel means")
@click.option("--truth", is_flag=True, help="the simulator's ground truth instead of the samples")
@click.option(
    "--timeout",
    default=ECHO_STATUS_TIMEOUT_S,
    show_default=True,
    help="seconds to wait for the daemon's status (asked first, to check DEVICE)",
)
def echo(
    device: str,
    endpoint: str,
    prefix: str,
    count: int | None,
    as_json: bool,
    summary: bool,
    truth: bool,
    timeout: float,
) -> None:
    """Print DEVICE's decoded samples as they arrive (Ctrl-C stops)."""
    import zenoh

    from imud.client import data_key

    with _session(endpoint, as_json) as s:
        st = _ask_status(s, endpoint, prefix, timeout, as_json)
        dev = _device(st, device, endpoint, truth, as_json)
        if dev["state"] != DeviceState.RUNNING and not as_json:
            click.echo(
                f"imud: {device} is in state {dev['state']}"
                + (f": {dev['last_error']}" if dev.get("last_error") else "")
                + "; waiting for samples (Ctrl-C to stop)",
                err=True,
            )
        sub = s.declare_subscriber(
            data_key(device, prefix, truth), zenoh.handlers.FifoChannel(16384)
        )
        try:
            out: Samples | Summary = (
                Summary(device, truth, as_json) if summary else Samples(truth, as_json, count)
            )
            for b in arrivals(sub, 0.05):
                if out.feed(b, time.monotonic()) and count is not None and out.printed >= count:
                    break
        except KeyboardInterrupt:
            pass
        except BrokenPipeError:  # `imud echo ... | head`: stop quietly, as `cat` would
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        finally:
            sub.undeclare()


if __name__ == "__main__":  # pragma: no cover
    main()
