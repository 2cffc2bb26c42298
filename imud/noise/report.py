"""What `imud noise` says about the fitted terms: units, discrete values, the figures other tools
and imud itself take, and a Kalibr imu.yaml.

Conventions (docs/noise.md "Which density"):
- N, K, B, Q, R are IEEE 952's (two-sided PSD): N is the Allan deviation's -1/2 line at 1 s.
- Kalibr's `*_noise_density` is the continuous-time strength sigma of E[n(t1) n(t2)] =
  sigma^2 delta(t1 - t2): the Allan N (avar = sigma^2 / tau). Its `*_random_walk` is K. Its
  discrete values at the update rate f are N sqrt(f) and K / sqrt(f).
- imud's own densities (a chip spec's `NoiseFigures`, a calibration's [noise] table, the ROS 2
  covariances) and datasheets' are one-sided: D = sqrt(2) N.
"""

from __future__ import annotations

import math
from typing import Any

from imud.noise.fit import B_FLOOR, AxisFit

SENSORS = (("gyro", "rad/s", "rad"), ("accel", "m/s^2", "m/s"))
AXES = ("x", "y", "z")


def units(base: str, integral: str) -> dict[str, str]:
    """Each term's unit for a sensor whose samples are in `base` (its integral in `integral`)."""
    per_s = {"rad/s": "rad/s^2", "m/s^2": "m/s^3"}.get(base, f"{base}/s")
    return {"Q": integral, "N": f"{base}/sqrt(Hz)", "B": base, "K": f"{per_s}/sqrt(Hz)",
            "R": per_s}  # fmt: skip


def resolved(f: AxisFit, name: str) -> bool:
    """The data show the term: its 95 % interval excludes zero."""
    return f.terms[name].lo > 0.0


