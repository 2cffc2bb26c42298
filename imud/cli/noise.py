"""`imud noise FILE.mcap|FILE.csv|DEVICE`: the overlapping Allan deviation of a device's gyro and
accelerometer (imud/noise/allan.py), streamed from a file (a recording's batches one at a time,
a CSV's rows as read) or live from a running daemon (`--duration`), and its noise terms fitted
with 95 % intervals (imud/noise/fit.py). Gaps (lost samples, a stamp jump, a row without the
sensor) split the samples into stretches; no Allan term spans one."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
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
    reader: dict[str, Any] | None = None  # what read the file, and how long it took
    # read on a thread of its own while the sums run (a file; not live, whose Ctrl-C ends the
    # capture where the main thread receives it)
    prefetch: bool = True


class Retry(Exception):
    """A fast reader met something it does not take as it is, part-way through: the analysis
    starts again from `fallback()` (the reader that names what is wrong, or reads it)."""

    def __init__(self, fallback: Any) -> None:
        super().__init__("fall back")
        self.fallback = fallback


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

    wall = time.monotonic()
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

    def analyse(src: Source) -> tuple[StreamingAllan, TemperatureBins | None, bool]:
        if src.n < 3:
            _fail(f"{src.name}: {src.n} samples: the Allan deviation needs at least 3",
                  EXIT_USAGE, as_json)  # fmt: skip
        acc = StreamingAllan(src.rate, 6, lags(src.n, per_decade))
        bins = TemperatureBins(src.rate, by_temp) if by_temp is not None else None
        saw_temp = False
        chunks = _joined(src.chunks)
        for c in _prefetched(chunks) if src.prefetch else chunks:
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
        return acc, bins, saw_temp

    try:
        acc, bins, saw_temp = analyse(src)
    except Retry as e:
        src = e.fallback()
        acc, bins, saw_temp = analyse(src)
    wall = time.monotonic() - wall
    r = acc.result()
    # the taus of the samples read (the grid was sized from an estimate of their count, an
    # upper bound: the same geometric grid, longer), as a grid sized from the count would be
    grid = StreamingAllan(1.0, 1, lags(max(r.n, 1), per_decade)).m
    keep = np.isin(r.m, grid)
    if not keep.all():
        r = dataclasses.replace(r, tau_s=r.tau_s[keep], m=r.m[keep], adev=r.adev[keep],
                                terms=r.terms[keep], stride=r.stride[keep])  # fmt: skip
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
    reader = None if src.reader is None else {**src.reader, "total_s": round(wall, 3)}
    if as_json:
        click.echo(json.dumps({
            "source": src.name, "device": src.device, "chip": src.chip, "rate_hz": rate,
            "samples": r.n, "stretches": acc.stretches,
            "tau_s": r.tau_s.tolist(), "terms": r.terms.tolist(), "stride": r.stride.tolist(),
            "gyro_adev_rad_s": r.adev[:, 0:3].tolist(),
            "accel_adev_m_s2": r.adev[:, 3:6].tolist(),
            "fit": s, "by_temperature": by,
            "kalibr": kalibr, "plot": plot_path, "reader": reader,
        }, indent=1))  # fmt: skip
        return
    click.echo(f"{src.name}: {r.n:,} samples at {rate:g} Hz in {acc.stretches} stretch(es)")
    if reader is not None:
        click.echo(_reader_line(reader))
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


def _reader_line(reader: dict[str, Any]) -> str:
    """How the samples were read: the parser, its seconds and MB/s, and the whole analysis'."""
    line = f"read by {reader['parser']}"
    if reader.get("read_s"):
        line += f": {reader['read_s']:.1f} s parsing"
        if reader.get("bytes"):
            mb_s = reader["bytes"] / 1e6 / max(reader["read_s"], 1e-9)
            line += f" ({mb_s:.0f} MB/s of the file)"
    return line + f", {reader['total_s']:.1f} s reading and analysing"


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
    return None if found is None else _densities(found[0], found[1], device)


