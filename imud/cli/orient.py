"""`imud orient FILE [--device NAME] [--out OUT.csv|OUT.mcap]`: the orientation filter run offline
on a recording (an MCAP file, a split one's parts, or imud's CSV), the same stage the daemon
runs with `[device.orientation]`, fed the recording's own batches."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click
import numpy as np

from imud.cli.common import EXIT_USAGE, _fail, _named, _new_file, _recorded_device


@click.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--device", help="the device (needed when the file holds more than one)")
@click.option(
    "--out",
    type=click.Path(dir_okay=False),
    help="write each sample's orientation: .csv (t_ns, quaternion, covariance) or .mcap (the "
    "device's batches with the orientation channels, and imu/data when the recording kept the "
    "daemon's config)",
)
@click.option("--update-hz", type=click.FloatRange(min=0.1, max=200.0), help="corrections a second")
@click.option("--no-mag", is_flag=True, help="leave the magnetometer out (heading from the start)")
@click.option("--json", "as_json", is_flag=True, help="the summary as JSON")
def orient(
    paths: tuple[str, ...],
    device: str | None,
    out: str | None,
    update_hz: float | None,
    no_mag: bool,
    as_json: bool,
) -> None:
    """Run imud's orientation filter on a recording."""
    from imud.calib.csvio import CsvError
    from imud.recording.reader import McapInputError, is_mcap, open_recordings

    files = [Path(p) for p in paths]
    for f in files:
        if not f.is_file():
            _fail(f"{f}: no such file", EXIT_USAGE, as_json)
    out_path = None if out is None else Path(out)
    if out_path is not None:
        if out_path.suffix.lower() not in (".csv", ".mcap"):
            _fail(f"--out {out_path}: name a .csv or a .mcap file", EXIT_USAGE, as_json)
        _new_file(out_path, "--out", as_json)
    over: dict[str, Any] = {}
    if update_hz is not None:
        over["update_hz"] = update_hz
    if no_mag:
        over["magnetometer"] = False
    try:
        if is_mcap(files[0]):
            rec = open_recordings(files)
            if rec.warning and not as_json:
                click.echo(f"imud: {rec.warning}", err=True)
            name = _recorded_device(rec, device, as_json)
            summary = _from_mcap(rec, name, over, out_path)
            source = _named(rec)
        else:
            if len(files) > 1:
                _fail("several CSV files: give one (or the parts of one MCAP)", EXIT_USAGE)
            summary = _from_csv(files[0], over, out_path)
            source = str(files[0])
    except (McapInputError, CsvError, ValueError) as e:
        _fail(str(e), EXIT_USAGE, as_json)
    summary = {"source": source, **summary}
    if out_path is not None:
        summary["out"] = str(out_path)
    if as_json:
        click.echo(json.dumps(summary))
        return
    _print(summary)


def _settings(base: dict[str, Any] | None, over: dict[str, Any]) -> Any:
    from imud.settings import Orientation

    fields = {k: v for k, v in (base or {}).items() if k != "enabled"}
    return Orientation(**{**fields, **over, "enabled": True})


def _stage(chip: str | None, device_cfg: Any, settings: Any) -> Any:
    """The stage with the chip's datasheet noise at the recorded settings (defaults for a
    chip imud does not know)."""
    from imud import registry
    from imud.orient.stage import OrientationStage, noise_model

    figures = None
    spec = registry.CHIPS.get(chip or "")
    if spec is not None and spec.noise is not None and device_cfg is not None:
        figures = spec.noise(device_cfg)
    noise = noise_model(
        None if figures is None else figures.gyro_density,
        None if figures is None else figures.accel_density,
        None if figures is None else figures.mag_sigma_t,
        settings.gyro_bias_walk,
    )
    return OrientationStage(settings, noise, None)


def _recorded_device_config(rec: Any, name: str) -> tuple[Any, dict[str, Any] | None]:
    """The device's config as the daemon ran it (None when the recording kept none) and its
    `[device.orientation]` table."""
    from imud.config import parse_config

    kept = rec.daemon_config()
    if kept is None:
        return None, None
    raw, _ = kept
    tables = [d for d in raw.get("device", []) if d.get("name") == name]
    if not tables:
        return None, None
    table = dict(tables[0])
    table.pop("calibration", None)  # a path on the recording machine; the noise needs none
    try:
        cfg = parse_config({"device": [table]}).device[0]
    except Exception:  # a config of another imud version: the datasheet's defaults then
        return None, tables[0].get("orientation")
    return cfg, tables[0].get("orientation")


