"""`imud calibrate accel|gyro|temp|mag|apply`: estimate a device's calibration from a recording
(offline, `--from FILE.csv`) or from the running daemon (`--device NAME`: its uncorrected stream),
print the estimate with its uncertainty, residuals and verdict, and write the device's file.

Exit codes: 0 accepted and written; 2 bad input (arguments, CSV, config); 3 the data did not
support a calibration (the reason is printed; nothing is written); 1 no daemon (live).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import click
import numpy as np

from imud.cli.common import EXIT_USAGE, _connect, _fail, _new_file, _prefix, _recorded_device

if TYPE_CHECKING:
    from imud.calib.file import CalibrationFile

EXIT_REFUSED = 3
Units = dict[str, Any]


def _units(f: Any) -> Any:
    f = click.option(
        "--accel-units",
        type=click.Choice(["m/s2", "g"]),
        default="m/s2",
        show_default=True,
        help="accel columns of --from",
    )(f)
    f = click.option(
        "--gyro-units",
        type=click.Choice(["rad/s", "dps"]),
        default="rad/s",
        show_default=True,
        help="gyro columns of --from",
    )(f)
    f = click.option(
        "--mag-units",
        type=click.Choice(["T", "uT"]),
        default="T",
        show_default=True,
        help="mag columns of --from",
    )(f)
    f = click.option(
        "--time-units",
        type=click.Choice(["s", "ms", "us", "ns"]),
        help="time column of --from whose name does not say its unit (time, timestamp, t)",
    )(f)
    return click.option(
        "--rate",
        "rate_hz",
        type=click.FloatRange(min=0, min_open=True),
        help="sample rate, Hz, of --from's sample counter (n_samples, ...) when it has no time",
    )(f)


def _source(f: Any) -> Any:
    for opt in reversed(
        [
            click.option(
                "--from",
                "from_csv",
                type=click.Path(dir_okay=False, exists=True),
                help="offline: a recording (docs/recording-csv.md), or imu_tk's accelerometer "
                "file (t x y z counts; then --gyro-from and --accel-counts/--gyro-counts)",
            ),
            click.option(
                "--format",
                "source_format",
                type=click.Choice(["auto", "csv", "imu_tk"]),
                default="auto",
                show_default=True,
                help="--from's format: a CSV recording, or imu_tk's text files; auto tells them "
                "by the first line",
            ),
            click.option(
                "--gyro-from",
                type=click.Path(dir_okay=False, exists=True),
                help="imu_tk's gyroscope file, the pair of --from's",
            ),
            click.option(
                "--accel-counts",
                help="imu_tk's files: accelerometer counts per m/s^2 and the count that reads "
                "zero, e.g. 414,32768",
            ),
            click.option(
                "--mag-counts",
                type=click.FloatRange(min=0.0, min_open=True),
                help="the magnetometer columns are raw counts, this many a microtesla (e.g. 30 "
                "for a QMC5883L at +-8 G)",
            ),
            click.option(
                "--gyro-counts",
                help="imu_tk's files: gyroscope counts per rad/s and the count that reads zero, "
                "e.g. 4770,32768",
            ),
            click.option("--device", help="live: a device of the running daemon"),
            click.option(
                "--shots",
                is_flag=True,
                help="--from is a shot list: each row one reading of a still pose (accel, mag), "
                "no time needed",
            ),
            click.option(
                "--out",
                type=click.Path(dir_okay=False),
                help="calibration file to write or update (default: the device's "
                "`calibration` in --config)",
            ),
            click.option(
                "--config",
                "config_path",
                type=click.Path(dir_okay=False),
                help="the daemon's config: where --device's calibration file is",
            ),
            click.option(
                "--chip", help="the chip the file is for (offline, when the CSV does not say)"
            ),
            click.option(
                "--duration",
                type=click.FloatRange(min=1.0),
                default=None,
                help="live: stop capturing after this many seconds",
            ),
            click.option(
                "--json",
                "as_json",
                is_flag=True,
                help="print the estimate, covariance, residuals and verdict as JSON",
            ),
            click.option(
                "--plot",
                type=click.Path(dir_okay=False),
                help="draw the fit to a PNG (needs the `plot` extra: matplotlib)",
            ),
            click.option("--dry-run", is_flag=True, help="estimate and print; write nothing"),
            _connect,
            _prefix,
        ]
    ):
        f = opt(f)
    return _units(f)


def _gravity_opts(f: Any) -> Any:
    f = click.option("--gravity", type=float, help="local g, m/s^2")(f)
    f = click.option(
        "--latitude", type=click.FloatRange(-90, 90), help="geodetic latitude, deg (normal gravity)"
    )(f)
    return click.option("--height", type=float, help="height above the ellipsoid, m")(f)


class _CalibrateGroup(click.Group):
    """The calibrate commands, where a recording too large for this machine's memory ends in a
    message and the fix, never a traceback (the CSV reader asks first; this is for what a
    procedure allocates after it)."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except MemoryError:
            _fail(
                "out of memory: the recording is too large for this machine; a calibration "
                "needs minutes of data, not hours: cut it (its first million rows: "
                "`head -n 1000001 FILE > part.csv`)",
                EXIT_USAGE,
                "--json" in sys.argv[1:],  # the subcommand's own flag, gone with its context
            )


