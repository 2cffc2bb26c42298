"""`imud noise FILE.mcap|FILE.csv [--device NAME]`: the overlapping Allan deviation of a device's
gyro and accelerometer (imud/noise/allan.py), streamed from the file: a recording's batches one
at a time, a CSV's rows as read. Gaps (lost samples, a stamp jump, a row without the sensor)
split the samples into stretches; no Allan term spans one."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import click
import numpy as np

from imud.cli.common import EXIT_USAGE, _fail, _recorded_device

F64 = Any


@click.command()
@click.argument("path", type=click.Path(dir_okay=False))
@click.option("--device", help="the device (needed when the recording holds more than one)")
@click.option("--per-decade", type=click.IntRange(2, 50), default=8, show_default=True,
              help="tau values per decade")  # fmt: skip
@click.option("--json", "as_json", is_flag=True, help="print JSON")
def noise(path: str, device: str | None, per_decade: int, as_json: bool) -> None:
    """The Allan deviation of a recording's gyro and accelerometer."""
    from imud.noise.allan import StreamingAllan, lags

    src = Path(path)
    rate, n, chunks = _mcap(src, device, as_json) if _is_mcap(src) else _csv(src, as_json)
    if n < 3:
        _fail(f"{path}: {n} samples: the Allan deviation needs at least 3", EXIT_USAGE, as_json)
    acc = StreamingAllan(rate, 6, lags(n, per_decade))
    for y in chunks:
        if y is None:
            acc.gap()
        else:
            acc.feed(y)
    r = acc.result()
    if not r.tau_s.size:
        _fail(f"{path}: no stretch without a gap is long enough for one tau", EXIT_USAGE, as_json)
    if as_json:
        click.echo(json.dumps({
            "source": path, "rate_hz": rate, "samples": r.n, "stretches": acc.stretches,
            "tau_s": r.tau_s.tolist(), "terms": r.terms.tolist(), "stride": r.stride.tolist(),
            "gyro_adev_rad_s": r.adev[:, 0:3].tolist(),
            "accel_adev_m_s2": r.adev[:, 3:6].tolist(),
        }, indent=1))  # fmt: skip
        return
    click.echo(f"{path}: {r.n:,} samples at {rate:g} Hz in {acc.stretches} stretch(es)")
    click.echo(f"{'tau s':>10} {'gyro x':>10} {'y':>10} {'z':>10} rad/s {'accel x':>10} "
               f"{'y':>10} {'z':>10} m/s^2  terms")  # fmt: skip
    for i in range(r.tau_s.size):
        g, a = r.adev[i, 0:3], r.adev[i, 3:6]
        mark = "" if r.stride[i] == 1 else f" (every {r.stride[i]}th)"
        gs, acs = " ".join(f"{v:10.4g}" for v in g), " ".join(f"{v:10.4g}" for v in a)
        click.echo(f"{r.tau_s[i]:10.4g} {gs}       {acs}        {r.terms[i]:,}{mark}")


def _is_mcap(path: Path) -> bool:
    from imud.recording.reader import is_mcap

    return is_mcap(path)


def _mcap(path: Path, device: str | None, as_json: bool) -> tuple[float, int, Iterator[Any]]:
    from imud.recording.reader import McapInputError, open_recordings
    from imud.wire import decode

    try:
        rec = open_recordings([path])
    except McapInputError as e:
        _fail(str(e), EXIT_USAGE, as_json)
    device = _recorded_device(rec, device, as_json)
    # a first pass for the count and the rate (the tau grid needs the record's length)
    n = 0
    first_t = last_t = None
    for _, _, w in rec.batches([device]):
        b = decode(w)
        if b.count:
            n += b.count
            first_t = int(b.t_ns[0]) if first_t is None else first_t
            last_t = int(b.t_ns[-1])
    if first_t is None or last_t is None or n < 3 or last_t <= first_t:
        _fail(f"{path}: {device} has too few samples for an Allan deviation", EXIT_USAGE, as_json)
    rate = (n - 1) / ((last_t - first_t) / 1e9)

    def chunks() -> Iterator[F64 | None]:
        from imud.channels import Channel

        end: int | None = None
        for _, _, w in rec.batches([device]):
            b = decode(w)
            if not b.count:
                continue
            if end is not None and (b.first_seq != end or b.lost_before):
                yield None
            end = b.first_seq + b.count
            g, a = b.get(Channel.GYRO), b.get(Channel.ACCEL)
            if g is None or a is None:
                _fail(f"{path}: {device} has no gyro and accelerometer", EXIT_USAGE, as_json)
            y = np.hstack((g, a)).astype(np.float64)
            ok = np.isfinite(y).all(axis=1)
            if ok.all():
                yield y
            else:  # rows without the sensor: gaps
                idx = np.flatnonzero(~ok)
                for k, part in enumerate(np.split(y, idx)):
                    part = part[1:] if k else part
                    if part.shape[0]:
                        yield part
                    yield None

    return rate, n, chunks()


def _csv(path: Path, as_json: bool) -> tuple[float, int, Iterator[Any]]:
    from imud.calib.csvio import CsvError, read_csv

    try:
        rec = read_csv(path)
    except CsvError as e:
        _fail(str(e), EXIT_USAGE, as_json)
    except OSError as e:
        _fail(f"{path}: cannot read: {e.strerror}", EXIT_USAGE, as_json)
    y = np.hstack((rec.gyro, rec.accel)).astype(np.float64)
    t = np.asarray(rec.t_ns, dtype=np.int64)
    if t.size < 3:
        _fail(f"{path}: {t.size} samples: too few for an Allan deviation", EXIT_USAGE, as_json)
    dt = np.diff(t)
    period = float(np.median(dt))
    # a stamp jump of more than half a period more, or a row without both sensors: a gap
    cut = np.zeros(t.size, dtype=bool)
    cut[1:] = dt > 1.5 * period
    bad: Any = ~np.isfinite(y).all(axis=1)
    n = int(np.count_nonzero(~bad))

    def chunks() -> Iterator[F64 | None]:
        starts = np.flatnonzero(cut | bad | np.r_[False, bad[:-1]])
        for k, part in enumerate(np.split(np.arange(t.size), starts)):
            rows = part[~bad[part]]
            if k:
                yield None
            if rows.size:
                yield y[rows]

    return 1e9 / period, n, chunks()
