"""`imud calibrate ... --plot FILE.png`: what a person checks before trusting a calibration.

accel: each pose's residual (|C (m - b)| - g) with its 1-sigma bar; mag: the field cloud before
and after correction against the fitted sphere; temp: each axis's reading against temperature
with the fitted polynomial; gyro: the bias with its uncertainty and, for a full fit, how far each
rotation's predicted gravity direction landed from the measured one. Needs matplotlib (the `plot`
extra); imported only when asked for.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: no display on a robot
import matplotlib.pyplot as plt
import numpy as np


def draw(kind: str, outcome: Any, path: Path) -> None:
    fig = plt.figure(figsize=(10, 6))
    if kind == "accel":
        poses = [p for p in outcome.plot.get("poses", []) if isinstance(p, dict)]
        ax = fig.add_subplot(1, 1, 1)
        r = np.array([p.get("residual", np.nan) for p in poses]) * 1e3
        s = np.array([p.get("sigma", np.nan) for p in poses]) * 1e3
        ax.errorbar(np.arange(1, len(r) + 1), r, yerr=s, fmt="o")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel("pose")
        ax.set_ylabel("|C (m - b)| - g  [mm/s^2]")
        ax.set_title("accelerometer: residual per still pose (1 sigma bars)")
    elif kind == "mag":
        fig.set_size_inches(14, 4.2)
        bias = np.asarray(outcome.plot["bias"])
        raw = (np.asarray(outcome.plot["raw"]) - bias) * 1e6  # centred: the shape is what to see
        cor = raw @ np.asarray(outcome.plot["matrix"]).T
        radius = float(np.median(np.linalg.norm(cor, axis=1)))
        ring = np.linspace(0.0, 2.0 * np.pi, 361)
        lim = 1.15 * float(np.max(np.abs(np.concatenate([raw, cor]))))
        for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
            ax = fig.add_subplot(1, 4, k + 1)
            ax.plot(raw[:, i], raw[:, j], ".", ms=1, alpha=0.5, label="raw, less the fitted centre")
            ax.plot(cor[:, i], cor[:, j], ".", ms=1, alpha=0.5, label="corrected")
            ax.plot(radius * np.cos(ring), radius * np.sin(ring), "k-", lw=0.8, label="|field|")
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_aspect("equal")
            ax.set_xlabel(f"{'xyz'[i]} [uT]")
            ax.set_ylabel(f"{'xyz'[j]} [uT]")
        ax = fig.add_subplot(1, 4, 4)
        ax.plot(np.linalg.norm(raw, axis=1), ".", ms=1, alpha=0.5)
        ax.plot(np.linalg.norm(cor, axis=1), ".", ms=1, alpha=0.5)
        ax.set_xlabel("sample")
        ax.set_ylabel("|m| [uT]")
        handles, labels = fig.axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=3, markerscale=8, frameon=False)
        fig.suptitle("magnetometer: the field before and after the ellipsoid fit")
        fig.tight_layout(rect=(0.0, 0.08, 1.0, 1.0))
        fig.savefig(path, dpi=100)
        plt.close(fig)
        return
    elif kind == "temp":
        temp = np.asarray(outcome.plot["temp"])
        for row, est in enumerate(outcome.plot["estimates"]):
            data = np.asarray(outcome.plot[est.sensor])
            x = np.linspace(est.span_c[0], est.span_c[1], 200)
            for axis in range(3):
                ax = fig.add_subplot(len(outcome.plot["estimates"]), 3, row * 3 + axis + 1)
                y = data[:, axis] - np.median(data[:, axis])
                step = max(1, len(temp) // 5000)
                ax.plot(temp[::step], y[::step], ".", ms=1)
                c = est.coefficients[:, axis]
                fit = sum(c[k] * (x - est.reference_c) ** (k + 1) for k in range(len(c)))
                ax.plot(x, fit - np.median(fit), "r-")
                ax.set_title(f"{est.sensor} {'xyz'[axis]} (order {est.order})")
                ax.set_xlabel("degC")
    else:
        rep = outcome.report
        motions = rep.get("motions") or []
        ax = fig.add_subplot(1, 2 if motions else 1, 1)
        b = np.array(rep["bias"])
        sig = np.array(
            [rep["parameters"].get(n, {"sigma": 0.0})["sigma"] for n in ("b_x", "b_y", "b_z")]
        )
        ax.bar(["x", "y", "z"], np.degrees(b) * 3600, yerr=np.degrees(sig) * 3600)
        ax.set_ylabel("bias [deg/h]")
        ax.set_title("gyro bias (1 sigma)")
        if motions:
            ax = fig.add_subplot(1, 2, 2)
            labels = [f"{m['from_pose']}-{m['to_pose']}" for m in motions]
            ax.bar(labels, [m["residual_deg"] for m in motions])
            ax.set_xlabel("motion (from pose - to pose)")
            ax.set_ylabel("gravity after, predicted - measured [deg]")
            ax.set_title("gyro: each rotation against gravity")
            ax.tick_params(axis="x", rotation=90)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