@click.group(cls=_CalibrateGroup)
def calibrate() -> None:
    """Estimate calibrations (accel, gyro, temp, mag) and apply them to recordings.

    Live (--device) the procedure reads the daemon's uncorrected stream; offline (--from) a CSV
    recording from imud or any tool (--accel-units/--gyro-units/--mag-units read other units).
    The estimate is printed with its uncertainty and residuals and a verdict; when accepted, the
    device's calibration file is written or updated (the daemon picks it up at once)."""


# the columns each procedure reads: the rest of a recording may be absent
_NEEDS = {"mag": ("mag",), "accel": ("accel",), "gyro": ("gyro",)}
_HOLDS = {"mag": "magnetometer", "temp": "temperature"}


class Job:
    """One procedure run: where the data comes from, where the result goes."""

    def __init__(self, kind: str, opts: dict[str, Any]) -> None:
        self.kind = kind
        self.o = opts
        self.as_json = bool(opts["as_json"])
        from_mcap = opts["from_csv"] is not None and _is_mcap(opts["from_csv"])
        if (opts["from_csv"] is None) == (opts["device"] is None) and not from_mcap:
            _fail(
                "give --from FILE.csv (offline) or --device NAME (live), one of the two "
                "(--from FILE.mcap takes --device for which of its devices)",
                EXIT_USAGE,
                self.as_json,
            )
        self.from_mcap = from_mcap
        self.chip: str | None = opts.get("chip")
        self.device_name: str | None = opts.get("device")
        self.out: Path | None = Path(opts["out"]) if opts.get("out") else None
        if opts.get("plot"):
            _check_plot_path(Path(opts["plot"]), self.as_json)
        self._from_config()

    def _from_config(self) -> None:
        cp = self.o.get("config_path")
        if cp is None:
            return
        from imud.cli.common import _load

        cfg = _load(cp)
        # the daemon this config runs: reach it where it listens, under its prefix
        ctx = click.get_current_context()
        if ctx.get_parameter_source("endpoint") == click.core.ParameterSource.DEFAULT:
            # a loopback listener is this machine's daemon; one on another address is left to
            # --connect (an unspecified address says nothing about where to connect)
            listen = [e for e in cfg.zenoh.listen if e.startswith("tcp/127.")]
            if listen:
                self.o["endpoint"] = listen[0]
        if ctx.get_parameter_source("prefix") == click.core.ParameterSource.DEFAULT:
            self.o["prefix"] = cfg.zenoh.prefix
        name = self.device_name
        if name is None:
            if self.out is None:
                _fail(
                    "--config needs --device (whose calibration file to write), or give --out",
                    EXIT_USAGE,
                    self.as_json,
                )
            return
        dev = next((d for d in cfg.device if d.name == name), None)
        if dev is None:
            _fail(
                f"{cp} has no device {name!r} (its devices: "
                f"{', '.join(d.name for d in cfg.device)})",
                EXIT_USAGE,
                self.as_json,
            )
        self.chip = self.chip or dev.chip
        if self.out is None:
            if dev.calibration is None:
                _fail(
                    f"device {name!r} in {cp} has no `calibration` file: add one "
                    '(e.g. calibration = "imu0.cal.toml") or give --out',
                    EXIT_USAGE,
                    self.as_json,
                )
            self.out = dev.calibration

    def recording(self, live: Any = None) -> Any:
        from imud.calib.csvio import CsvError, read_comments, read_csv
        from imud.calib.imutk import is_imu_tk

        fmt = self.o.get("source_format", "auto")
        if self.from_mcap:
            return self._mcap(Path(self.o["from_csv"]))
        if self.o["from_csv"] is not None:
            looks = is_imu_tk(Path(self.o["from_csv"]))
            if looks and self.kind in ("mag", "temp") and fmt != "csv":
                _fail(
                    f"{self.o['from_csv']} is imu_tk's format (t x y z counts of an "
                    f"accelerometer or a gyro): it holds no {_HOLDS[self.kind]}; give a CSV "
                    "recording with those columns (docs/recording-csv.md)",
                    EXIT_USAGE,
                    self.as_json,
                )
            if fmt == "imu_tk" and not looks:
                _fail(
                    f"--format imu_tk, but {self.o['from_csv']} is not imu_tk's format (its first "
                    "line is not four numbers t x y z): give --format csv (or auto)",
                    EXIT_USAGE,
                    self.as_json,
                )
            if fmt == "imu_tk" or (fmt == "auto" and looks):
                return self._imu_tk(Path(self.o["from_csv"]))
            if fmt == "csv" and looks:
                _fail(
                    f"{self.o['from_csv']}: --format csv, but its first line is four numbers "
                    "and no header, imu_tk's format: give --format imu_tk (or auto)",
                    EXIT_USAGE,
                    self.as_json,
                )
        if self.o.get("gyro_from") is not None:
            _fail(
                f"--gyro-from goes with imu_tk's files, and {self.o['from_csv']} is not one "
                "(its first line is not four numbers t x y z): give the CSV alone",
                EXIT_USAGE,
                self.as_json,
            )
        if self.o["from_csv"] is not None:
            path = Path(self.o["from_csv"])
            try:
                comments = read_comments(path)
                rec = read_csv(
                    path,
                    self.o["accel_units"],
                    self.o["gyro_units"],
                    self.o["mag_units"],
                    time_units=self.o["time_units"],
                    rate_hz=self.o["rate_hz"],
                    # a recording holds what it measured: a magnetometer session needs no more
                    need=_NEEDS.get(self.kind, ("accel", "gyro")),
                    mag_per_ut=self.o.get("mag_counts"),
                    untimed_rate_hz=1.0 if self.o.get("shots") else None,  # rows, not time
                    accel_counts=self._counts("accel"),
                    gyro_counts=self._counts("gyro"),
                )
            except CsvError as e:
                _fail(str(e), EXIT_USAGE, self.as_json)
            if comments.get("samples", "").startswith("corrected"):
                _fail(
                    f"{path} holds corrected samples (recorded without --raw): calibrate from "
                    "uncorrected ones (`imud record DEVICE --raw`)",
                    EXIT_USAGE,
                    self.as_json,
                )
            self.chip = self.chip or comments.get("chip")
            self.device_name = self.device_name or comments.get("device")
            return rec
        return live(self)

    def check_shots(self, strict: bool, holdout: bool) -> None:
        """--shots with what it cannot go with: a usage error, said before any work."""
        if not self.o.get("shots"):
            return
        why = None
        if self.kind not in ("accel", "mag"):
            why = f"--shots: a shot list calibrates accel or mag; {self.kind} needs a stream"
        elif self.o["from_csv"] is None:
            why = "--shots reads a file (--from): a live capture is a stream"
        elif strict:
            why = (
                "--strict tests the residuals against the noise within each pose, and a shot list "
                "has one reading a pose: drop --strict (the residuals' RMS is judged against the "
                "tolerance)"
            )
        elif holdout:
            why = (
                "--holdout/--compare need still windows to split, and a shot list has one reading "
                "a pose: drop them"
            )
        if why is not None:
            _fail(why, EXIT_USAGE, self.as_json)

    def grade(self) -> Any:
        """The sensor's grade for the default tolerances: --grade, else the chip's, else
        consumer (imud.calib.acceptance.Grade)."""
        from imud.calib.acceptance import Grade

        if self.o.get("grade"):
            return Grade(self.o["grade"])
        if self.chip:
            from imud import registry

            spec = registry.CHIPS.get(self.chip)
            if spec is not None:
                return Grade(spec.grade)
        return Grade.CONSUMER

    def _mcap(self, path: Path) -> Any:
        """A device of an MCAP recording (imud record -o), its samples as recorded."""
        rec, chip, name = read_mcap_device(path, self.o.get("device"), self.as_json)
        self.chip = self.chip or chip
        self.device_name = name
        return rec

    def _counts(self, sensor: str) -> tuple[float, float] | None:
        """--accel-counts / --gyro-counts, parsed (a bad one is a usage error, said)."""
        from imud.calib.imutk import ImuTkError, parse_counts

        text = self.o.get(f"{sensor}_counts")
        if text is None:
            return None
        try:
            return parse_counts(text, sensor)
        except ImuTkError as e:
            _fail(str(e), EXIT_USAGE, self.as_json)

    def _imu_tk(self, accel_path: Path) -> Any:
        """imu_tk's pair of files (docs/recording-csv.md "imu_tk's files")."""
        from imud.calib.imutk import ImuTkError, parse_counts, read_imu_tk
        from imud.units import STANDARD_GRAVITY

        missing = [
            flag
            for flag, key in (
                ("--gyro-from GYRO_FILE", "gyro_from"),
                ("--accel-counts PER_UNIT,ZERO", "accel_counts"),
                ("--gyro-counts PER_UNIT,ZERO", "gyro_counts"),
            )
            if self.o.get(key) is None
        ]
        if missing:
            _fail(
                f"{accel_path} is imu_tk's format (t x y z counts): give {', '.join(missing)} "
                "(e.g. --accel-counts 414,32768 --gyro-counts 4770,32768 for its Xsens data)",
                EXIT_USAGE,
                self.as_json,
            )
        try:
            return read_imu_tk(
                accel_path,
                Path(self.o["gyro_from"]),
                parse_counts(self.o["accel_counts"], "accel"),
                parse_counts(self.o["gyro_counts"], "gyro"),
                (self.o["accel_units"], self.o["gyro_units"]),
                self.o.get("gravity") or STANDARD_GRAVITY,
            )
        except ImuTkError as e:
            _fail(str(e), EXIT_USAGE, self.as_json)

    def existing(self) -> CalibrationFile:
        """The calibration file this run updates, read once (procedures consult it before
        fitting, and `finish` updates it)."""
        if self._existing is None:
            self._existing = self._read_existing()
        return self._existing

    _existing: CalibrationFile | None = None

    def _read_existing(self) -> CalibrationFile:
        from imud.calib.file import CalibrationError, CalibrationFile, load_or_new

        if self.out is None:
            if self.o["dry_run"]:
                return CalibrationFile(chip=self.chip, device=self.device_name)
            _fail(
                "give --out CAL.toml (or --config with --device) to say where the calibration "
                "goes; --dry-run only prints it",
                EXIT_USAGE,
                self.as_json,
            )
        try:
            return load_or_new(self.out, self.chip, self.device_name)
        except CalibrationError as e:
            _fail(f"{e} (fix or move it: it would be updated)", EXIT_USAGE, self.as_json)

    def finish(self, outcome: Any, gravity_note: str | None, notes: list[str], source: str) -> None:
        from imud.calib.file import write_calibration

        report = {
            "kind": self.kind,
            "source": source,
            **outcome.report,
            "accepted": outcome.accepted,
            "reasons": outcome.reasons,
            "notes": [*outcome.report.get("notes", []), *notes],
        }
        if gravity_note:
            report["gravity_source"] = gravity_note
        if self.o.get("plot"):  # before the file: a plot that fails leaves nothing half done
            _plot(self.kind, outcome, Path(self.o["plot"]), self.as_json)
        written = None
        if outcome.accepted and not self.o["dry_run"]:
            from imud.calib.file import CalibrationError

            try:
                cf = outcome.update(self.existing(), source)
            except CalibrationError as e:  # a fit no file can hold: said, nothing written
                _fail(f"not written: {e}", EXIT_REFUSED, self.as_json)
            assert self.out is not None
            write_calibration(self.out, cf)
            written = str(self.out)
        report["written"] = written
        if self.as_json:
            click.echo(json.dumps(report, indent=2))
        else:
            from imud.cli.calibrate_view import show

            show(report)
        sys.exit(0 if outcome.accepted else EXIT_REFUSED)