def _from_mcap(rec: Any, name: str, over: dict[str, Any], out: Path | None) -> dict[str, Any]:
    from imud.channels import Channel
    from imud.wire import decode, encode

    cfg, table = _recorded_device_config(rec, name)
    chip = rec.info.get(name, {}).get("chip") or (None if cfg is None else cfg.chip)
    settings = _settings(table, over)
    stage = _stage(chip, cfg, settings)
    writer = _McapWriter(rec, name, out) if out is not None and out.suffix == ".mcap" else None
    rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    period = None
    lost = 0
    try:
        for _, _, wire in rec.batches([name]):
            b = decode(wire)
            if not b.count or b.get(Channel.GYRO) is None:
                continue
            if b.count > 1:
                period = float(np.median(np.diff(b.t_ns))) / 1e9
            if period is None:
                continue  # a lone first sample: its rate is unknown yet
            ch = {c: a.astype(np.float64) for c, a in b.channels.items()}
            ch = stage.run(ch, period, b.lost_before)
            lost += b.lost_before
            q, cov = ch[Channel.ORIENTATION], ch[Channel.ORIENTATION_COVARIANCE]
            rows.append((b.t_ns, q, cov))
            if writer is not None:
                flags = b.sample_flags
                chans = {**b.channels, Channel.ORIENTATION: q, Channel.ORIENTATION_COVARIANCE: cov}
                writer.add(
                    encode(
                        name,
                        b.first_seq,
                        b.t_ns,
                        chans,
                        flags,
                        kind=b.kind,
                        flags=b.flags,
                        lost_before=b.lost_before,
                    )
                )
    finally:
        if writer is not None:
            writer.close()
    if not rows:
        raise ValueError(f"{rec.path}: {name} has no gyro samples to integrate")
    t = np.concatenate([r[0] for r in rows])
    q = np.concatenate([r[1] for r in rows])
    cov = np.concatenate([r[2] for r in rows])
    if out is not None and out.suffix == ".csv":
        _write_csv(out, t, q, cov, {"device": name, "chip": str(chip), "source": str(rec.path)})
    return _summary(stage, t, q, cov, lost, name, chip, writer)


def _from_csv(path: Path, over: dict[str, Any], out: Path | None) -> dict[str, Any]:
    from imud.calib.csvio import read_comments, read_csv
    from imud.config import parse_config
    from imud.orient.offline import orient

    if out is not None and out.suffix == ".mcap":
        _fail(f"--out {out}: a CSV recording gives a CSV (an MCAP holds imud's batches)", 2)
    comments = read_comments(path)
    chip = comments.get("chip")
    cfg = None
    if chip:
        try:
            table = {"name": "csv", "chip": chip, "bus": {"kind": "sim"}}
            cfg = parse_config({"device": [table]}).device[0]
        except Exception:  # a chip imud does not know: the default noise
            cfg = None
    rec = read_csv(path, need=("accel", "gyro"))
    settings = _settings(None, over)
    stage = _stage(chip, cfg, settings)
    mag = rec.mag if rec.mag is not None and not np.isnan(rec.mag).any() else None
    o = orient(stage, rec.t_ns, rec.gyro, rec.accel, mag)
    if out is not None:
        _write_csv(out, o.t_ns, o.orientation, o.covariance, {"source": str(path)})
    return _summary(stage, o.t_ns, o.orientation, o.covariance, o.lost, "csv", chip, None)


class _McapWriter:
    """The oriented batches into a new MCAP the way `imud record` writes them (the native
    topic, the recording's attachments and device descriptions), with imu/data when the
    recording kept the daemon's config."""

    def __init__(self, rec: Any, name: str, out: Path) -> None:
        from imud.recording.mcapfile import Attachment, McapOut

        info = dict(rec.info.get(name, {}))
        channels = list(info.get("channels", []))
        for key in ("orientation", "orientation_covariance"):
            if key not in channels:
                channels.append(key)
        info["channels"] = channels
        meta = {
            "imud": {"devices": name, "oriented_from": str(rec.path)},
            "imud.devices": {name: json.dumps(info)},
        }
        atts = [Attachment(n, _media(n), data) for n, data in rec.attachments.items()]
        self.out = McapOut(out, atts, meta)
        self.name = name
        self.ros2 = self._ros2(rec, name)

    def _ros2(self, rec: Any, name: str) -> Any:
        from imud.config import parse_config
        from imud.ros2.messages import Ros2Messages

        kept = rec.daemon_config()
        if kept is None:
            return None
        raw, _ = kept
        devices = [dict(d) for d in raw.get("device", []) if d.get("name") == name]
        if not devices:
            return None
        d = devices[0]
        d.pop("calibration", None)
        d["orientation"] = {**d.get("orientation", {}), "enabled": True}
        d["ros2"] = {**d.get("ros2", {}), "enabled": True}
        try:
            cfg = parse_config({"ros2": {**raw.get("ros2", {}), "enabled": True}, "device": [d]})
        except Exception:
            return None
        return Ros2Messages(cfg, self._ros, diagnostics=False)

    def _ros(self, topic: Any, msgs: Any) -> None:
        size = msgs.records.dtype.itemsize
        self.out.add_many(topic.name, topic.type_name, msgs.stamps_ns, msgs.records.tobytes(), size)

    def add(self, wire: bytes) -> None:
        from imud.recording.recorder import native_topic
        from imud.recording.schemas import BATCH, batch_cdr
        from imud.wire import peek

        _, n, _, last_ns, _ = peek(wire)
        if n:
            self.out.add(native_topic("imud", self.name), BATCH, last_ns, batch_cdr(wire))
            if self.ros2 is not None:
                self.ros2.batch(self.name, wire)

    def close(self) -> None:
        if self.ros2 is not None:
            self.ros2.flush()
        self.out.close()


