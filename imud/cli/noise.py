"""`imud noise FILE.mcap|FILE.csv|DEVICE`: the overlapping Allan deviation of a device's gyro and
accelerometer (imud/noise/allan.py), streamed from a file (a recording's batches one at a time,
a CSV's rows as read) or live from a running daemon (`--duration`), and its noise terms fitted
with 95 % intervals (imud/noise/fit.py). Gaps (lost samples, a stamp jump, a row without the
sensor) split the samples into stretches; no Allan term spans one."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import numpy as np

from imud.cli.common import (
    EXIT_USAGE,
    _connect,
    _fail,
    _new_file,
    _prefix,
    _recorded_device,
)

F64 = Any
Chunk = tuple[F64, F64 | None] | None  # (samples (n, 6), temperatures (n,) or None) or a gap


@dataclass
class Source:
    """Where the samples come from: `n` sizes the tau grid (an upper bound is enough: a tau
    with no term is left out), `rate` the nominal rate (the measured one relabels the taus)."""

    name: str
    rate: float
    n: int
    chunks: Iterator[Chunk]
    device: str | None = None
    chip: str | None = None
    datasheet: dict[str, float] | None = None  # one-sided densities of the chip at its settings
    measured_rate: float | None = None  # set by the reader once the samples are read


def _duration(text: str | None) -> float | None:
    if text is None:
        return None
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(s|m|min|h|d)?\s*", text)
    if not m or float(m.group(1)) <= 0:
        raise click.BadParameter(f"{text!r}: a positive time such as 90s, 30m, 2h")
    scale = {"s": 1, "m": 60, "min": 60, "h": 3600, "d": 86400}[m.group(2) or "s"]
    return float(m.group(1)) * scale


@click.command()
@click.argument("source", metavar="FILE|DEVICE")
@click.option("--device", help="the device (needed when the recording holds more than one)")
@click.option("--per-decade", type=click.IntRange(2, 50), default=8, show_default=True,
              help="tau values per decade")  # fmt: skip
@click.option("--json", "as_json", is_flag=True, help="print JSON")
@click.option("--kalibr", "kalibr", type=click.Path(dir_okay=False),
              help="write a Kalibr imu.yaml here (the worst axis of each sensor)")  # fmt: skip
@click.option("--rostopic", default=None, help="the rostopic written in --kalibr's file "
              "[default: /<device>/imu/data_raw]")  # fmt: skip
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False),
              help="write a PNG of the curves and fitted lines (needs imud[plot])")  # fmt: skip
@click.option("--by-temperature", "by_temp", type=float, is_flag=False, flag_value=5.0,
              default=None, metavar="[BIN_C]",
              help="gyro bias and N per temperature bin of BIN_C °C (default 5)")  # fmt: skip
@click.option(
    "--duration",
    "duration_text",
    default=None,
    help="live: subscribe to DEVICE on a running daemon for this long (90s, 30m, 2h)",
)
@_connect
@_prefix
def noise(
    source: str,
    device: str | None,
    per_decade: int,
    as_json: bool,
    kalibr: str | None,
    rostopic: str | None,
    plot_path: str | None,
    by_temp: float | None,
    duration_text: str | None,
    endpoint: str,
    prefix: str,
) -> None:
    """The Allan deviation of a recording's (or a live device's) gyro and accelerometer, and its
    noise terms: quantisation Q, white noise N, bias instability B, random walk K, rate ramp R."""
    from imud.noise.allan import StreamingAllan, lags
    from imud.noise.fit import fit
    from imud.noise.report import kalibr_yaml, summary, text
    from imud.noise.tempbins import TemperatureBins

    for option, out in (("--kalibr", kalibr), ("--plot", plot_path)):
        if out is not None:
            _new_file(Path(out), option, as_json)
    if by_temp is not None and not (by_temp > 0 and math.isfinite(by_temp)):
        _fail(f"--by-temperature {by_temp}: the bin width must be a positive number of °C "
              "(e.g. --by-temperature 2)", EXIT_USAGE, as_json)  # fmt: skip
    try:
        duration = _duration(duration_text)
    except click.BadParameter as e:
        _fail(f"--duration {e.message}", EXIT_USAGE, as_json)
    path = Path(source)
    if duration is not None:
        if path.is_file():
            _fail(f"--duration is for a live device; {source} is a file (leave --duration out)",
                  EXIT_USAGE, as_json)  # fmt: skip
        src = _live(source, duration, endpoint, prefix, as_json)
    elif not path.exists() and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_\-]*", source):
        _fail(f"{source}: no such file; for a live device give --duration (e.g. "
              f"`imud noise {source} --duration 2h`)", EXIT_USAGE, as_json)  # fmt: skip
    else:
        src = _mcap(path, device, as_json) if _is_mcap(path) else _csv(path, as_json)
    if src.n < 3:
        _fail(f"{src.name}: {src.n} samples: the Allan deviation needs at least 3", EXIT_USAGE,
              as_json)  # fmt: skip
    acc = StreamingAllan(src.rate, 6, lags(src.n, per_decade))
    bins = TemperatureBins(src.rate, by_temp) if by_temp is not None else None
    saw_temp = False
    for c in src.chunks:
        if c is None:
            acc.gap()
            if bins:
                bins.gap()
            continue
        y, temp = c
        acc.feed(y)
        if bins is not None and temp is not None:
            saw_temp = True
            bins.feed(y, temp)
    r = acc.result()
    rate = src.measured_rate or src.rate
    if rate != src.rate:  # the taus at the measured rate (the sums do not depend on it)
        r = dataclasses.replace(r, tau_s=r.m / rate)
    if not r.tau_s.size:
        _fail(f"{src.name}: no stretch without a gap is long enough for one tau", EXIT_USAGE,
              as_json)  # fmt: skip
    if bins is not None and not saw_temp:
        _fail(f"{src.name}: no temperature recorded (a `temp` column, or the chip's temperature "
              "channel): --by-temperature has nothing to bin by; leave it out", EXIT_USAGE,
              as_json)  # fmt: skip
    fits = fit(r)
    s = summary(fits, rate, src.datasheet)
    s.update({"source": src.name, "device": src.device, "chip": src.chip})
    if kalibr is not None:
        topic = rostopic or f"/{src.device or 'imu'}/imu/data_raw"
        Path(kalibr).write_text(kalibr_yaml(s, topic, src.name))
    if plot_path is not None:
        from imud.noise.plot import PlotUnavailable, plot

        try:
            what = " ".join(x for x in (src.device, src.chip) if x)
            title = f"{src.name}: {what} {r.n:,} samples at {rate:g} Hz"
            plot(r, fits, Path(plot_path), title, src.datasheet)
        except PlotUnavailable as e:
            _fail(str(e), EXIT_USAGE, as_json)
    by = _by_temperature(bins, rate) if bins is not None else None
    if as_json:
        click.echo(json.dumps({
            "source": src.name, "device": src.device, "chip": src.chip, "rate_hz": rate,
            "samples": r.n, "stretches": acc.stretches,
            "tau_s": r.tau_s.tolist(), "terms": r.terms.tolist(), "stride": r.stride.tolist(),
            "gyro_adev_rad_s": r.adev[:, 0:3].tolist(),
            "accel_adev_m_s2": r.adev[:, 3:6].tolist(),
            "fit": s, "by_temperature": by,
            "kalibr": kalibr, "plot": plot_path,
        }, indent=1))  # fmt: skip
        return
    click.echo(f"{src.name}: {r.n:,} samples at {rate:g} Hz in {acc.stretches} stretch(es)")
    click.echo(f"{'tau s':>10} {'gyro x':>10} {'y':>10} {'z':>10} rad/s {'accel x':>10} "
               f"{'y':>10} {'z':>10} m/s^2  terms")  # fmt: skip
    for i in range(r.tau_s.size):
        g, a = r.adev[i, 0:3], r.adev[i, 3:6]
        mark = "" if r.stride[i] == 1 else f" (every {r.stride[i]}th)"
        gs, acs = " ".join(f"{v:10.4g}" for v in g), " ".join(f"{v:10.4g}" for v in a)
        click.echo(f"{r.tau_s[i]:10.4g} {gs}       {acs}        {r.terms[i]:,}{mark}")
    for line in text(s):
        click.echo(line)
    if by is not None:
        click.echo(f"by temperature ({by_temp:g} °C bins): mean gyro rad/s per axis; gyro N "
                   "rad/s/sqrt(Hz) [95 %]")  # fmt: skip
        for b in by:
            if b["gyro_n"] is None:
                click.echo(f"  {b['lo_c']:6.1f} .. {b['hi_c']:6.1f} °C: {b['samples']:,} samples"
                           ": too few for an Allan deviation")  # fmt: skip
                continue
            ns = ", ".join(f"{x['value']:.3g} [{x['lo95']:.3g}, {x['hi95']:.3g}]"
                           for x in b["gyro_n"])  # fmt: skip
            mean = ", ".join(f"{v:+.4g}" for v in b["gyro_mean_rad_s"])
            click.echo(f"  {b['lo_c']:6.1f} .. {b['hi_c']:6.1f} °C: {b['samples']:,} samples; "
                       f"mean {mean}; N {ns}")  # fmt: skip
    for option, out in (("Kalibr imu.yaml", kalibr), ("plot", plot_path)):
        if out is not None:
            click.echo(f"{option}: {out}")


def _by_temperature(bins: Any, rate: float) -> list[dict[str, Any]]:
    out = []
    for lo, hi, n, mean, fits in bins.results():

        def n_of(f: Any) -> dict[str, float]:
            t = f.terms["N"]
            return {"value": t.value, "lo95": t.lo, "hi95": t.hi}

        out.append({
            "lo_c": lo, "hi_c": hi, "samples": n, "gyro_mean_rad_s": mean.tolist(),
            "gyro_n": None if fits is None else [n_of(f) for f in fits[0:3]],
            "accel_n": None if fits is None else [n_of(f) for f in fits[3:6]],
        })  # fmt: skip
    return out


def _is_mcap(path: Path) -> bool:
    from imud.recording.reader import is_mcap

    return is_mcap(path)


def _datasheet(rec: Any, device: str) -> dict[str, float] | None:
    """The recorded chip's one-sided densities at its recorded settings (None: not known)."""
    found = rec.daemon_config()
    if found is None:
        return None
    from imud import registry
    from imud.recording.daemoncfg import DaemonConfig

    cfg = DaemonConfig(*found)
    try:
        if cfg.config is None:
            return None
        dev = next((d for d in cfg.config.device if d.name == device), None)
        spec = registry.CHIPS.get(dev.chip) if dev is not None else None
        if dev is None or spec is None or spec.noise is None:
            return None
        nf = spec.noise(dev)
        return {"gyro": nf.gyro_density, "accel": nf.accel_density}
    finally:
        cfg.close()