# what matplotlib writes, by the file's suffix
_PLOT_FORMATS = ("png", "pdf", "svg", "jpg", "jpeg", "webp", "tif", "tiff", "eps", "ps")


def _check_plot_path(path: Path, as_json: bool) -> None:
    """--plot's file, checked before any work: a format matplotlib writes, in a directory that
    exists, and matplotlib installed."""
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in _PLOT_FORMATS:
        _fail(
            f"--plot {path}: name a picture file ({', '.join('.' + f for f in _PLOT_FORMATS)}), "
            "e.g. fit.png",
            EXIT_USAGE,
            as_json,
        )
    if not path.parent.is_dir():
        _fail(f"--plot {path}: no directory {path.parent}", EXIT_USAGE, as_json)
    try:
        import matplotlib  # noqa: F401
    except ImportError as e:
        _fail(f"--plot needs matplotlib: pip install 'imud[plot]' ({e})", EXIT_USAGE, as_json)


def _plot(kind: str, outcome: Any, path: Path, as_json: bool) -> None:
    from imud.calib.plot import draw

    try:
        draw(kind, outcome, path)
    except (OSError, ValueError) as e:  # the disk, permissions: nothing else was written
        _fail(f"--plot {path}: not drawn ({e}); no calibration written", EXIT_USAGE, as_json)