def _write_csv(
    path: Path, t: np.ndarray, q: np.ndarray, cov: np.ndarray, about: dict[str, str]
) -> None:
    """t_ns, the quaternion (w, x, y, z, body to world ENU) and the world-frame error
    covariance (rad^2); empty fields before the filter's start."""
    header = ["t_ns", "qw", "qx", "qy", "qz", "cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz",
              "cov_zz"]  # fmt: skip
    with open(path, "w") as f:
        for k, v in about.items():
            f.write(f"# {k}: {v}\n")
        f.write("# orientation: imud orient (docs/orientation.md); quaternion body -> world ENU\n")
        f.write(",".join(header) + "\n")
        vals = np.column_stack([q, cov])
        text = np.char.mod("%.9g", vals)
        text[np.isnan(vals)] = ""
        lines = [
            ",".join([str(ti), *row]) for ti, row in zip(t.tolist(), text.tolist(), strict=True)
        ]
        f.write("\n".join(lines) + "\n")


def _summary(
    stage: Any, t: np.ndarray, q: np.ndarray, cov: np.ndarray, lost: int, name: str,
    chip: str | None, writer: Any,
) -> dict[str, Any]:  # fmt: skip
    from imud.orient.metrics import yaw_deg

    ok = ~np.isnan(q[:, 0])
    last = q[ok][-1:] if ok.any() else None
    out: dict[str, Any] = {
        "device": name,
        "chip": chip,
        "samples": int(t.shape[0]),
        "oriented": int(ok.sum()),
        "lost": lost,
        "filter": stage.status(),
    }
    if last is not None:
        w, x, y, z = last[0].tolist()
        roll = math.degrees(math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
        pitch = math.degrees(math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))))
        out["last"] = {
            "t_ns": int(t[ok][-1]),
            "quaternion_wxyz": [round(v, 7) for v in last[0].tolist()],
            "roll_deg": round(roll, 3),
            "pitch_deg": round(pitch, 3),
            "yaw_deg": round(float(yaw_deg(last)[0]), 3),
            "tilt_sigma_deg": round(math.degrees(math.sqrt(cov[ok][-1, 0] + cov[ok][-1, 3])), 4),
        }
    if writer is not None and writer.ros2 is None:
        out["note"] = "the recording kept no daemon config: the MCAP has no imu/data topic"
    return out


def _print(s: dict[str, Any]) -> None:
    f = s["filter"]
    click.echo(
        f"{s['source']}: {s['device']} ({s['chip']}): {s['oriented']:,} of {s['samples']:,} "
        f"samples oriented, {s['lost']:,} lost"
    )
    bias = " ".join(f"{math.degrees(b):.4f}" for b in f["bias_rad_s"])
    click.echo(
        f"  filter {f['state']}, heading {f['heading']}; gyro bias {bias} deg/s; gravity "
        f"{f['accel_updates']} used {f['accel_rejected']} rejected"
        + (
            f", field {f['mag_updates']} used {f['mag_rejected']} rejected"
            if f["mag_updates"] or f["mag_rejected"]
            else ""
        )
    )
    last = s.get("last")
    if last:
        click.echo(
            f"  last: roll {last['roll_deg']:.2f} pitch {last['pitch_deg']:.2f} yaw "
            f"{last['yaw_deg']:.2f} deg (tilt sigma {last['tilt_sigma_deg']:.3f} deg)"
        )
    if s.get("out"):
        click.echo(f"  written: {s['out']}")
    if s.get("note"):
        click.echo(f"  note: {s['note']}")


def _media(name: str) -> str:
    return "application/toml" if name.endswith(".toml") else "application/octet-stream"