def axis_json(f: AxisFit, rate_hz: float, unit: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, t in f.terms.items():
        out[name] = {"value": t.value, "lo95": t.lo, "hi95": t.hi, "unit": unit[name],
                     "resolved": t.lo > 0.0, "interval_tau_s": t.tau_s, "edf": t.edf}  # fmt: skip
    out["N_discrete"] = f.terms["N"].value * math.sqrt(rate_hz)
    out["K_discrete"] = f.terms["K"].value / math.sqrt(rate_hz)
    out["adev_min"] = f.adev_min
    out["tau_min_s"] = f.tau_min_s
    out["B_from_min"] = f.b_from_min
    out["fit_from_tau_s"] = f.tau_lo_s
    return out


def kalibr_figure(f: AxisFit, name: str) -> float:
    """What Kalibr gets for a term: its value, or its 95 % upper bound when the data do not
    resolve it (a random walk too small to show in the record: zero would tell an estimator
    the bias never moves)."""
    t = f.terms[name]
    return t.value if t.lo > 0.0 else t.hi


def summary(
    fits: list[AxisFit], rate_hz: float, datasheet: dict[str, float] | None = None
) -> dict[str, Any]:
    """fits: six axes, gyro x y z then accel x y z. datasheet: one-sided densities
    ("gyro", "accel") of the recorded chip at its settings, when known."""
    out: dict[str, Any] = {"rate_hz": rate_hz, "bias_floor_factor": B_FLOOR,
                           "kalibr": {}, "imud": {}}  # fmt: skip
    for s, (name, base, integral) in enumerate(SENSORS):
        u = units(base, integral)
        axes = fits[3 * s : 3 * s + 3]
        out[name] = {a: axis_json(f, rate_hz, u) for a, f in zip(AXES, axes, strict=True)}
        # the worst axis: what an estimator must allow for on every axis
        out["kalibr"][name] = {
            "noise_density": max(f.terms["N"].value for f in axes),
            "random_walk": max(kalibr_figure(f, "K") for f in axes),
            "random_walk_resolved": all(resolved(f, "K") for f in axes),
        }
        n = [f.terms["N"].value for f in axes]
        out["imud"][name] = {
            "one_sided_density": [math.sqrt(2.0) * v for v in n],
            "unit": u["N"],
            "note": "sqrt(2) N: the density a chip spec's NoiseFigures, a calibration's [noise] "
            "table and the ROS 2 covariances take (one-sided)",
        }
        if datasheet and name in datasheet:
            d = datasheet[name]
            out["imud"][name]["datasheet_one_sided_density"] = d
            out["imud"][name]["datasheet_allan_n"] = d / math.sqrt(2.0)
    return out


def kalibr_yaml(s: dict[str, Any], rostopic: str, source: str) -> str:
    """A Kalibr imu.yaml (kalibr wiki "YAML formats"), the worst axis of each sensor."""
    g, a = s["kalibr"]["gyro"], s["kalibr"]["accel"]

    def note(x: dict[str, Any]) -> str:
        return "" if x["random_walk_resolved"] else " (95 % upper bound: not resolved)"

    return (
        f"# imud noise {source}: the worst axis of each sensor; N is the Allan deviation's\n"
        "# -1/2 line at 1 s, K its +1/2 line at 3 s (IEEE 952), docs/noise.md\n"
        "#Accelerometers\n"
        f"accelerometer_noise_density: {a['noise_density']:.6e}  # m/s^2/sqrt(Hz)\n"
        f"accelerometer_random_walk: {a['random_walk']:.6e}  # m/s^3/sqrt(Hz){note(a)}\n"
        "#Gyroscopes\n"
        f"gyroscope_noise_density: {g['noise_density']:.6e}  # rad/s/sqrt(Hz)\n"
        f"gyroscope_random_walk: {g['random_walk']:.6e}  # rad/s^2/sqrt(Hz){note(g)}\n"
        f"rostopic: {rostopic}\n"
        f"update_rate: {s['rate_hz']:.6g}  # Hz\n"
    )


def _g(v: float) -> str:
    return f"{v:.3g}"


def text(s: dict[str, Any]) -> list[str]:
    """The fit as lines for a terminal."""
    lines = [
        "fitted terms (IEEE 952; 95 % intervals from the equivalent degrees of freedom; "
        "'<' an upper bound: not resolved):"
    ]
    for name, base, integral in SENSORS:
        u = units(base, integral)
        for a in AXES:
            d = s[name][a]
            parts = []
            for t in ("N", "B", "K", "Q", "R"):
                x = d[t]
                if x["resolved"]:
                    parts.append(f"{t} {_g(x['value'])} [{_g(x['lo95'])}, {_g(x['hi95'])}]")
                elif t in ("N", "B", "K"):
                    parts.append(f"{t} <{_g(x['hi95'])}")
            lines.append(f"  {name} {a}: " + "; ".join(parts))
        lines.append(
            f"    units: N {u['N']}, B {u['B']}, K {u['K']}, Q {u['Q']}, R {u['R']}; "
            f"discrete at {s['rate_hz']:g} Hz: N sqrt(f) and K / sqrt(f) in {base}"
        )
        lines.append(
            "    discrete N: " + ", ".join(_g(s[name][a]["N_discrete"]) for a in AXES)
            + f" {base}; B from the curve's minimum / {B_FLOOR:.4f}: "
            + ", ".join(_g(s[name][a]["B_from_min"]) for a in AXES)
        )  # fmt: skip
    lines.append(
        f"B = floor / sqrt(2 ln2 / pi) = floor / {B_FLOOR:.4f}; the fitted B is the floor of the "
        "flicker term alone, the minimum's reading includes the other terms there"
    )
    for name, _, _ in SENSORS:
        i = s["imud"][name]
        line = (
            f"imud's {name} density (one-sided, sqrt(2) N, as covariances and calibrations "
            f"take it): " + ", ".join(_g(v) for v in i["one_sided_density"]) + f" {i['unit']}"
        )
        if "datasheet_one_sided_density" in i:
            line += (
                f"; datasheet {_g(i['datasheet_one_sided_density'])} "
                f"(Allan N {_g(i['datasheet_allan_n'])})"
            )
        lines.append(line)
    return lines