def _compare_file(
    path: str | None, as_json: bool, sensor: str = "accel", job: Job | None = None
) -> Any:
    """The calibration file --compare names, read (a bad one is a usage error, said): imud's,
    or imu_tk's (T K B in counts), applied through --accel-counts / --gyro-counts."""
    if path is None:
        return None
    from imud.calib.file import CalibrationError, CalibrationFile, SensorTable, read_calibration
    from imud.calib.imutk import is_imu_tk_calibration, read_imu_tk_calibration

    if is_imu_tk_calibration(Path(path)):
        counts = None if job is None else job._counts(sensor)
        if job is None or counts is None:
            _fail(
                f"--compare {path} is imu_tk's calibration (of counts): give --{sensor}-counts "
                "PER_UNIT,ZERO, the nominal scale the recording was read with, so it applies",
                EXIT_USAGE,
                as_json,
            )
        units = job.o.get(f"{sensor}_units")
        unit_si = {"g": job.o.get("gravity") or 9.80665, "dps": math.pi / 180}.get(units or "", 1.0)
        matrix, bias = read_imu_tk_calibration(Path(path), counts, float(unit_si))
        table = SensorTable(
            bias=tuple(bias.tolist()),
            matrix=tuple(tuple(r) for r in matrix.tolist()),
            source=f"imu_tk: {path}",
        )
        return CalibrationFile(**{sensor: table})

    try:
        cf = read_calibration(Path(path))
    except CalibrationError as e:
        _fail(str(e), EXIT_USAGE, as_json)
    if cf.sensor(sensor) is None:
        _fail(f"--compare {path}: the file has no [{sensor}] table to compare", EXIT_USAGE, as_json)
    return cf