def _batch_chunks(batches: Iterator[Any], name: str, as_json: bool) -> Iterator[Chunk]:
    """Decoded batches as chunks: a seq gap or lost samples is a gap; rows without the gyro or
    accelerometer (NaN: the chip marked them invalid) are gaps."""
    from imud.channels import Channel

    end: int | None = None
    for b in batches:
        if not b.count:
            continue
        if end is not None and (b.first_seq != end or b.lost_before):
            yield None
        end = b.first_seq + b.count
        g, a = b.get(Channel.GYRO), b.get(Channel.ACCEL)
        if g is None or a is None:
            _fail(f"{name} has no gyro and accelerometer", EXIT_USAGE, as_json)
        tc = b.get(Channel.TEMPERATURE)
        temp = None if tc is None else np.asarray(tc, dtype=np.float64)
        y = np.hstack((g, a)).astype(np.float64)
        ok = np.isfinite(y).all(axis=1)
        if ok.all():
            yield y, temp
            continue
        idx = np.flatnonzero(~ok)
        starts = np.r_[0, idx + 1]
        stops = np.r_[idx, y.shape[0]]
        for k, (i, j) in enumerate(zip(starts, stops, strict=True)):
            if k:
                yield None
            if j > i:
                yield y[i:j], None if temp is None else temp[i:j]


