"""`imud plot FILE.mcap|FILE.csv [-o PNG] [--device NAME]`: a picture a device of a recording
(imud/recording/plot.py). With several devices, `-o run.png` writes `run_<device>.png` each."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from imud.cli.common import EXIT_USAGE, _fail, _new_file

if TYPE_CHECKING:
    from imud.recording.plot import Series


@click.command()
@click.argument("path", type=click.Path(dir_okay=False, exists=True))
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), help="the PNG to write")
@click.option(
    "--device", "--devices", "devices", multiple=True,
    help="only these devices (repeat it, or name them with commas: --devices a,b)",
)  # fmt: skip
def plot(path: str, out: str | None, devices: tuple[str, ...]) -> None:
    """Draw a recording: each device's axes over time, its rate, gaps marked, temperature."""
    try:
        from imud.recording import plot as draw
    except ImportError as e:
        _fail(f"imud plot needs matplotlib: pip install 'imud[plot]' ({e})", EXIT_USAGE)
    src = Path(path)
    target = Path(out) if out else src.with_suffix(".png")
    if target.suffix.lower() != ".png":
        _fail(f"-o {target}: name a .png file", EXIT_USAGE)
    series = (
        _from_mcap(src, [n for d in devices for n in d.split(",") if n])
        if _is_mcap(src)
        else [_from_csv(src)]
    )
    wheres = [
        target if len(series) == 1 else target.with_name(f"{target.stem}_{s.name}.png")
        for s in series
    ]
    for where in wheres:
        _new_file(where, "-o")
    for s, where in zip(series, wheres, strict=True):
        draw.draw(s, where)
        click.echo(f"{where}: {s.name}, {s.t_ns.size:,} samples, {s.lost:,} lost")


def _is_mcap(path: Path) -> bool:
    from imud.recording.reader import is_mcap

    return is_mcap(path)


def _from_mcap(path: Path, devices: list[str]) -> list[Series]:
    from imud.recording.export import device_data
    from imud.recording.plot import Series as Drawn
    from imud.recording.reader import McapInputError, open_recording

    try:
        rec = open_recording(path)
        if rec.warning:
            click.echo(f"imud: {rec.warning}", err=True)
        names = devices or sorted(rec.devices)
        out = []
        for name in names:
            d = device_data(rec, name)  # the file read once: samples, losses, gaps
            temp = d.temp[:, 0] if d.temp is not None and d.temp.ndim == 2 else d.temp
            out.append(Drawn(name, d.t_ns, d.accel, d.gyro, d.mag, temp, d.gaps_ns, d.lost))
    except McapInputError as e:
        _fail(str(e), EXIT_USAGE)
    return out


def _from_csv(path: Path) -> Series:
    from imud.calib.csvio import CsvError, read_comments, read_csv
    from imud.recording.plot import Series as Drawn
    from imud.recording.plot import gaps_from_time

    try:
        rec = read_csv(path, need=())
    except CsvError as e:
        _fail(str(e), EXIT_USAGE)
    gaps, lost = gaps_from_time(rec.t_ns)
    name = read_comments(path).get("device") or path.stem
    return Drawn(name, rec.t_ns, rec.accel, rec.gyro, rec.mag, rec.temp, gaps, lost)