def _refused(e: Exception, as_json: bool) -> None:
    if as_json:
        click.echo(json.dumps({"accepted": False, "reasons": [str(e)], "written": None}))
    else:
        click.echo(f"imud: refused: {e}", err=True)
    sys.exit(EXIT_REFUSED)


def _prepared(job: Job, rec: Any) -> tuple[Any, list[str]]:
    """The recording with the device file's temperature polynomials applied (notes say so)."""
    from imud.calib.procedure import compensate

    return (rec, []) if job.out is None else compensate(rec, job.existing())


def _grade(f: Any) -> Any:
    return click.option(
        "--grade",
        type=click.Choice(["consumer", "industrial", "tactical"]),
        help="the sensor's class, which sets the default tolerances (default: the chip's own, "
        "else consumer; docs/calibration.md)",
    )(f)


def _significance(f: Any) -> Any:
    return click.option(
        "--significance",
        type=click.FloatRange(min=1e-12, max=0.5),
        default=0.01,
        show_default=True,
        help="chance of refusing a right calibration by chance (the p threshold of the residual "
        "tests and of the still check's slow-turn test)",
    )(f)


def _min_still(f: Any) -> Any:
    return click.option(
        "--min-still",
        type=click.FloatRange(min=0.5),
        default=2.0,
        show_default=True,
        help="seconds a pose must be held still to count",
    )(f)


def _gravity(job: Job, gravity: float | None, lat: float | None, h: float | None) -> Any:
    from imud.calib.procedure import local_gravity

    try:
        return local_gravity(gravity, lat, h)
    except ValueError as e:
        _fail(str(e), EXIT_USAGE, job.as_json)


# --- the procedures ------------------------------------------------------------------------------


