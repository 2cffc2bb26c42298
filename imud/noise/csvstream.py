"""imud's own CSV recordings (docs/recording-csv.md) read a block at a time, for files too big to
hold: a day at 1 kHz is 86.4 M rows, 8.5 GB of text.

`imud.calib.csvio.read_csv` reads a whole file into memory (its line scan, then NumPy's parser at
about 60 MB/s): right for a calibration's minutes, not for a day. Here the rows are parsed a
block at a time and handed on, so memory stays a few blocks whatever the file's length:

- with pyarrow (the optional `noise` extra): `pyarrow.csv.open_csv`, its streaming reader, whose
  C++ parser and number conversion (correctly rounded) run at about 300 MB/s on the development
  machine (docs/noise.md);
- without it: NumPy's `fromstring(sep=",")` on 16 MB of text at a time, about 60 MB/s.

Only a file whose header names imud's own columns (timestamp_ns, ax..gz, optionally temp,
mx..mz, flags, in any order and case) is streamed. Anything the block reader does not take as
it is (a comment or blank line among the rows, a value that is not a number, NaN, a time that
does not increase) raises `NotStreamable`: the caller then reads the file with `read_csv`, whose
refusal names the line and column (or which reads what the documented format allows and this
reader does not)."""

from __future__ import annotations

import importlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

IMUD_COLUMNS = ("timestamp_ns", "ax", "ay", "az", "gx", "gy", "gz", "temp",
                "mx", "my", "mz", "flags")  # fmt: skip
REQUIRED = ("timestamp_ns", "ax", "ay", "az", "gx", "gy", "gz")
VALUES = ("gx", "gy", "gz", "ax", "ay", "az")  # the order of the samples handed on
PYARROW_BLOCK = 4 << 20  # bytes of text a pyarrow block holds (about 40,000 rows)
NUMPY_BLOCK = 16 << 20  # bytes of text parsed at once without pyarrow
MIN_ROWS = 131_072  # rows handed on at once (blocks joined up to it): the Allan sums' step
# costs a Python loop over the taus, so fewer, longer steps cost less


class NotStreamable(ValueError):
    """This file (or a line in it) is not for the block reader: read it with read_csv."""


@dataclass
class Block:
    """Rows in file order: stamps (ns), samples (n, 6) gyro then accel, temperature or None."""

    t: I64
    y: F64
    temp: F64 | None


@dataclass
class CsvStream:
    """The layout of an imud CSV, found from its first lines; `blocks()` reads the rows."""

    path: Path
    skip_lines: int  # the lines before the header (comments, blank lines)
    names: list[str]  # the header's fields as written
    index: dict[str, int]  # imud column -> field position
    parser: str = ""  # what parsed the rows (set by blocks())
    read_s: float = 0.0  # seconds spent parsing (not analysing)
    comments: dict[str, str] = field(default_factory=dict)

    @property
    def has_temp(self) -> bool:
        return "temp" in self.index


def open_stream(path: Path) -> CsvStream:
    """The layout of `path`; NotStreamable when its header is not imud's own columns."""
    comments: dict[str, str] = {}
    skip = 0
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("utf-8", "replace").lstrip("\ufeff").strip()
            if not line or line.startswith("#"):
                if line.startswith("#") and ":" in line:
                    k, _, v = line[1:].partition(":")
                    comments[k.strip()] = v.strip()
                skip += 1
                continue
            names = [n.strip() for n in line.split(",")]
            break
        else:
            raise NotStreamable("no header")
    keys = [n.lower() for n in names]
    if any(k not in IMUD_COLUMNS for k in keys) or len(set(keys)) != len(keys):
        raise NotStreamable("not imud's own columns")
    if not all(k in keys for k in REQUIRED):
        raise NotStreamable("a required column missing")
    return CsvStream(path, skip, names, {k: i for i, k in enumerate(keys)}, comments=comments)


def _pyarrow(name: str = "pyarrow") -> Any:
    """pyarrow's module (importlib: it ships no type information, and is optional)."""
    return importlib.import_module(name)


def pyarrow_version() -> str | None:
    try:
        return str(_pyarrow().__version__)
    except ImportError:
        return None