def _mcap(path: Path, device: str | None, as_json: bool) -> Source:
    """One pass over the batches: the tau grid is sized from the recording's span and the
    device's configured rate (an indexed file has both without reading its data), and the
    taus are relabelled at the measured rate at the end. A file without its summary is
    counted first (it has to be read to know its length)."""
    from imud.recording.reader import McapInputError, _span, open_recordings
    from imud.wire import decode

    try:
        rec = open_recordings([path])
    except McapInputError as e:
        _fail(str(e), EXIT_USAGE, as_json)
    device = _recorded_device(rec, device, as_json)
    info = rec.info.get(device, {})
    odr = float(info.get("odr_hz") or 0.0)
    single = rec.indexed and len(rec.parts) <= 1
    n_est = 0
    if single and odr > 0:
        first, last = _span(rec)
        n_est = int((last - first) / 1e9 * odr * 1.05) + 1024  # the last batch's samples, margin
    if n_est < 3:  # no summary, a split recording, or no rate recorded: count
        n_est = sum(decode(w).count for _, _, w in rec.batches([device]))
        odr = odr or 1.0
    src = Source(str(path), odr if odr > 0 else 1.0, n_est, iter(()), device,
                 info.get("chip"), _datasheet(rec, device))  # fmt: skip
    span = {"n": 0, "stretches": 0, "ns": 0}

    def measured() -> Iterator[Any]:
        """The decoded batches, timing each stretch for the measured rate."""
        prev_end: int | None = None
        first_t = last_t = None
        n_run = 0
        for _, _, w in rec.batches([device]):
            b = decode(w)
            if not b.count:
                continue
            if prev_end is not None and (b.first_seq != prev_end or b.lost_before):
                if first_t is not None and last_t is not None and n_run > 1:
                    span["n"] += n_run - 1
                    span["ns"] += last_t - first_t
                first_t, n_run = None, 0
            prev_end = b.first_seq + b.count
            first_t = int(b.t_ns[0]) if first_t is None else first_t
            last_t = int(b.t_ns[-1])
            n_run += b.count
            yield b
        if first_t is not None and last_t is not None and n_run > 1:
            span["n"] += n_run - 1
            span["ns"] += last_t - first_t
        if span["ns"] > 0:
            src.measured_rate = span["n"] / (span["ns"] / 1e9)
        elif src.rate == 1.0:
            _fail(f"{path}: {device} has too few samples for an Allan deviation", EXIT_USAGE,
                  as_json)  # fmt: skip

    src.chunks = _batch_chunks(measured(), f"{path}: {device}", as_json)
    return src