@calibrate.command()
@_source
@_gravity_opts
@click.option(
    "--model",
    type=click.Choice(["full", "axes"]),
    default="full",
    show_default=True,
    help="full: 9 parameters from >= 9 orientations; axes: the six faces (Ferraris)",
)
@_min_still
@click.option(
    "--poses",
    type=click.IntRange(min=6),
    default=12,
    show_default=True,
    help="live: distinct orientations to capture before fitting",
)
@_significance
@click.option(
    "--strict",
    is_flag=True,
    help="accept only residuals that are the poses' noise alone (a lab set-up); by default a "
    "model error within --tolerance-mg is accepted and reported",
)
@click.option(
    "--tolerance-mg",
    type=click.FloatRange(min=0.0, max=1000.0),
    help="the model error accepted beyond the noise, mg per residual component (default for "
    "--model full by --grade: 5 consumer, 2 industrial, 1 tactical; 17.5 per axis for axes: a "
    "pose up to about 1.7 deg off its face)",
)
@_grade
@click.option(
    "--holdout",
    is_flag=True,
    help="also judge the fit on still windows it did not see (each pose split in time, two "
    "folds): |a| - g beside the uncalibrated data and the seed's six-face method",
)
@click.option(
    "--compare",
    "compare_path",
    type=click.Path(dir_okay=False, exists=True),
    help="a calibration file (imud's) judged on the same held-out windows; implies --holdout",
)
def accel(
    gravity: float | None,
    latitude: float | None,
    height: float | None,
    model: str,
    min_still: float,
    poses: int,
    significance: float,
    strict: bool,
    tolerance_mg: float | None,
    holdout: bool,
    compare_path: str | None,
    **opts: Any,
) -> None:
    """Accelerometer bias, scale and misalignment from still poses against local gravity.
    The residuals are judged as the poses' noise plus a model-error floor (poses a little off,
    drift), reported in mg and accepted within --tolerance-mg; --strict for the noise alone."""
    from imud.calib.acceptance import MG, Acceptance
    from imud.calib.procedure import run_accel
    from imud.calib.still import CalibrationRefused

    job = Job("accel", opts)
    job.check_shots(strict, holdout or compare_path is not None)
    g, note = _gravity(job, gravity, latitude, height)
    from imud.cli.calibrate_live import capture_poses

    def missing(ivs: list[Any]) -> str | None:
        """Why these poses cannot give the fit yet (None: they can)."""
        from imud.calib.accel import fit_accel_intervals

        try:
            res = fit_accel_intervals(ivs, g, model)  # type: ignore[arg-type]
        except CalibrationRefused as e:
            return str(e)
        if res.estimate.fit.residuals["dof"] <= 0:  # exact: untestable, so not yet
            return res.estimate.verdict.reasons[0]
        return None

    rec = job.recording(lambda j: capture_poses(j, poses, min_still, missing))
    rec, notes = _prepared(job, rec)
    try:
        tolerance = None if tolerance_mg is None else tolerance_mg * MG
        acceptance = Acceptance(strict, significance, tolerance, job.grade())
        compare = _compare_file(compare_path, job.as_json, "accel", job)
        outcome = run_accel(
            rec,
            g,
            model,  # type: ignore[arg-type]
            min_s=min_still,
            acceptance=acceptance,
            holdout=holdout,
            compare=compare,
            shots=bool(opts.get("shots")),
        )
    except CalibrationRefused as e:
        _refused(e, job.as_json)
    job.finish(outcome, note, notes, rec.source)


@calibrate.command()
@_source
@click.option(
    "--full-turns",
    is_flag=True,
    help="each rotation between still poses was a whole number of turns "
    "(a turntable or Ferraris session): gives the scale about the vertical too",
)
@_min_still
@click.option(
    "--latitude",
    type=click.FloatRange(-90.0, 90.0),
    help="degrees north: model Earth's rotation (15 deg/h), which MEMS-grade turns and still "
    "poses can resolve",
)
@_significance
@click.option(
    "--strict",
    is_flag=True,
    help="accept only rotations whose residuals are the noise alone; by default a model error "
    "within --tolerance-deg is accepted and reported",
)
@click.option(
    "--tolerance-deg",
    type=click.FloatRange(min=0.0, max=90.0),
    help="the model error accepted beyond the noise on each component of a rotation's carried "
    "gravity direction, degrees (default 1: a direction error up to 1.4 deg)",
)
@click.option(
    "--tolerance-dph",
    type=click.FloatRange(min=0.0, max=36000.0),
    help="with --latitude: the scatter of the still poses' gyro means accepted beyond their "
    "noise (the bias drifting through the session), deg/h (default by --grade: 360 consumer, "
    "100 industrial, 10 tactical)",
)
@_grade
@click.option(
    "--holdout",
    is_flag=True,
    help="also judge the fit on rotations it did not see (the recording's two halves, each "
    "judging the other's fit): the gravity direction each carries, in degrees, beside the "
    "uncalibrated gyro and the seed's bias-only correction",
)
@click.option(
    "--compare",
    "compare_path",
    type=click.Path(dir_okay=False, exists=True),
    help="a calibration file (imud's) whose gyro is judged on the same rotations; implies "
    "--holdout",
)
def gyro(
    full_turns: bool,
    min_still: float,
    latitude: float | None,
    significance: float,
    strict: bool,
    tolerance_deg: float | None,
    tolerance_dph: float | None,
    holdout: bool,
    compare_path: str | None,
    **opts: Any,
) -> None:
    """Gyro bias from still data (its standard error from the data's own noise); with rotations
    between still poses, also scale and misalignment."""
    from imud.calib.procedure import gyro_needs_more, run_gyro
    from imud.calib.still import CalibrationRefused

    job = Job("gyro", opts)
    job.check_shots(False, False)
    from imud.cli.calibrate_live import capture_for

    def more(r: Any) -> str | None:
        """Live, after 30 s: what the full fit still needs (the file's accel applied)."""
        cf = job.existing() if job.out is not None else None
        return gyro_needs_more(r, full_turns, cf, min_still, latitude)

    rec = job.recording(lambda j: capture_for(j, 30.0, more=more))
    rec, notes = _prepared(job, rec)
    cf = job.existing() if job.out is not None else None
    try:
        from imud.calib.acceptance import Acceptance

        tolerance = None if tolerance_deg is None else math.radians(tolerance_deg)
        bias_tolerance = None if tolerance_dph is None else math.radians(tolerance_dph) / 3600
        acceptance = Acceptance(strict, significance, tolerance, job.grade(), bias_tolerance)
        compare = _compare_file(compare_path, job.as_json, "gyro", job)
        outcome = run_gyro(
            rec, full_turns, cf, min_still, latitude, significance, acceptance, holdout, compare
        )
    except CalibrationRefused as e:
        _refused(e, job.as_json)
    job.finish(outcome, None, notes, rec.source)


