"""`imud echo`'s output: samples under a header with units, or once-a-second summaries."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import click

if TYPE_CHECKING:
    from imud.channels import Channel
    from imud.wire import Batch


def arrivals(sub: Any, idle_s: float) -> Iterator[Batch | None]:
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


_AXES = {1: "", 3: " x y z", 4: " w x y z", 6: " xx xy xz yy yz zz"}


def _value_format(unit: str) -> str:
    """How wide and precise one value of a channel in `unit` prints (tesla and a covariance in
    rad^2 need exponents)."""
    return {"T": "+10.3e", "rad^2": "+10.3e", "degC": "7.2f", "1": "+7.4f"}.get(unit, "+9.4f")


def _flag_names(flags: int) -> str:
    from imud.channels import SampleFlag

    names = [f.name or "" for f in SampleFlag if flags & f]
    rest = flags & ~sum(SampleFlag)
    return "|".join([*names, *([f"0x{rest:x}"] if rest else [])])


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


class Samples:
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
        from imud.wire import FLAG_GAP_UNCERTAIN

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
            if b.flags & FLAG_GAP_UNCERTAIN:
                row["lost_estimated"] = True  # the count may be off: docs/wire-format.md
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


class Summary:
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
