"""`imud record DEVICE --csv FILE --duration S [--raw]`: the live stream into a CSV recording
(docs/recording-csv.md) that every offline `imud calibrate` command reads.

Samples are written as they arrive (nothing is held in memory); the file appears complete under
its name at the end (a crash leaves `FILE.partial`). Samples a chip marked invalid cannot be
written (the format has no NaN): they are left out and counted, as are samples lost on the way.
"""

from __future__ import annotations

import time
from pathlib import Path

import click
import numpy as np

from imud.cli.common import EXIT_USAGE, _ask_status, _connect, _device, _fail, _prefix, _session


@click.command()
@click.argument("device")
@click.option(
    "--csv", "csv_path", required=True, type=click.Path(dir_okay=False), help="the file to write"
)
@click.option("--raw", is_flag=True, help="the uncorrected stream (what calibration needs)")
@click.option("--duration", required=True, type=click.FloatRange(min=0.1), help="seconds")
@_connect
@_prefix
def record(
    device: str, csv_path: str, raw: bool, duration: float, endpoint: str, prefix: str
) -> None:
    """Write DEVICE's samples (corrected, or --raw) for --duration seconds to a CSV file."""
    import imud.client as ic
    from imud.calib.csvio import CsvWriter
    from imud.calib.file import now_iso
    from imud.channels import INVALID_MASK, Channel

    out = Path(csv_path)
    if not out.parent.is_dir():
        _fail(f"--csv {out}: directory {out.parent} does not exist", EXIT_USAGE)
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