@calibrate.command()
@_source
@click.option(
    "--sensor", type=click.Choice(["accel", "gyro", "both"]), default="both", show_default=True
)
@click.option("--max-order", type=click.IntRange(1, 3), default=3, show_default=True)
def temp(sensor: str, max_order: int, **opts: Any) -> None:
    """Bias against temperature (polynomial per axis, order chosen by the fit) from a still
    recording across a temperature span."""
    from imud.calib.procedure import run_temp
    from imud.calib.still import CalibrationRefused

    job = Job("temp", opts)
    job.check_shots(False, False)
    from imud.cli.calibrate_live import capture_for

    rec = job.recording(lambda j: capture_for(j, 600.0, show_temperature=True))
    sensors: tuple[Literal["accel", "gyro"], ...] = (
        ("accel", "gyro") if sensor == "both" else (sensor,)  # type: ignore[assignment]
    )
    try:
        outcome = run_temp(rec, sensors, max_order)
    except CalibrationRefused as e:
        _refused(e, job.as_json)
    job.finish(outcome, None, [], rec.source)


@calibrate.command()
@_source
@click.option(
    "--field-ut",
    type=click.FloatRange(min=1, max=1000),
    help="the local field magnitude (e.g. from a geomagnetic model), microtesla",
)
@click.option(
    "--strict",
    is_flag=True,
    help="accept only residuals that are the noise alone; by default a model error within "
    "--tolerance-ut is accepted and reported",
)
@click.option(
    "--tolerance-ut",
    type=click.FloatRange(min=0.0, max=1000.0),
    help="the model error accepted beyond the noise, uT (default 3 % of the fitted field, "
    "about 1.7 deg of heading)",
)
@_grade
def mag(field_ut: float | None, strict: bool, tolerance_ut: float | None, **opts: Any) -> None:
    """Magnetometer hard and soft iron (full ellipsoid) from a recording rotated through many
    directions."""
    from imud.calib.procedure import run_mag
    from imud.calib.still import CalibrationRefused

    job = Job("mag", opts)
    job.check_shots(strict, False)
    from imud.cli.calibrate_live import capture_for

    rec = job.recording(lambda j: capture_for(j, 90.0, need_mag=True))
    if rec.mag is None:
        _fail(f"{rec.source}: no magnetometer data (mx, my, mz)", EXIT_USAGE, job.as_json)
    rec, notes = _prepared(job, rec)
    try:
        from imud.calib.acceptance import Acceptance

        tolerance = None if tolerance_ut is None else tolerance_ut * 1e-6
        acceptance = Acceptance(strict, 0.01, tolerance, job.grade())
        field = None if field_ut is None else field_ut * 1e-6
        outcome = run_mag(rec, field, acceptance, shots=bool(opts.get("shots")))
        if opts.get("mag_counts"):  # the centre where the file's counts put it, as users quote it
            per_ut = float(opts["mag_counts"])
            outcome.report["centre_counts"] = [b * 1e6 * per_ut for b in outcome.report["bias"]]
    except CalibrationRefused as e:
        _refused(e, job.as_json)
    job.finish(outcome, None, notes, rec.source)