def blocks(s: CsvStream, use_pyarrow: bool = True) -> Iterator[Block]:
    """The rows a block at a time (at least MIN_ROWS each, the last excepted), checked: every
    value finite, stamps strictly increasing across the file. NotStreamable otherwise."""
    version = pyarrow_version() if use_pyarrow else None
    raw = _pyarrow_blocks(s) if version is not None else _numpy_blocks(s)
    s.parser = (f"pyarrow {version} (pyarrow.csv.open_csv)" if version is not None
                else "numpy fromstring (pip install 'imud[noise]' for pyarrow)")  # fmt: skip
    last: int | None = None
    pending: list[Block] = []
    held = 0
    t0 = time.perf_counter()
    for b in raw:
        if not b.t.size:
            continue
        if not np.isfinite(b.y).all() or (b.temp is not None and not np.isfinite(b.temp).all()):
            raise NotStreamable("a value that is not a finite number")
        step = np.diff(b.t)
        if (last is not None and b.t[0] <= last) or (step.size and step.min() <= 0):
            raise NotStreamable("a time that does not increase")
        last = int(b.t[-1])
        pending.append(b)
        held += b.t.size
        if held >= MIN_ROWS:
            s.read_s += time.perf_counter() - t0
            yield _join(pending)
            t0 = time.perf_counter()
            pending, held = [], 0
    s.read_s += time.perf_counter() - t0
    if pending:
        yield _join(pending)


def _join(bs: list[Block]) -> Block:
    if len(bs) == 1:
        return bs[0]
    temps = [b.temp for b in bs if b.temp is not None]
    temp = np.concatenate(temps) if len(temps) == len(bs) else None
    return Block(np.concatenate([b.t for b in bs]), np.concatenate([b.y for b in bs]), temp)


def _pyarrow_blocks(s: CsvStream) -> Iterator[Block]:
    pa, pc = _pyarrow(), _pyarrow("pyarrow.csv")

    want = [*VALUES, "timestamp_ns"] + (["temp"] if s.has_temp else [])
    cols = {k: s.names[s.index[k]] for k in want}
    types = {cols[k]: (pa.int64() if k == "timestamp_ns" else pa.float64()) for k in want}
    try:
        reader = pc.open_csv(
            s.path,
            read_options=pc.ReadOptions(skip_rows=s.skip_lines, block_size=PYARROW_BLOCK),
            parse_options=pc.ParseOptions(ignore_empty_lines=True),
            convert_options=pc.ConvertOptions(
                column_types=types, include_columns=list(types), strings_can_be_null=False
            ),
        )
        for batch in reader:
            if any(c.null_count for c in batch.columns):
                raise NotStreamable("an empty value")
            t = batch.column(cols["timestamp_ns"]).to_numpy()
            y = np.column_stack([batch.column(cols[k]).to_numpy() for k in VALUES])
            temp = batch.column(cols["temp"]).to_numpy() if s.has_temp else None
            yield Block(np.asarray(t, dtype=np.int64), y, temp)
    except (pa.ArrowInvalid, pa.ArrowTypeError) as e:  # a field that is no number, a short row
        raise NotStreamable(str(e)) from None


def _numpy_blocks(s: CsvStream) -> Iterator[Block]:
    """16 MB of rows at a time through NumPy's text parser. Stamps are parsed as doubles (it
    has no integer mode): 19-digit nanoseconds lose up to 128 ns each, far below a sample
    period, and the rate is measured over the whole record."""
    width = len(s.names)
    tail = b""
    with open(s.path, "rb") as f:
        for _ in range(s.skip_lines + 1):
            f.readline()
        while True:
            chunk = f.read(NUMPY_BLOCK)
            text = tail + chunk
            cut = text.rfind(b"\n") + 1 if chunk else len(text)  # the last line may lack one
            tail, text = text[cut:], text[:cut]
            if text.strip():
                yield _numpy_parse(s, text, width)
            if not chunk:
                return


def _numpy_parse(s: CsvStream, text: bytes, width: int) -> Block:
    if b"#" in text or b"\n\n" in text or b",," in text or text.startswith(b"\n"):
        raise NotStreamable("a comment or blank line among the rows")
    text = text.replace(b"\r", b"").rstrip(b"\n")
    rows = text.count(b"\n") + 1
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a field it cannot read is a DeprecationWarning
        try:
            v = np.fromstring(text.replace(b"\n", b","), sep=",")
        except (ValueError, DeprecationWarning):
            raise NotStreamable("a field that is not a number") from None
    if v.size != rows * width:
        raise NotStreamable("a row with another number of fields than the header")
    v = v.reshape(rows, width)
    y = np.ascontiguousarray(v[:, [s.index[k] for k in VALUES]])
    temp = v[:, s.index["temp"]].copy() if s.has_temp else None
    return Block(v[:, s.index["timestamp_ns"]].astype(np.int64), y, temp)