def _csv(path: Path, as_json: bool) -> Source:
    from imud.calib.csvio import CsvError, read_comments, read_csv

    try:
        rec = read_csv(path)
    except CsvError as e:
        _fail(str(e), EXIT_USAGE, as_json)
    except OSError as e:
        _fail(f"{path}: cannot read: {e.strerror}", EXIT_USAGE, as_json)
    y = np.hstack((rec.gyro, rec.accel)).astype(np.float64)
    t = np.asarray(rec.t_ns, dtype=np.int64)
    temp = None if rec.temp is None else np.asarray(rec.temp, dtype=np.float64)
    if t.size < 3:
        _fail(f"{path}: {t.size} samples: too few for an Allan deviation", EXIT_USAGE, as_json)
    dt = np.diff(t)
    period = float(np.median(dt))
    # a stamp jump of more than half a period more, or a row without both sensors: a gap
    cut = np.zeros(t.size, dtype=bool)
    cut[1:] = dt > 1.5 * period
    bad: Any = ~np.isfinite(y).all(axis=1)
    n = int(np.count_nonzero(~bad))
    # the rate over the stretches (every step within them), not one median step
    inner = ~cut[1:] & ~bad[1:] & ~bad[:-1]
    rate = float(inner.sum() / (dt[inner].sum() / 1e9)) if inner.any() else 1e9 / period

    def chunks() -> Iterator[Chunk]:
        starts = np.flatnonzero(cut | bad | np.r_[False, bad[:-1]])
        for k, part in enumerate(np.split(np.arange(t.size), starts)):
            rows = part[~bad[part]]
            if k:
                yield None
            if rows.size:
                yield y[rows], None if temp is None else temp[rows]

    comments = read_comments(path)
    return Source(str(path), rate, n, chunks(), comments.get("device"), comments.get("chip"))


