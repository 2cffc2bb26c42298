"""What the `imud` subcommands share: the --connect/--prefix options, exit codes, failing with a
message (or JSON), and asking a daemon for its status and one of its devices."""

from __future__ import annotations

import difflib
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import click

from imud.errors import ConfigError
from imud.zerrors import DEFAULT_ENDPOINT, endpoint_problem

if TYPE_CHECKING:
    from imud.config import ImudConfig

EXIT_NO_DAEMON = 1
EXIT_USAGE = 2


def _check_endpoint(_ctx: click.Context, _param: click.Parameter, value: str) -> str:
    """A malformed endpoint is a usage error naming the value and the expected form; left to
    Zenoh it would read as "no daemon reachable"."""
    problem = endpoint_problem(value)
    if problem:
        raise click.BadParameter(problem)
    return value


_connect = click.option(
    "--connect",
    "endpoint",
    default=DEFAULT_ENDPOINT,
    show_default=True,
    callback=_check_endpoint,
    help="Zenoh endpoint of the daemon, PROTOCOL/HOST:PORT",
)
_prefix = click.option("--prefix", default="imud", show_default=True, help="key prefix")


def _named(rec: Any) -> str:
    """A recording as messages name it: its file, or a split one's first and last part."""
    if len(rec.parts) > 1:
        first, last = rec.parts[0][0], rec.parts[-1][0]
        return f"{first} ... {last.name} ({len(rec.parts)} parts)"
    return str(rec.path)


def _recorded_device(rec: Any, name: str | None, as_json: bool = False) -> str:
    """The device of a recording a command works on: `name`, or the only one it holds; a name
    it does not hold, or none of several, is a usage error naming what it holds."""
    held = ", ".join(sorted(rec.devices))
    if name is None:
        if len(rec.devices) != 1:
            _fail(f"{_named(rec)} holds {held}: give --device NAME", EXIT_USAGE, as_json)
        return str(next(iter(rec.devices)))
    if name not in rec.devices:
        _fail(f"{_named(rec)} has no device {name!r} (it holds {held})", EXIT_USAGE, as_json)
    return name


def _new_file(path: Path, option: str, as_json: bool = False) -> None:
    """An output file the command will create: its directory there, no file of that name (what
    is already on disk, a recording most of all, is never overwritten)."""
    if not path.parent.is_dir():
        _fail(f"{option} {path}: directory {path.parent} does not exist", EXIT_USAGE, as_json)
    if path.exists():
        _fail(
            f"{option} {path}: exists; choose another name (nothing is overwritten)",
            EXIT_USAGE,
            as_json,
        )


def _fail(message: str, code: int, as_json: bool = False) -> NoReturn:
    """Stop with `message`: on stderr, or as `{"error": ...}` on stdout for --json callers (a
    script reading JSON gets JSON, whatever happened)."""
    if as_json:
        click.echo(json.dumps({"error": message}))
    else:
        click.echo(f"imud: {message}", err=True)
    sys.exit(code)


# --- talking to a daemon -------------------------------------------------------------------------
# Zenoh's receive tasks on the thread that polls its sockets, not handed to two more threads:
# what a subscriber of every stream pays per message halves (docs/performance.md §16). Only for
# the commands that subscribe to every stream and end on a flag, not on KeyboardInterrupt
# (record, view): a Ctrl-C that interrupts a pending query then took seconds to end the
# process (measured with `status --watch` against a stopped daemon: 5.9 s, against 0.1 s).
LEAN_RUNTIME = "(rx: (handover: app))"


def _lean_runtime() -> None:
    """LEAN_RUNTIME for this process, unless the user set a ZENOH_RUNTIME of their own: before
    its first session, which is when Zenoh reads it."""
    os.environ.setdefault("ZENOH_RUNTIME", LEAN_RUNTIME)


def _session(endpoint: str, as_json: bool = False) -> Any:
    from imud.session import NoDaemon, open_session

    try:
        return open_session(endpoint)
    except NoDaemon as e:
        _fail(f"{e}; is `imud run` running? (--connect to point elsewhere)", 1, as_json)


def _ask_status(
    session: Any, endpoint: str, prefix: str, timeout: float, as_json: bool = False
) -> dict[str, Any]:
    from imud.session import NoDaemon, get_status

    try:
        return get_status(session, prefix, timeout=timeout)
    except NoDaemon as e:
        _fail(_no_answer(endpoint, prefix, e), EXIT_NO_DAEMON, as_json)


def _no_answer(endpoint: str, prefix: str, e: Exception) -> str:
    return (
        f"no daemon answered at {endpoint} ({e}); is `imud run` running there, "
        f"with [zenoh] prefix = {prefix!r}?"
    )


def _device(
    st: dict[str, Any], device: str, endpoint: str, truth: bool, as_json: bool
) -> dict[str, Any]:
    """DEVICE's entry in the daemon's status; a wrong name or truth that is not published is a
    usage error now, rather than a subscription that never receives anything."""
    by = {d["name"]: d for d in st.get("devices", [])}
    if device not in by:
        close = difflib.get_close_matches(device, list(by), n=1, cutoff=0.5)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        _fail(
            f"no device {device!r} on the daemon at {endpoint}{hint} "
            f"(its devices: {', '.join(by) or 'none'})",
            EXIT_USAGE,
            as_json,
        )
    dev = by[device]
    if truth and not dev.get("truth", False):
        if str(dev.get("bus", "")).startswith("sim-"):
            why = (
                f"{device} does not publish simulator truth (truth is off): set `truth = true` "
                "in its [device.sim] table and restart the daemon"
            )
        else:
            why = f"{device} is real hardware ({dev.get('bus')}): only simulated devices have truth"
        _fail(why, EXIT_USAGE, as_json)
    found: dict[str, Any] = dev
    return found


def _load(path: str) -> ImudConfig:
    """The config through `load_config`, or its errors, one per line, and exit 2."""
    from imud.config import load_config

    try:
        return load_config(path)
    except ConfigError as e:
        click.echo(f"{path}: invalid config:", err=True)
        for m in e.messages:
            click.echo(f"  {m}", err=True)
        sys.exit(EXIT_USAGE)