def _densities(config: dict[str, Any], cal: dict[str, str], device: str) -> dict[str, float] | None:
    """A device's datasheet densities at the settings a daemon config (a table) gives it."""
    from imud import registry
    from imud.recording.daemoncfg import DaemonConfig

    cfg = DaemonConfig(config, cal)
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
        yield from _finite(np.hstack((g, a)).astype(np.float64), temp)


JOIN = 131_072  # samples fed to the Allan sums at once


def _joined(chunks: Iterator[Chunk]) -> Iterator[Chunk]:
    """Consecutive chunks joined up to JOIN samples (a gap, or a change in whether they carry
    a temperature, ends a join): the sums' step costs a Python loop over the taus whatever its
    length, so a recording's 20-sample batches fed one by one cost 10x their arithmetic."""
    held: list[tuple[F64, F64 | None]] = []
    n = 0

    def out() -> Chunk:
        ys = [y for y, _ in held]
        ts = [t for _, t in held if t is not None]
        y = ys[0] if len(ys) == 1 else np.concatenate(ys)
        temp = None if len(ts) != len(ys) else ts[0] if len(ts) == 1 else np.concatenate(ts)
        return y, temp

    for c in chunks:
        if c is not None and held and (c[1] is None) != (held[0][1] is None):
            yield out()
            held, n = [], 0
        if c is None:
            if held:
                yield out()
                held, n = [], 0
            yield None
            continue
        held.append(c)
        n += c[0].shape[0]
        if n >= JOIN:
            yield out()
            held, n = [], 0
    if held:
        yield out()


_END = object()  # the reading thread's last item


@dataclass(frozen=True)
class _Failed:
    """What the reading thread raised, handed to the caller's thread to raise there."""

    error: BaseException


def _prefetched(chunks: Iterator[Chunk], depth: int = 4) -> Iterator[Chunk]:
    """The chunks read on another thread, `depth` ahead: parsing (pyarrow, zstd, NumPy's
    gathers) and the Allan sums (NumPy) both run mostly without the GIL, so on two cores a
    file is read while the previous chunk is summed. What the reader raises (a refusal, a
    hand-over to another reader) is raised here, in order."""
    import queue
    import threading

    q: queue.Queue[Any] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item: Any) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False  # the caller has stopped reading

    def read() -> None:
        try:
            for c in chunks:
                if not put(c):
                    return
            put(_END)
        except BaseException as e:  # raised again on the caller's thread
            put(_Failed(e))

    t = threading.Thread(target=read, name="imud-noise-read", daemon=True)
    t.start()
    try:
        while True:
            item = q.get()
            if item is _END:
                return
            if isinstance(item, _Failed):
                raise item.error
            yield item
    finally:
        stop.set()
        t.join(timeout=5.0)


def _finite(y: F64, temp: F64 | None) -> Iterator[Chunk]:
    """The samples, a row that is not finite (the chip marked it invalid: NaN) a gap."""
    ok = np.isfinite(y).all(axis=1)
    if ok.all():
        yield y, temp
        return
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
    from imud.wire import WireError, decode

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
        try:
            first, last = _span(rec)
            n_est = int((last - first) / 1e9 * odr * 1.05) + 1024  # the last batch's, margin
        except Exception:  # a damaged first or last chunk (zstd's, the library's errors):
            n_est = 0  # counted below, where the damage is said
    if n_est < 3:  # no summary, a split recording, or no rate recorded: count
        try:
            n_est = sum(decode(w).count for _, _, w in rec.batches([device]))
        except (McapInputError, WireError) as e:
            _fail(f"{path}: {device}: damaged: {e}", EXIT_USAGE, as_json)
        odr = odr or 1.0
    src = Source(str(path), odr if odr > 0 else 1.0, n_est, iter(()), device,
                 info.get("chip"), _datasheet(rec, device))  # fmt: skip
    parts = rec.parts or [(rec.path, rec.indexed)]
    if all(indexed for _, indexed in parts) and os.environ.get("IMUD_NOISE_MCAP") != "library":
        src.chunks = _scanned(src, [p for p, _ in parts], rec.devices[device], as_json,
                              lambda: _mcap_library(src, rec, device, as_json))  # fmt: skip
        return src
    return _mcap_library(src, rec, device, as_json)


