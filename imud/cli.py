"""The `imud` command: run the daemon, ask it how it is doing, watch its data, check configs.

Exit codes: 0 done, 1 no daemon (or the daemon failed to start), 2 usage or config errors (a
malformed `--connect`, an unknown device, truth asked of a device that does not publish it).
"""

from __future__ import annotations

import contextlib
import difflib
import json
import math
import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Any, NoReturn

import click

from imud.config import DEFAULT_ENDPOINT
from imud.errors import ConfigError
from imud.status import DeviceState
from imud.zerrors import endpoint_problem

if TYPE_CHECKING:
    from rich.console import Console, RenderableType
    from rich.table import Table
    from rich.text import Text

    from imud.channels import Channel
    from imud.config import ImudConfig
    from imud.wire import Batch

EXIT_NO_DAEMON = 1
EXIT_USAGE = 2
ECHO_STATUS_TIMEOUT_S = 1.0  # echo's status question: a wrong name must fail within 2 s


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


def _load(path: str) -> ImudConfig:
    from imud.config import load_config

    try:
        return load_config(path)
    except ConfigError as e:
        click.echo(f"{path}: invalid config:", err=True)
        for m in e.messages:
            click.echo(f"  {m}", err=True)
        sys.exit(EXIT_USAGE)


def _fail(message: str, code: int, as_json: bool = False) -> NoReturn:
    """Stop with `message`: on stderr, or as `{"error": ...}` on stdout for --json callers (a
    script reading JSON gets JSON, whatever happened)."""
    if as_json:
        click.echo(json.dumps({"error": message}))
    else:
        click.echo(f"imud: {message}", err=True)
    sys.exit(code)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
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

    cfg = _load(config_path)
    setup_logging(log_level)
    for handler in logging.getLogger().handlers:
        handler.addFilter(CleanZenohMessages())
    daemon = Daemon(cfg)
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
    if as_json:
        click.echo(json.dumps(cfg.model_dump(mode="json"), indent=2))
        return
    for line in config_summary(cfg, file):
        click.echo(line)