def _live(device: str, duration: float, endpoint: str, prefix: str, as_json: bool) -> Source:
    """Subscribe to DEVICE's corrected stream on the daemon at `endpoint` for `duration` s (the
    session is the one every command opens: loopback by default, no multicast scouting)."""
    import zenoh

    from imud.cli.common import _ask_status, _device, _session
    from imud.client import data_key
    from imud.wire import decode

    s = _session(endpoint, as_json)
    st = _ask_status(s, endpoint, prefix, 5.0, as_json)
    dev = _device(st, device, endpoint, False, as_json)
    rate = float(dev.get("chip_rate_hz") or dev.get("odr_hz") or 0.0)
    if rate <= 0:
        _fail(f"{device}: the daemon reports no rate for it", EXIT_USAGE, as_json)
    datasheet = _live_datasheet(s, prefix, device)
    sub = s.declare_subscriber(data_key(device, prefix), zenoh.handlers.FifoChannel(16384))
    src = Source(f"live {device}", rate, int(rate * duration * 1.05) + 1024, iter(()), device,
                 dev.get("chip"), datasheet)  # fmt: skip

    def arrivals() -> Iterator[Any]:
        end = time.monotonic() + duration
        first_t = last_t = None
        n = 0
        try:
            while time.monotonic() < end:
                sample = sub.try_recv()
                if sample is None:
                    time.sleep(0.01)
                    continue
                b = decode(sample.payload.to_bytes())
                if b.count:
                    first_t = int(b.t_ns[0]) if first_t is None else first_t
                    last_t = int(b.t_ns[-1])
                    n += b.count
                yield b
        except KeyboardInterrupt:
            pass  # Ctrl-C: analyse what came
        finally:
            sub.undeclare()
            s.close()
        if first_t is not None and last_t is not None and last_t > first_t:
            src.measured_rate = (n - 1) / ((last_t - first_t) / 1e9)

    src.chunks = _batch_chunks(arrivals(), f"live {device}", as_json)
    return src


def _live_datasheet(session: Any, prefix: str, device: str) -> dict[str, float] | None:
    """The chip's densities from the daemon's own config (None when it does not say)."""
    try:
        from imud import registry
        from imud.recording.daemoncfg import DaemonConfig
        from imud.session import get_config

        view = get_config(session, prefix, timeout=2.0)
        cfg = DaemonConfig(view.get("config") or {}, {})
        try:
            dev = next((d for d in (cfg.config.device if cfg.config else [])
                        if d.name == device), None)  # fmt: skip
            spec = registry.CHIPS.get(dev.chip) if dev is not None else None
            if dev is None or spec is None or spec.noise is None:
                return None
            nf = spec.noise(dev)
            return {"gyro": nf.gyro_density, "accel": nf.accel_density}
        finally:
            cfg.close()
    except Exception:  # the figures are a comparison only: the analysis goes on without them
        return None
