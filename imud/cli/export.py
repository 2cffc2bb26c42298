"""`imud export FILE.mcap... --csv OUT [--device NAME]`: one device of a recording (one file, or
a split one's parts) as imud's CSV (docs/recording-csv.md), what other tools and spreadsheets
read."""

from __future__ import annotations

from pathlib import Path

import click

from imud.cli.common import EXIT_USAGE, _fail, _named, _new_file, _recorded_device


@click.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "--csv", "csv_path", required=True, type=click.Path(dir_okay=False), help="the CSV to write"
)
@click.option("--device", help="the device (needed when the file holds more than one)")
def export(paths: tuple[str, ...], csv_path: str, device: str | None) -> None:
    """Write one device of an MCAP recording as a CSV recording."""
    from imud.recording.export import to_csv
    from imud.recording.reader import McapInputError, open_recordings

    out = Path(csv_path)
    _new_file(out, "--csv")
    try:
        rec = open_recordings([Path(p) for p in paths])
        path = _named(rec)
        if rec.warning:
            click.echo(f"imud: {rec.warning}", err=True)
        device = _recorded_device(rec, device)
        d = to_csv(rec, device, out)
    except McapInputError as e:
        _fail(str(e), EXIT_USAGE)
    except ValueError as e:  # samples the CSV cannot hold in that order, and the like
        _fail(f"{path}: cannot write {out}: {e}", 1)
    extra = [f"{n:,} {what}" for n, what in ((d.invalid, "invalid (left out)"), (d.lost, "lost"))]
    click.echo(f"{out}: {d.t_ns.size:,} samples of {device}; " + ", ".join(extra))