@calibrate.command("apply")
@click.option("--calibration", "cal_path", required=True, type=click.Path(dir_okay=False))
@click.option("--from", "from_csv", required=True, type=click.Path(dir_okay=False, exists=True))
@click.option("--out", required=True, type=click.Path(dir_okay=False))
@click.option("--device", help="--from FILE.mcap: which of its devices")
@_units
def apply_cmd(
    cal_path: str,
    from_csv: str,
    out: str,
    device: str | None,
    accel_units: str,
    gyro_units: str,
    mag_units: str,
    time_units: str | None,
    rate_hz: float | None,
) -> None:
    """Apply a calibration file to an uncorrected recording with exactly the daemon's code
    (imud.pipeline.correct), writing the corrected recording."""
    from imud.calib.csvio import CsvError, CsvWriter, read_comments, read_csv
    from imud.calib.file import CalibrationError, load_calibration, read_calibration
    from imud.channels import Channel, SampleFlag
    from imud.pipeline import correct

    _new_file(Path(out), "--out")
    try:
        cal = load_calibration(Path(cal_path))
        source: dict[str, str] = {}
        from_mcap = _is_mcap(from_csv)
        if from_mcap:  # a recording: the device's samples, as the offline fits read it
            rec, chip, name = read_mcap_device(Path(from_csv), device, False)
            source = {"device": name, "chip": chip or "?", "source": from_csv}
            made_for = read_calibration(Path(cal_path)).chip
            if chip and made_for and made_for != chip:
                _fail(
                    f"{cal_path} is a calibration of a {made_for}, and {name} in {from_csv} is "
                    f"a {chip}: give that device's calibration",
                    EXIT_USAGE,
                )
        else:
            rec = read_csv(
                Path(from_csv),
                accel_units,  # type: ignore[arg-type]
                gyro_units,  # type: ignore[arg-type]
                mag_units,  # type: ignore[arg-type]
                time_units=time_units,  # type: ignore[arg-type]
                rate_hz=rate_hz,
            )
    except (CalibrationError, CsvError) as e:
        _fail(str(e), EXIT_USAGE)
    si = {Channel.ACCEL: rec.accel, Channel.GYRO: rec.gyro}
    if rec.temp is not None:
        si[Channel.TEMPERATURE] = rec.temp
    if rec.mag is not None:
        si[Channel.MAG] = rec.mag
    period_s = 1.0 / rec.rate_hz
    chans, clamped, _ = correct(cal, si, rec.n, None, period_s)
    flags = np.zeros(rec.n, dtype=np.uint32)
    if clamped is not None:
        flags[clamped] |= np.uint32(SampleFlag.TEMPERATURE_OUTSIDE_CALIBRATION)
    comments = {
        **(source if from_mcap else read_comments(Path(from_csv))),
        "samples": f"corrected with {cal_path}",
    }
    comments.pop("format", None)
    with CsvWriter(
        Path(out),
        has_temp=rec.temp is not None,
        has_mag=rec.mag is not None,
        has_flags=True,
        comments=comments,
    ) as w:
        w.write(
            rec.t_ns,
            chans[Channel.ACCEL],
            chans[Channel.GYRO],
            rec.temp,
            chans.get(Channel.MAG),
            flags,
        )
    n_out = int(np.count_nonzero(flags))
    click.echo(
        f"{out}: {rec.n} samples corrected"
        + (f"; {n_out} outside the calibration's temperature span (flagged)" if n_out else "")
    )


def _is_mcap(path: str) -> bool:
    from imud.recording.reader import is_mcap

    return is_mcap(Path(path))


def read_mcap_device(path: Path, name: str | None, as_json: bool) -> tuple[Any, str | None, str]:
    """(the calibration Recording, the chip, the device) of one device of an MCAP recording; a
    file that is not one, a device not in it, or corrected samples end in a usage error."""
    from imud.calib.csvio import SATURATED_MASK
    from imud.calib.recording import Recording
    from imud.recording.export import device_data
    from imud.recording.reader import McapInputError, open_recording

    try:
        rec = open_recording(path)
        if rec.warning:
            click.echo(f"imud: {rec.warning}", err=True)
        name = _recorded_device(rec, name, as_json)
        # what a calibration is fitted to: the uncorrected stream where it was recorded
        d = device_data(rec, name, raw=name in rec.raw)
    except McapInputError as e:
        _fail(str(e), EXIT_USAGE, as_json)
    if d.calibrated:
        _fail(
            f"{path}: {name}'s samples were corrected by a calibration when recorded; "
            "calibrate from uncorrected ones: record with --raw (`imud record -o F.mcap --raw`)",
            EXIT_USAGE,
            as_json,
        )
    n = d.t_ns.size
    absent = np.full((n, 3), np.nan)
    samples = Recording(
        d.t_ns,
        absent if d.accel is None else d.accel,
        absent.copy() if d.gyro is None else d.gyro,
        d.temp[:, 0] if d.temp is not None and d.temp.ndim == 2 else d.temp,
        d.mag,
        (d.flags & np.uint32(SATURATED_MASK)) != 0,
        f"{path} ({name})",
    )
    return samples, rec.info.get(name, {}).get("chip"), name
