"""`imud status`'s table: fits the terminal, whole columns dropped before a number is split;
long text (errors, bus-process restarts) below it, one line per device."""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from imud.errors import BUS_ERROR_KEYS
from imud.status import LABELS, DeviceState

if TYPE_CHECKING:
    from rich.console import Console, RenderableType
    from rich.table import Table
    from rich.text import Text


def cut(text: Text, width: int) -> Text:
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
# counters that are columns of the table: below it only when their column was dropped
_COLUMN_OF = {"lost_samples": "lost", "fifo_overflows": "overflows", "bus_errors": "bus err"}
_KINDS = frozenset(BUS_ERROR_KEYS.values())
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
    out: list[RenderableType] = [cut(Text(head), width)]
    now = time.time()
    if st.get("config_error"):  # a reload refused: the daemon runs the config it had
        at = st.get("config_error_at")
        when = f" {_ago(now - at)} ago" if isinstance(at, int | float) else ""
        out.append(Text(f"config reload failed{when}; running the previous config:", style="red"))
        out.extend(
            cut(Text(f"  {line}", style="red"), width) for line in st["config_error"].splitlines()
        )
    if st.get("restart_needed"):
        out.append(cut(Text(st["restart_needed"], style="yellow"), width))
    out.append(table)
    for d in devices:
        parts = _counters(d, cols)
        line = ", ".join(parts)
        if d.get("calibration_error"):
            line += ("; " if line else "") + f"uncalibrated: {d['calibration_error']}"
        if d.get("last_error"):
            at = d.get("last_error_at")
            when = f" {_ago(now - at)} ago" if isinstance(at, int | float) else ""
            line += ("; " if line else "") + f"last error{when}: {d['last_error']}"
        if line:
            text = Text(f"{d['name']}: ", style="bold")
            text.append(line, style="red" if d["state"] == DeviceState.ERROR else "")
            out.append(cut(text, width))
    for d in devices:
        chip = _chip_line(d.get("chip_status") or {})
        if chip:
            text = Text(f"{d['name']} {d.get('chip', 'chip')}: ", style="bold")
            text.append(chip)
            out.append(cut(text, width))
    for d in devices:
        tracking = d.get("gyro_bias_tracking")
        if tracking:
            text = Text(f"{d['name']} gyro bias tracking: ", style="bold")
            text.append(_tracking_line(tracking))
            out.append(cut(text, width))
        orientation = d.get("orientation")
        if orientation:
            text = Text(f"{d['name']} orientation: ", style="bold")
            text.append(_orientation_line(orientation))
            out.append(cut(text, width))
    ros2 = st.get("ros2")
    if ros2:
        out.append(cut(_ros2_line(ros2), width))
    for b in st.get("buses", []):
        if b.get("restarts") or b.get("last_error"):
            line = f"bus {b['bus']}: process restarted {b.get('restarts', 0)} times"
            if b.get("last_error"):
                line += f"; last error: {b['last_error']}"
            out.append(cut(Text(line), width))
    return out


def _orientation_line(o: dict[str, Any]) -> str:
    """`running, heading relative to the start, bias 0.010 -0.020 0.003 deg/s, gravity 120 used
    3 rejected, still 4`."""
    bias = " ".join(f"{math.degrees(b):.3f}" for b in o.get("bias_rad_s", []))
    line = f"{o.get('state')}, heading {o.get('heading')}, bias {bias} deg/s"
    line += f", gravity {o.get('accel_updates', 0)} used {o.get('accel_rejected', 0)} rejected"
    if o.get("mag_updates") or o.get("mag_rejected"):
        line += f", field {o.get('mag_updates', 0)} used {o.get('mag_rejected', 0)} rejected"
    line += f", still {o.get('still_updates', 0)}"
    if o.get("restarts"):
        line += f", restarted {o['restarts']} times after a long gap"
    return line


def _ros2_line(r: dict[str, Any]) -> Text:
    """`ROS 2 (rmw_zenoh, dds) domain 0, node imud: 7 topics, 12345 messages`, then what went
    wrong: a profile that did not start, messages dropped for a stamp that stepped back."""
    from rich.text import Text

    topics = r.get("topics") or []
    sent = sum((r.get("messages") or {}).values())
    text = Text("ROS 2 ", style="bold")
    text.append(
        f"({', '.join(r.get('profiles') or [])}) domain {r.get('domain_id')}, node "
        f"{r.get('node')}: {len(topics)} topics, {sent} messages"
    )
    dropped = r.get("dropped") or {}
    if dropped:
        each = ", ".join(f"{k} {v}" for k, v in sorted(dropped.items()))
        text.append(f"; not sent, stamp not after the last: {each}", style="yellow")
    if r.get("error"):
        text.append(f"; {r['error']}", style="red")
    return text


def _counters(d: dict[str, Any], cols: list[str]) -> list[str]:
    """The nonzero counters not in the table: the status record's own (by their labels), bus
    errors by kind, then the chip's (`chip_counters`, by their names)."""
    parts = [
        f"{d[k]} {label}"
        for k, label in LABELS.items()
        if d.get(k) and k not in _KINDS and _COLUMN_OF.get(k) not in cols
    ]
    kinds = [f"{LABELS[k]} {d[k]}" for k in sorted(_KINDS) if d.get(k)]
    if kinds:
        parts.append("bus errors by kind: " + ", ".join(kinds))
    chip = (d.get("chip_counters") or {}).items()
    parts.extend(f"{n} {k.replace('_', ' ')}" for k, n in chip if n)
    return parts


def _tracking_line(tr: dict[str, Any]) -> str:
    """The tracker's state and what it holds, in mrad/s (a gyro bias is a few of them)."""
    bias = ", ".join(f"{1e3 * b:+.2f}" for b in tr.get("bias_rad_s", ()))
    return (
        f"{tr.get('state', '?')}, ({bias}) mrad/s, "
        f"{tr.get('learned_windows', 0)}/{tr.get('windows', 0)} windows learned"
    )


def _chip_line(cs: dict[str, Any]) -> str:
    """A chip's own health (its driver's `chip_status`) on one line: every key with something
    to say, nested tables as key=value; nothing for zeros and empties."""

    def show(v: Any) -> str:
        if isinstance(v, dict):
            return " ".join(f"{k}={show(x)}" for k, x in v.items())
        if isinstance(v, list | tuple):
            return ",".join(show(x) for x in v)
        if isinstance(v, float):
            return f"{v:.6g}"
        return str(v)

    return ", ".join(
        f"{k.replace('_', ' ')} {show(v)}" for k, v in cs.items() if v not in (0, None, "", [], {})
    )
