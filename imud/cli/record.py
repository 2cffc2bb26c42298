"""`imud record`: a running daemon's streams into a file.

`imud record [DEVICE ...] -o FILE.mcap [--duration S] [--split-size MB | --split-duration S]`:
every device (or those named) into MCAP (imud/recording): the native batches, lossless, the
ROS 2 messages the daemon's output makes of them, /diagnostics, the config and calibration files;
a progress line while it runs, a summary at the end. Ctrl-C (or SIGTERM) ends it cleanly.

`imud record DEVICE --csv FILE --duration S [--raw]`: one device into a CSV recording
(docs/recording-csv.md) that every offline `imud calibrate` command reads. Samples are written
as they arrive; the file appears complete under its name at the end (a crash leaves
`FILE.partial`). Samples a chip marked invalid cannot be written (the format has no NaN): they
are left out and counted, as are samples lost on the way.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import click
import numpy as np

from imud.cli.common import (
    EXIT_USAGE,
    _ask_status,
    _connect,
    _device,
    _fail,
    _lean_runtime,
    _new_file,
    _prefix,
    _session,
)


@click.command()
@click.argument("devices", nargs=-1)
@click.option(
    "-o", "--output", "mcap_path", type=click.Path(dir_okay=False), help="the MCAP file to write"
)
@click.option(
    "--csv", "csv_path", type=click.Path(dir_okay=False), help="one device into a CSV recording"
)
@click.option(
    "--raw",
    is_flag=True,
    help="the uncorrected stream (what calibration needs): --csv writes it alone, -o beside "
    "the corrected one",
)
@click.option("--duration", type=click.FloatRange(min=0.1), help="seconds (default: until Ctrl-C)")
@click.option(
    "--split-size",
    type=click.FloatRange(min=1.0),
    help="start a new file (NAME_001.mcap, ...) every this many MB",
)
@click.option(
    "--split-duration", type=click.FloatRange(min=1.0), help="start a new file every this many s"
)
@click.option(
    "--recover",
    "broken",
    type=click.Path(dir_okay=False, exists=True),
    help="salvage every complete message of an MCAP file whose recorder died into a new, "
    "indexed file (-o, default BROKEN-recovered.mcap)",
)
@_connect
@_prefix
def record(
    devices: tuple[str, ...],
    mcap_path: str | None,
    csv_path: str | None,
    raw: bool,
    duration: float | None,
    split_size: float | None,
    split_duration: float | None,
    broken: str | None,
    endpoint: str,
    prefix: str,
) -> None:
    """Record a running daemon's devices (all, or DEVICES) to MCAP (-o FILE.mcap), or one
    device to a CSV recording (--csv FILE)."""
    if broken is not None:
        if devices or csv_path is not None or duration is not None:
            _fail("--recover takes the broken file alone (and -o for where it goes)", 2)
        _recover(Path(broken), None if mcap_path is None else Path(mcap_path))
        return
    if (mcap_path is None) == (csv_path is None):
        _fail("give -o FILE.mcap (every device, or those named) or --csv FILE (one device)", 2)
    if csv_path is not None:
        if len(devices) != 1 or duration is None:
            _fail(
                "--csv records one device for a --duration: "
                "imud record DEVICE --csv FILE --duration S",
                2,
            )
        if split_size is not None or split_duration is not None:
            _fail("--split-size/--split-duration split MCAP files (-o), not a CSV", 2)
        _record_csv(devices[0], Path(csv_path), raw, duration, endpoint, prefix)
        return
    if split_size is not None and split_duration is not None:
        _fail("give --split-size or --split-duration, not both", 2)
    assert mcap_path is not None
    _record_mcap(
        list(devices), Path(mcap_path), duration, split_size, split_duration, endpoint, prefix,
        raw,
    )  # fmt: skip


def _record_mcap(
    names: list[str],
    out: Path,
    duration: float | None,
    split_mb: float | None,
    split_s: float | None,
    endpoint: str,
    prefix: str,
    raw: bool = False,
) -> None:
    from imud.recording.mcapfile import McapOut
    from imud.recording.recorder import Recorder, attachments
    from imud.session import NoDaemon, get_config, get_status

    if out.suffix != ".mcap":
        _fail(f"-o {out}: name the file .mcap (what Foxglove and ros2 bag look for)", EXIT_USAGE)
    if not out.parent.is_dir():
        _fail(f"-o {out}: directory {out.parent} does not exist", EXIT_USAGE)
    if out.exists():
        _fail(f"-o {out}: exists; choose another name (nothing recorded is overwritten)", 2)
    if split_mb is not None or split_s is not None:
        taken = sorted(out.parent.glob(f"{out.stem}_[0-9][0-9][0-9]{out.suffix}"))
        if taken:
            parts = f"{out.stem}_000{out.suffix}, {out.stem}_001{out.suffix}, ..."
            there = ", ".join(p.name for p in taken[:3])
            _fail(f"-o {out}: split, its parts are {parts}, and {there} exist already; "
                  "choose another name", 2)  # fmt: skip
    if not os.access(out.parent, os.W_OK):
        _fail(f"-o {out}: cannot write in {out.parent}: choose a directory that is yours", 2)
    _lean_runtime()  # every stream subscribed; signals only set a flag
    with _session(endpoint) as s:
        st = _ask_status(s, endpoint, prefix, 2.0)
        for n in names:
            _device(st, n, endpoint, False, False)
        names = names or [d["name"] for d in st.get("devices", [])]
        if not names:
            _fail(f"the daemon at {endpoint} runs no devices: nothing to record", EXIT_USAGE)
        try:
            view: dict[str, Any] | None = get_config(s, prefix, timeout=2.0)
        except NoDaemon:  # an older daemon: the native batches, without ROS 2 messages
            view = None
        meta = {
            "imud": {"devices": ",".join(names), "endpoint": endpoint, "prefix": prefix},
            # each device as the daemon described it when the recording began (what replay
            # answers status queries with): chip, channels, rate, bus
            "imud.devices": {
                d["name"]: json.dumps(d) for d in st.get("devices", []) if d["name"] in names
            },
        }
        mcap = McapOut(
            out,
            attachments(view),
            meta,
            split_bytes=None if split_mb is None else int(split_mb * 1e6),
            split_s=split_s,
            # a backstop: the loop below flushes every second, before its progress line (two
            # timers would close a chunk, and fsync, twice a second)
            flush_s=2.0,
        )
        rec = Recorder(s, prefix, names, view, mcap, raw=raw)
        if rec.ros2_error:
            click.echo(f"imud: {rec.ros2_error}", err=True)
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
        rec.start()
        start = time.monotonic()
        end = None if duration is None else start + duration
        next_status = start + 1.0  # a flush point and a progress line, at least 1 s apart
        tty = sys.stderr.isatty()
        failed: OSError | None = None
        silent_since: float | None = None  # the daemon stopped answering status at
        try:
            while not stop.is_set() and (end is None or time.monotonic() < end):
                rec.drain(0.2)
                now = time.monotonic()
                if now >= next_status:
                    next_status = now + 1.0
                    rec.flush()  # what the line counts is on disk: a crash loses what follows
                    try:
                        devs = get_status(s, prefix, timeout=0.5).get("devices", [])
                        rec.status([d for d in devs if d.get("name") in names], time.time_ns())
                        silent_since = None
                    except NoDaemon:  # restarting, or gone: the recording goes on when it is back
                        silent_since = silent_since or now
                    silent = None if silent_since is None else now - silent_since
                    _progress(rec, now - start, tty, silent)
        except OSError as e:  # the disk is full, or went away: what was flushed is there
            failed = e
        finally:
            try:
                rec.stop()
            except OSError as e:  # closing needs the disk too
                failed = failed or e
    if failed is not None:
        _fail(_write_failure(failed, rec.out.paths, out, time.monotonic() - start), 1)
    _summary(rec, time.monotonic() - start, tty)


def _write_failure(e: OSError, paths: list[Path], out: Path, elapsed: float) -> str:
    """What a failed write means for the files: one that could not be made holds nothing; one
    cut off mid-way holds what was flushed."""
    cut = [p for p in paths if p.exists() and p.stat().st_size > 0]
    why = e.strerror or str(e)
    if e.filename is not None and not Path(e.filename).exists():
        return f"cannot create {e.filename}: {why}; the recording stopped after {elapsed:.1f} s"
    last = cut[-1] if cut else out
    return (
        f"writing {last} failed after {elapsed:.1f} s: {why} (a full disk?); the recording "
        f"stopped, and what was flushed before is in the file: `imud record --recover {last}` "
        "indexes it"
    )


def _recover(broken: Path, out: Path | None) -> None:
    from imud.recording.recover import RecoverError, recover

    out = out or broken.with_name(f"{broken.stem}-recovered.mcap")
    if out.suffix != ".mcap":
        _fail(f"-o {out}: the recovered file is MCAP: name it .mcap", EXIT_USAGE)
    if out.exists():
        _fail(f"{out} exists; give -o for where the recovered file goes", EXIT_USAGE)
    try:
        r = recover(broken, out)
    except RecoverError as e:
        _fail(str(e), EXIT_USAGE)
    except OSError as e:
        out.unlink(missing_ok=True)
        _fail(f"cannot write {out}: {e.strerror}", 1)
    state = (
        "it was complete"
        if r.complete
        else "it ended without its summary (its recorder stopped before closing it)"
        if r.stopped_at.startswith("EndOfFile")
        else f"it ended in a damaged record ({r.stopped_at})"
    )
    click.echo(f"{out}: {r.messages:,} messages, {r.attachments} attachments from {broken}")
    click.echo(f"  {state}")
    for topic, n in sorted(r.per_topic.items()):
        click.echo(f"  {topic}: {n:,}")


def _progress(rec: Any, elapsed: float, tty: bool, silent_s: float | None = None) -> None:
    c = rec.counts.values()
    samples = sum(x.samples for x in c)
    line = (
        f"{elapsed:6.0f} s  {len(rec.devices)} device(s)  {samples:,} samples  "
        f"{sum(x.lost for x in c):,} lost  {sum(x.dropped for x in c):,} dropped  "
        f"{rec.out.bytes_written() / 1e6:.1f} MB  {samples / max(elapsed, 1e-9):,.0f} samples/s"
    )
    if silent_s is not None:  # said, so a frozen count is not taken for a frozen recorder
        line += f"  (no answer from the daemon for {silent_s:.0f} s)"
    click.echo(("\r" + line) if tty else line, err=True, nl=not tty)


def _summary(rec: Any, elapsed: float, tty: bool) -> None:
    if tty:
        click.echo("", err=True)
    paths = rec.out.paths
    if not paths:
        _fail(f"nothing arrived from {', '.join(rec.devices)} in {elapsed:.1f} s", 1)
    size = sum(p.stat().st_size for p in paths)
    click.echo(f"{', '.join(str(p) for p in paths)}: {size / 1e6:.1f} MB, {elapsed:.1f} s")
    for name, c in rec.counts.items():
        extra = (
            f", {c.dropped:,} samples dropped by the recorder (disk too slow)" if c.dropped else ""
        )
        click.echo(f"  {name}: {c.samples:,} samples, {c.lost:,} lost by the daemon{extra}")


def _record_csv(
    device: str, out: Path, raw: bool, duration: float, endpoint: str, prefix: str
) -> None:
    import imud.client as ic
    from imud.calib.csvio import CsvWriter
    from imud.calib.file import now_iso
    from imud.channels import INVALID_MASK, Channel

    _new_file(out, "--csv")
    with _session(endpoint) as s:
        dev = _device(_ask_status(s, endpoint, prefix, 2.0), device, endpoint, False, False)
        chans = set(dev.get("channels", []))
        if not {"accel", "gyro"} <= chans:
            _fail(
                f"{device} does not publish accel and gyro ({', '.join(sorted(chans))})", EXIT_USAGE
            )
        has_temp, has_mag = "temperature_c" in chans, "mag" in chans
        comments = {
            "device": device,
            "chip": dev["chip"],
            "samples": "raw (uncorrected)" if raw else "corrected",
            "recorded": now_iso(),
            "rate_hz": f"{dev.get('odr_hz')}",
        }
        rows = invalid = lost = 0
        with CsvWriter(
            out, has_temp=has_temp, has_mag=has_mag, has_flags=True, comments=comments
        ) as w:
            end = time.monotonic() + duration
            for b in ic.batches(s, device, prefix, raw=raw, timeout=5.0):
                lost += int(b.lost_before) if rows else 0
                ok = (b.sample_flags & np.uint32(INVALID_MASK)) == 0
                invalid += int(np.count_nonzero(~ok))
                if ok.any():
                    t = b.get(Channel.TEMPERATURE)
                    m = b.get(Channel.MAG)
                    acc, gyr = b.accel, b.gyro
                    assert acc is not None and gyr is not None
                    w.write(
                        b.t_ns[ok],
                        acc[ok],
                        gyr[ok],
                        None if t is None else t[ok],
                        None if m is None else m[ok],
                        b.sample_flags[ok],
                    )
                    rows += int(np.count_nonzero(ok))
                if time.monotonic() >= end:
                    break
    if rows == 0:
        out.unlink(missing_ok=True)
        _fail(f"no samples arrived from {device} within {duration:g} s", 1)
    extra = [f"{n} {what}" for n, what in ((invalid, "invalid (left out)"), (lost, "lost")) if n]
    click.echo(f"{out}: {rows} samples of {device}" + (f"; {', '.join(extra)}" if extra else ""))