def _scanned(src: Source, paths: list[Path], topic: str, as_json: bool,
             fallback: Any) -> Iterator[Chunk]:  # fmt: skip
    """The samples by imud/noise/mcapscan.py: many chunks' batches at a time. Cut at gaps as
    the batch reader cuts them; the rate is measured over each stretch's stamps."""
    from imud.noise.mcapscan import NotScannable, scan

    src.reader = {"parser": "MCAP chunk scan (imud/noise/mcapscan.py)", "read_s": 0.0,
                  "bytes": sum(p.stat().st_size for p in paths)}  # fmt: skip
    end: int | None = None
    first_t = last_t = None
    n_run = spans_n = spans_ns = 0
    runs = scan(paths, topic)
    while True:
        t0 = time.perf_counter()
        try:
            run = next(runs, None)
        except (NotScannable, ValueError, IndexError, OverflowError, MemoryError, OSError):
            # a damaged file the scan's checks did not name: the recording reader reads it
            # or says what is wrong
            raise Retry(fallback) from None
        src.reader["read_s"] += time.perf_counter() - t0
        if run is None:
            break
        ends = run.first_seq + run.count
        prev = np.r_[run.first_seq[0] if end is None else end, ends[:-1]]
        new = (run.first_seq != prev) | (run.lost > 0)
        if end is None:
            new[0] = False
        end = int(ends[-1])
        bounds = np.r_[0, np.flatnonzero(new), run.count.size]
        starts = np.r_[0, np.cumsum(run.count)]
        for i, j in itertools.pairwise(bounds):
            if i == j:
                continue
            if new[i]:
                if first_t is not None and last_t is not None and n_run > 1:
                    spans_n += n_run - 1
                    spans_ns += last_t - first_t
                first_t, n_run = None, 0
                yield None
            first_t = int(run.t_first[i]) if first_t is None else first_t
            last_t = int(run.t_last[j - 1])
            n_run += int(run.count[i:j].sum())
            a, b = int(starts[i]), int(starts[j])
            yield from _finite(run.y[a:b], None if run.temp is None else run.temp[a:b])
    if first_t is not None and last_t is not None and n_run > 1:
        spans_n += n_run - 1
        spans_ns += last_t - first_t
    if spans_ns > 0:
        src.measured_rate = spans_n / (spans_ns / 1e9)
    elif src.rate == 1.0:
        _fail(f"{src.name}: {src.device} has too few samples for an Allan deviation", EXIT_USAGE,
              as_json)  # fmt: skip


def _mcap_library(src: Source, rec: Any, device: str, as_json: bool) -> Source:
    """The batches one at a time through the recording reader (a file without its summary, or
    one the chunk scan does not take as it is)."""
    from imud.wire import WireError, decode

    path = src.name
    src.reader = {"parser": "the mcap library, a batch at a time (imud/recording/reader.py)"}
    span = {"n": 0, "stretches": 0, "ns": 0}

    def batches() -> Iterator[bytes]:
        from imud.recording.reader import McapInputError

        try:
            for _, _, w in rec.batches([device]):
                yield w
        except McapInputError as e:  # an indexed file damaged past its summary
            _fail(str(e), EXIT_USAGE, as_json)

    def measured() -> Iterator[Any]:
        """The decoded batches, timing each stretch for the measured rate."""
        prev_end: int | None = None
        first_t = last_t = None
        n_run = 0
        for w in batches():
            try:
                b = decode(w)
            except WireError as e:
                _fail(f"{path}: {device}: a damaged batch: {e}", EXIT_USAGE, as_json)
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


STREAM_BYTES = 64 << 20  # a CSV bigger than this is read a block at a time (imud/noise/csvstream)


def _csv(path: Path, as_json: bool) -> Source:
    """A file up to STREAM_BYTES is read whole by read_csv (every form the documented format
    allows, a refusal naming its line); a bigger one in imud's own columns a block at a time
    (imud/noise/csvstream.py), handing over to read_csv for a line it does not take."""
    try:
        big = path.stat().st_size > STREAM_BYTES
    except OSError:
        big = False
    if big:
        from imud.noise.csvstream import NotStreamable, open_stream

        try:
            return _csv_streamed(open_stream(path), as_json)
        except NotStreamable:
            pass
    return _csv_whole(path, as_json)