def config_summary(cfg: ImudConfig, path: str) -> list[str]:
    """What a config asks for, for a human: one line per device, one for the daemon, one for
    Zenoh. Addresses in hex, as datasheets and i2cdetect write them."""
    from imud.buses.models import describe

    n = len(cfg.device)
    d, z = cfg.daemon, cfg.zenoh
    rt = f"realtime priority {d.realtime_priority}" if d.realtime_priority else "no realtime"
    lines = [
        f"{path}: valid, {n} device{'s' if n != 1 else ''}",
        f"daemon: {'one process per bus' if d.bus_processes else 'bus threads'}, {rt}",
        f"zenoh: {z.mode}, listen {', '.join(z.listen) or 'nowhere'}, "
        f"connect {', '.join(z.connect) or 'none'}, prefix {z.prefix!r}, "
        f"shared memory {'on' if z.shared_memory else 'off'}"
        + (
            ", options " + ", ".join(f"{k}={v!r}" for k, v in z.options.items())
            if z.options
            else ""
        ),
    ]
    rows = []
    for dev in cfg.device:
        ranges = []
        fields = dev.model_dump()  # the range fields have the same names for every chip
        gyro, accel = fields.get("gyro_range_dps"), fields.get("accel_range_g")
        if gyro is not None:
            ranges.append(f"gyro ±{gyro:g} °/s")
        if accel is not None:
            ranges.append(f"accel ±{accel:g} g")
        if dev.sim is not None:
            sim = f"sim ({dev.sim.motion.kind}{', truth on' if dev.sim.truth else ''})"
        else:
            sim = "hardware"
        extra = f", calibration {dev.calibration}" if dev.calibration else ""
        rows.append(
            [
                dev.name,
                dev.chip,
                " + ".join(describe(b) for b in dev.die_buses()),
                f"{dev.odr_hz:g} Hz",
                ", ".join(ranges),
                sim + extra,
            ]
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        lines.append("  " + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    return lines


@main.command("config-schema")
def config_schema() -> None:
    """Print the config file's JSON Schema."""
    from imud.config import config_model

    click.echo(json.dumps(config_model().model_json_schema(), indent=2))


# --- talking to a daemon -------------------------------------------------------------------------
def _session(endpoint: str, as_json: bool = False) -> Any:
    from imud.client import NoDaemon, open_session

    try:
        return open_session(endpoint)
    except NoDaemon as e:
        _fail(f"{e}; is `imud run` running? (--connect to point elsewhere)", 1, as_json)


def _ask_status(
    session: Any, endpoint: str, prefix: str, timeout: float, as_json: bool = False
) -> dict[str, Any]:
    from imud.client import NoDaemon, get_status

    try:
        return get_status(session, prefix, timeout=timeout)
    except NoDaemon as e:
        _fail(_no_answer(endpoint, prefix, e), EXIT_NO_DAEMON, as_json)


def _no_answer(endpoint: str, prefix: str, e: Exception) -> str:
    return (
        f"no daemon answered at {endpoint} ({e}); is `imud run` running there, "
        f"with [zenoh] prefix = {prefix!r}?"
    )


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
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C is how --watch ends
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

    from imud.client import NoDaemon, get_status

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
                console.print(_cut(Text(f"imud: {err}"), console.width))
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
                body = _cut(Text(f"imud: {err}", style="red"), console.width)
            else:
                body = Group(*status_view(st, endpoint, console))
            view.update(body, refresh=True)


def _cut(text: Text, width: int) -> Text:
    """One line, cut with an ellipsis at `width` (rich would wrap it onto the next lines)."""
    text.truncate(width, overflow="ellipsis")
    text.no_wrap = True
    return text


def _ago(seconds: float) -> str:
    s = max(0, int(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min"
    if s < 86400:
        return f"{s // 3600} h {s % 3600 // 60} min"
    return f"{s // 86400} d {s % 86400 // 3600} h"


def _num(v: Any, spec: str = "") -> str:
    return "-" if v is None else format(v, spec)


# (header, status key(s) -> cell, right-aligned). Listed in display order; `_DROP` says which go
# first when the terminal is too narrow. device, state, rate and lost always stay.
_COLUMNS: dict[str, tuple[Any, bool]] = {
    "device": (lambda d: d["name"], False),
    "chip": (lambda d: d["chip"], False),
    "bus": (lambda d: d["bus"], False),
    "state": (lambda d: d["state"], False),
    "odr Hz": (lambda d: _num(d["odr_hz"], "g"), True),
    "rate Hz": (lambda d: _num(d["measured_rate_hz"], ".1f"), True),
    "samples": (lambda d: str(d["samples"]), True),
    "lost": (lambda d: str(d["lost_samples"]), True),
    "overflows": (lambda d: str(d["fifo_overflows"]), True),
    "bus err": (lambda d: str(d["bus_errors"]), True),
    "temp °C": (lambda d: _num(d["temperature_c"], ".1f"), True),
    "calibration": (lambda d: (d["calibration"] or "-").rsplit("/", 1)[-1], False),
}
_DROP = ("calibration", "bus", "odr Hz", "overflows", "chip", "temp °C", "bus err", "samples")
# counters shown below the table when nonzero (and not already a column)
_NOTES = (
    ("lost_samples", "lost", "lost"),
    ("fifo_overflows", "FIFO overflows", "overflows"),
    ("bus_errors", "bus errors", "bus err"),
    ("invalid_samples", "invalid samples", None),
    ("bad_registers", "bad registers", None),
    ("restarts", "restarts", None),
    ("unexpected_errors", "unexpected errors", None),
    ("publish_dropped", "publish drops", None),
)
_STATE_STYLE = {DeviceState.RUNNING: "green", DeviceState.ERROR: "red", DeviceState.STOPPED: "dim"}


def _table(devices: list[dict[str, Any]], columns: Iterable[str]) -> Table:
    from rich import box
    from rich.table import Table

    t = Table(box=box.SIMPLE_HEAD, pad_edge=False, show_edge=False, collapse_padding=True)
    cols = list(columns)
    for c in cols:
        t.add_column(c, no_wrap=True, justify="right" if _COLUMNS[c][1] else "left")
    for d in devices:
        cells = [str(_COLUMNS[c][0](d)) for c in cols]
        if "state" in cols:
            i = cols.index("state")
            cells[i] = f"[{_STATE_STYLE.get(d['state'], 'yellow')}]{cells[i]}[/]"
        t.add_row(*cells)
    return t


def status_view(st: dict[str, Any], endpoint: str, console: Console) -> list[RenderableType]:
    """The status as a headline, a table that fits the console's width (whole columns are left
    out, lowest value first, rather than any number folded), and one line per device or bus
    with something to say (its last error and how long ago, counters not in the table), cut at
    the width: the full text is in --json."""
    from rich.text import Text

    width = console.width
    devices = st.get("devices", [])
    running = sum(d["state"] == DeviceState.RUNNING for d in devices)
    head = (
        f"imud {st.get('version', '?')} at {endpoint}, up {_ago(st.get('uptime_s', 0))}: "
        f"{running}/{len(devices)} devices running"
        + ("" if st.get("ready", True) else ", starting")
    )
    cols = list(_COLUMNS)
    table = _table(devices, cols)
    unbounded = console.options.update_width(100_000)  # measure() is clamped to the width
    for drop in _DROP:
        if console.measure(table, options=unbounded).maximum <= width:
            break
        cols.remove(drop)
        table = _table(devices, cols)
    out: list[RenderableType] = [_cut(Text(head), width), table]
    now = time.time()
    for d in devices:
        parts = [f"{d[k]} {label}" for k, label, col in _NOTES if d.get(k) and col not in cols]
        line = ", ".join(parts)
        if d.get("last_error"):
            at = d.get("last_error_at")
            when = f" {_ago(now - at)} ago" if isinstance(at, int | float) else ""
            line += ("; " if line else "") + f"last error{when}: {d['last_error']}"
        if line:
            text = Text(f"{d['name']}: ", style="bold")
            text.append(line, style="red" if d["state"] == DeviceState.ERROR else "")
            out.append(_cut(text, width))
    for b in st.get("buses", []):
        if b.get("restarts") or b.get("last_error"):
            line = f"bus {b['bus']}: process restarted {b.get('restarts', 0)} times"
            if b.get("last_error"):
                line += f"; last error: {b['last_error']}"
            out.append(_cut(Text(line), width))
    return out


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
            out: _Samples | _Summary = (
                _Summary(device, truth, as_json) if summary else _Samples(truth, as_json, count)
            )
            for b in _arrivals(sub, 0.05):
                if out.feed(b, time.monotonic()) and count is not None and out.printed >= count:
                    break
        except KeyboardInterrupt:
            pass
        except BrokenPipeError:  # `imud echo ... | head`: stop quietly, as `cat` would
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        finally:
            sub.undeclare()


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


def _arrivals(sub: Any, idle_s: float) -> Iterator[Batch | None]:
    """Decoded batches as they arrive, and None after each `idle_s` without one (so a summary
    window closes on time when a device stops sending)."""
    from imud.wire import decode

    while True:
        sample = sub.try_recv()
        if sample is not None:
            yield decode(sample.payload.to_bytes())
            continue
        end = time.monotonic() + idle_s
        while sample is None and time.monotonic() < end:
            time.sleep(0.002)
            sample = sub.try_recv()
        yield None if sample is None else decode(sample.payload.to_bytes())


_AXES = {1: "", 3: " x y z", 4: " w x y z"}


def _value_format(unit: str) -> str:
    """How wide and precise one value of a channel in `unit` prints (tesla needs exponents)."""
    return {"T": "+10.3e", "degC": "7.2f", "1": "+7.4f"}.get(unit, "+9.4f")


def _flag_names(flags: int) -> str:
    from imud.channels import SampleFlag

    names = [f.name or "" for f in SampleFlag if flags & f]
    rest = flags & ~sum(SampleFlag)
    return "|".join([*names, *([f"0x{rest:x}"] if rest else [])])


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


class _Samples:
    """One line (or JSON object) per sample, under a header naming the columns and units; truth
    is marked on the header and on every line, so it cannot pass for measurements."""

    def __init__(self, truth: bool, as_json: bool, limit: int | None = None) -> None:
        self.truth, self.as_json, self.limit = truth, as_json, limit
        self.printed = 0
        self.mask: int | None = None
        self.next_seq: int | None = None
        self.widths: dict[Channel, int] = {}

    def feed(self, b: Batch | None, _now: float) -> bool:
        """Print batch `b`; true when a sample was printed (the caller checks --count)."""
        if b is None:
            return False
        lost = 0 if self.next_seq is None else max(0, b.first_seq - self.next_seq)
        self.next_seq = b.first_seq + b.count
        if not self.as_json:
            if self.mask != int(b.mask):
                self._header(b)
            if lost:
                click.echo(f"# lost {lost} samples before seq {b.first_seq}")
        out = []
        for i in range(b.count):
            out.append(
                self._json(b, i, lost if i == 0 else 0) if self.as_json else self._line(b, i)
            )
            self.printed += 1
            if self.limit is not None and self.printed >= self.limit:
                break
        if out:
            click.echo("\n".join(out))
        return bool(out)

    def _header(self, b: Batch) -> None:
        from imud.channels import CHANNELS

        self.mask = int(b.mask)
        # truth lines carry a leading "truth" column; the header names it in capitals
        first = ["#TRUTH", "seq".rjust(10)] if self.truth else ["#" + "seq".rjust(9)]
        cells = [*first, "t [s]".ljust(17)]
        self.widths = {}
        for ch in b.channels:
            info = CHANNELS[ch]
            label = f"{info.key}{_AXES.get(info.width, '')} [{info.unit}]"
            n = len(format(0.0, _value_format(info.unit)))
            self.widths[ch] = max(len(label), info.width * n + info.width - 1, len("invalid"))
            cells.append(label.rjust(self.widths[ch]))
        cells.append("flags")
        if self.truth:
            click.echo(f"# TRUTH: {b.device}'s simulator ground truth, not measured data")
        click.echo("  ".join(cells))

    def _line(self, b: Batch, i: int) -> str:
        from imud.channels import CHANNELS

        t = int(b.t_ns[i])
        cells = ["truth ", f"{b.first_seq + i:>10}"] if self.truth else [f"{b.first_seq + i:>10}"]
        cells.append(f"{t // 1_000_000_000}.{t // 1000 % 1_000_000:06d}".ljust(17))
        flags = int(b.sample_flags[i])
        for ch, arr in b.channels.items():
            w = self.widths.get(ch, 0)
            if flags & int(ch):
                cells.append("invalid".rjust(w))
                continue
            spec = _value_format(CHANNELS[ch].unit)
            v = arr[i]
            text = (
                format(float(v), spec)
                if arr.ndim == 1
                else " ".join(format(float(x), spec) for x in v)
            )
            cells.append(text.rjust(w))
        cells.append(_flag_names(flags) if flags else "")
        return "  ".join(cells).rstrip()

    def _json(self, b: Batch, i: int, lost: int) -> str:
        from imud.channels import CHANNELS

        flags = int(b.sample_flags[i])
        row: dict[str, Any] = {
            "device": b.device,
            "seq": int(b.first_seq + i),
            "t_ns": int(b.t_ns[i]),
            "flags": flags,
        }
        if self.truth:
            row["truth"] = True
        if lost:
            row["lost_before"] = lost
        for ch, arr in b.channels.items():
            v = arr[i]
            if flags & int(ch):
                row[CHANNELS[ch].key] = None
            elif arr.ndim == 1:
                row[CHANNELS[ch].key] = _finite(float(v))
            else:
                row[CHANNELS[ch].key] = [_finite(float(x)) for x in v]
        if flags:
            row["flag_names"] = _flag_names(flags)
        return json.dumps(row)


class _Summary:
    """Once a second: samples/s, lost and invalid samples, and the mean of every channel the
    device carries, with units. The rate comes from the samples' own stamps (the span they
    cover), so delivery jitter does not move it."""

    def __init__(self, device: str, truth: bool, as_json: bool) -> None:
        self.device, self.truth, self.as_json = device, truth, as_json
        self.printed = 0
        self.start: float | None = None
        self.prev_t_ns: int | None = None
        self.next_seq: int | None = None
        self._reset()

    def _reset(self) -> None:
        import numpy as np

        self.n = self.lost = self.invalid = 0
        self.first_t_ns: int | None = None
        self.last_t_ns: int | None = None
        self.sums: dict[Channel, tuple[np.ndarray, np.ndarray]] = {}

    def feed(self, b: Batch | None, now: float) -> bool:
        """Add batch `b` (None: nothing arrived); print the window once it is a second old."""
        import numpy as np

        from imud.channels import INVALID_MASK

        if self.start is None:
            self.start = now
        if b is not None and b.count:
            if self.next_seq is not None:
                self.lost += max(0, b.first_seq - self.next_seq)
            self.next_seq = b.first_seq + b.count
            self.n += b.count
            self.invalid += int(np.count_nonzero(b.sample_flags & INVALID_MASK))
            if self.first_t_ns is None:
                self.first_t_ns = int(b.t_ns[0])
            self.last_t_ns = int(b.t_ns[-1])
            for ch, arr in b.channels.items():
                a = arr.astype(np.float64).reshape(b.count, -1)
                ok = np.isfinite(a)
                s, k = self.sums.get(ch, (np.zeros(a.shape[1]), np.zeros(a.shape[1])))
                self.sums[ch] = (s + np.where(ok, a, 0.0).sum(axis=0), k + ok.sum(axis=0))
        if now - self.start < 1.0:
            return False
        self._print(now - self.start)
        self.printed += 1
        self.start = now
        if self.last_t_ns is not None:
            self.prev_t_ns = self.last_t_ns
        self._reset()
        return True

    def _rate(self) -> float:
        if self.n == 0 or self.last_t_ns is None or self.first_t_ns is None:
            return 0.0
        if self.prev_t_ns is not None and self.last_t_ns > self.prev_t_ns:
            return self.n / ((self.last_t_ns - self.prev_t_ns) / 1e9)
        if self.n > 1 and self.last_t_ns > self.first_t_ns:
            return (self.n - 1) / ((self.last_t_ns - self.first_t_ns) / 1e9)
        return 0.0

    def _print(self, window_s: float) -> None:
        from imud.channels import CHANNELS

        means: dict[str, float | list[float | None] | None] = {}
        units: dict[str, str] = {}
        for ch, (s, k) in self.sums.items():
            info = CHANNELS[ch]
            avg = [float(x) / int(c) if c else None for x, c in zip(s, k, strict=True)]
            means[info.key] = avg[0] if info.width == 1 else avg
            units[info.key] = info.unit
        rate = self._rate()
        if self.as_json:
            row: dict[str, Any] = {"device": self.device}
            if self.truth:
                row["truth"] = True
            row |= {
                "window_s": round(window_s, 3),
                "samples": self.n,
                "rate_hz": round(rate, 3),
                "lost": self.lost,
                "invalid": self.invalid,
                "mean": means,
                "units": units,
            }
            click.echo(json.dumps(row))
            return
        parts = [
            f"{'TRUTH ' if self.truth else ''}{self.device}: {rate:8.1f} samples/s",
            f"lost {self.lost}",
        ]
        if self.invalid:
            parts.append(f"invalid {self.invalid}")
        for key, m in means.items():
            spec = "+.3e" if units[key] == "T" else ("+.3f" if units[key] != "degC" else ".2f")
            vals = m if isinstance(m, list) else [m]
            text = " ".join("-" if v is None else format(v, spec) for v in vals)
            if isinstance(m, list):
                text = f"[{text}]"
            parts.append(f"{key} {text} {units[key]}")
        click.echo("  ".join(parts))


if __name__ == "__main__":  # pragma: no cover
    main()
