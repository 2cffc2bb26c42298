"""How `imud calibrate` prints an estimate: parameters with their 1-sigma uncertainty in units a
person reads (mg and ppm for the accelerometer, deg/h for the gyro, microtesla for the
magnetometer), residuals, the verdict with its reasons, and the seed method beside it."""

from __future__ import annotations

import math
from typing import Any

from rich.console import Console
from rich.table import Table

from imud.units import STANDARD_GRAVITY as G0

# (unit name, factor from SI) for the bias of each sensor
_BIAS_UNIT = {
    "accel": ("mg", 1e3 / G0),
    "gyro": ("deg/h", 180 / math.pi * 3600),
    "mag": ("uT", 1e6),
}


def _fmt(v: float, digits: int = 4) -> str:
    return f"{v:.{digits}g}"


def _params(report: dict[str, Any], sensor: str) -> Table:
    unit, k = _BIAS_UNIT.get(sensor, ("", 1.0))
    t = Table(title="parameters (1 sigma)", title_justify="left", box=None, pad_edge=False)
    for col in ("name", "value", "sigma", ""):
        t.add_column(col, justify="right" if col in ("value", "sigma") else "left")
    for name, p in report.get("parameters", {}).items():
        v, s = p["value"], p["sigma"]
        if name.startswith("b_"):
            extra = f"{v * k:+.4g} +- {s * k:.2g} {unit}"
        elif name.startswith("C_") or name.startswith("c"):
            extra = f"+- {s * 1e6:.3g} ppm" if name.startswith("C_") else ""
        else:
            extra = ""
        t.add_row(name, _fmt(v, 7), _fmt(s, 2), extra)
    return t


def show(report: dict[str, Any], console: Console | None = None) -> None:
    con = console or Console(highlight=False)
    kind = report.get("kind", "")
    con.print(f"[bold]imud calibrate {kind}[/bold] from {report.get('source', '?')}")
    for note in report.get("notes", []):
        con.print(f"  note: {note}")
    if report.get("gravity_source"):
        g = report.get("gravity")
        con.print(f"  gravity: {g if g is not None else ''} ({report['gravity_source']})")
    blocks = list(report["sensors"].values()) if "sensors" in report else [report]
    for r in blocks:
        sensor = r.get("sensor", kind)
        con.print(f"\n[bold]{sensor}[/bold] - {r.get('procedure', '')}")
        if "orientations" in r:
            con.print(f"  distinct orientations: {r['orientations']}")
        if "coverage" in r:
            c = r["coverage"]
            needs = "" if c["required"] is None else f" (needs {c['required']:.0%})"
            con.print(f"  direction coverage: {c['fraction']:.0%}{needs}")
        if "order" in r:
            con.print(
                f"  polynomial order {r['order']} about {r['reference_c']:g} degC, "
                f"span {r['span_c'][0]:g}..{r['span_c'][1]:g} degC"
            )
        con.print(_params(r, sensor))
        res = r.get("residuals", {})
        if res:
            con.print("  residuals: " + ", ".join(f"{k} {_fmt(v)}" for k, v in res.items()))
        held = r.get("holdout")
        if held and "unavailable" in held:
            con.print(f"  held out: not made: {held['unavailable']}")
        elif held:
            names = {"calibrated": "this calibration", "uncalibrated": "uncalibrated",
                     "seed": "seed six-face", "compare": "--compare file"}  # fmt: skip
            parts = [f"{names.get(k, k)} {v * 1e3:.3f}" for k, v in held["rms"].items() if v]
            if sensor == "gyro":
                names["seed"] = "seed bias-only"
                parts = [f"{names.get(k, k)} {v:.3f}" for k, v in held["rms"].items() if v]
                what = f"{held['windows']} rotations, gravity carried, RMS deg"
            else:
                what = f"{held['windows']} still windows, |a| - g RMS, mm/s^2"
            con.print(f"  held out ({what}): " + ", ".join(parts))
            rest = held.get("at_rest_deg_h")
            if rest:
                still = [f"{names.get(k, k)} {v:.1f}" for k, v in rest.items() if v is not None]
                con.print(
                    "    at rest (|rate| in the held-out poses, RMS deg/h): " + ", ".join(still)
                )
            for note in held.get("notes", []):
                con.print(f"    {note}")
        seed = r.get("seed_up_down")
        if seed:
            unit, k = _BIAS_UNIT["accel"]
            b = ", ".join(f"{x * k:+.3g}" for x in seed["bias"])
            s = ", ".join(f"{x:.5f}" for x in seed["scale"])
            con.print(f"  seed up/down (per axis, for comparison): bias [{b}] {unit}, scale [{s}]")
        spread = r.get("field_norm_spread")
        if spread:
            con.print(
                f"  field-norm spread std/mean: corrected {spread['corrected']:.5f}, raw "
                f"{spread['raw']:.5f}, seed min/max {spread['seed_min_max']:.5f}"
            )
        centre = r.get("centre_counts")
        if centre:  # the hard iron in the file's own counts (--mag-counts)
            c = ", ".join(f"{x:.1f}" for x in centre)
            con.print(f"  hard-iron centre: [{c}] counts")
        mm = r.get("seed_min_max")
        if mm:
            b = ", ".join(f"{x * 1e6:+.3g}" for x in mm["bias"])
            con.print(f"  seed min/max (for comparison): hard iron [{b}] uT")
        earth = r.get("earth_rotation")
        if earth:
            if earth.get("earth_rate_note"):
                con.print(f"  {earth['earth_rate_note']}")
            e = earth.get("earth")
            if isinstance(e, dict) and "heading_deg" in e:
                con.print(
                    f"  Earth's rotation modelled: heading {e['heading_deg']:.1f} +- "
                    f"{e.get('heading_sigma_deg', float('nan')):.1f} deg"
                )
        motions = r.get("motions") or []
        if motions:
            con.print("  per rotation: poses, duration s, angle deg, gravity miss deg")
        for m in motions[:40]:
            con.print(
                f"    {m['from_pose']:2d} -> {m['to_pose']:2d} {m['duration_s']:6.1f} "
                f"{m['angle_deg']:7.1f} {m['residual_deg']:8.4f}"
            )
        poses = [p for p in r.get("poses", []) if isinstance(p, dict) and "residual" in p]
        shots = bool(poses) and all(p.get("duration_s") == 0.0 for p in poses)
        if poses:
            where = "reading (data row)" if shots else "start s, held s"
            con.print(f"  per pose: {where}, residual |C(m-b)| - g (its sigma), mm/s^2")
        for k, p in enumerate(poses[:40]):
            t0, dur = p.get("t0_s", float("nan")), p.get("duration_s", float("nan"))
            at = "" if shots else f" at {t0:7.1f} for {dur:5.1f}"
            con.print(
                f"    {k + 1:2d}{at}: {p['residual'] * 1e3:+7.2f} "
                f"({p.get('sigma', float('nan')) * 1e3:.2f})"
            )
    ok = report.get("accepted")
    con.print(
        "\n[bold]verdict:[/bold] " + ("[green]accepted[/green]" if ok else "[red]refused[/red]")
    )
    for why in report.get("reasons", []):
        con.print(f"  - {why}")
    if report.get("written"):
        con.print(f"written: {report['written']}")
    elif ok:
        con.print("not written (--dry-run)")
    else:
        con.print("nothing written")