def _csv_streamed(stream: Any, as_json: bool) -> Source:
    """The rows a block at a time. The period, for the gap rule (a step of over 1.5 periods),
    is the median step of the first block (131,072 rows or more); the rate is measured over
    every step inside the stretches. The sample count sizing the tau grid is the file's size
    over its shortest row among the first ones (an upper bound: taus beyond a tenth of what
    was read are left out at the end)."""
    from imud.calib.csvio import CsvError, unit_problems
    from imud.noise.csvstream import NotStreamable, blocks
    from imud.units import STANDARD_GRAVITY

    path = stream.path
    parser = os.environ.get("IMUD_NOISE_CSV", "pyarrow")
    it = blocks(stream, use_pyarrow=parser != "numpy")
    first = next(it, None)
    if first is None or first.t.size < 3:
        raise NotStreamable("too few rows for a block")
    problems = unit_problems(first.y[:, 3:6], first.y[:, 0:3], first.temp, None,
                             ("m/s2", "rad/s", "T"), STANDARD_GRAVITY)  # fmt: skip
    if problems:
        cols = "; ".join(", ".join(stream.names[stream.index[q]] if q in stream.index else q
                                   for q in qs) for qs, _ in problems)  # fmt: skip
        _fail(str(CsvError(path, "; ".join(p for _, p in problems), None, cols)), EXIT_USAGE,
              as_json)  # fmt: skip
    period = float(np.median(np.diff(first.t)))
    with open(path, "rb") as f:
        head = f.read(1 << 16).splitlines()[stream.skip_lines + 1 : -1]
    shortest = min((len(x) + 1 for x in head if x.strip()), default=8)
    n_est = int(path.stat().st_size / shortest) + 1024
    src = Source(str(path), 1e9 / period, n_est, iter(()), stream.comments.get("device"),
                 stream.comments.get("chip"))  # fmt: skip
    src.reader = {"parser": "", "read_s": 0.0, "bytes": path.stat().st_size}

    def chunks() -> Iterator[Chunk]:
        inner_n = inner_ns = 0
        last: int | None = None
        b: Any = first
        try:
            while b is not None:
                t = b.t
                dt = np.diff(t) if last is None else np.diff(np.r_[last, t])
                cut = dt > 1.5 * period  # dt[k]: the step into row k (or k + 1 on the first)
                inner_n += int(np.count_nonzero(~cut))
                inner_ns += int(dt[~cut].sum())
                rows = np.flatnonzero(cut) + (1 if last is None else 0)
                last = int(t[-1])
                for k, (i, j) in enumerate(itertools.pairwise(np.r_[0, rows, t.size])):
                    if k:
                        yield None
                    yield b.y[i:j], None if b.temp is None else b.temp[i:j]
                b = next(it, None)
        except NotStreamable:
            raise Retry(lambda: _csv_whole(path, as_json)) from None
        src.reader = {"parser": stream.parser, "read_s": round(stream.read_s, 3),
                      "bytes": path.stat().st_size}  # fmt: skip
        if inner_n:
            src.measured_rate = inner_n / (inner_ns / 1e9)

    src.chunks = chunks()
    return src


def _csv_whole(path: Path, as_json: bool) -> Source:
    from imud.calib.csvio import CsvError, read_comments, read_csv

    w0 = time.perf_counter()

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
    src = Source(str(path), rate, n, chunks(), comments.get("device"), comments.get("chip"))
    src.reader = {
        "parser": "read_csv, whole (imud/calib/csvio.py: numpy.loadtxt)",
        "read_s": round(time.perf_counter() - w0, 3),
        "bytes": path.stat().st_size,
    }
    return src


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
                 dev.get("chip"), datasheet, prefetch=False)  # fmt: skip

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
        from imud.session import get_config

        view = get_config(session, prefix, timeout=2.0)
        return _densities(view.get("config") or {}, {}, device)
    except Exception:  # the figures are a comparison only: the analysis goes on without them
        return None
