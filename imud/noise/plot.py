"""`imud noise --plot out.png`: the Allan deviation per axis on log-log axes, the fitted terms'
lines with their slopes, and the datasheet's white noise beside (its Allan N = density / sqrt(2),
one-sided convention). matplotlib is the optional `plot` extra, imported only here."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from imud.noise.allan import AllanResult
from imud.noise.fit import B_FLOOR, SLOPE, AxisFit, basis

INSTALL = "pip install 'imud[plot]'"


class PlotUnavailable(RuntimeError):
    """matplotlib is not installed: the message says how to install it."""


def _pyplot() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")  # a file, never a window: works over ssh and in CI
        import matplotlib.pyplot as plt
    except ImportError as e:
        raise PlotUnavailable(f"--plot needs matplotlib: {INSTALL} ({e})") from None
    return plt


def plot(
    r: AllanResult,
    fits: list[AxisFit],
    path: Path,
    title: str,
    datasheet: dict[str, float] | None = None,
) -> None:
    """Two panels (gyro, accel), three axes each, written to `path` (PNG by its suffix)."""
    plt = _pyplot()
    fig, panels = plt.subplots(1, 2, figsize=(10, 4.2), dpi=80)
    colours = ("tab:red", "tab:green", "tab:blue")
    sensors = (("gyro", "rad/s"), ("accel", "m/s²"))
    t = np.geomspace(r.tau_s[0], r.tau_s[-1], 200)
    for s, (ax, (name, unit)) in enumerate(zip(panels, sensors, strict=True)):
        for k in range(3):
            col = 3 * s + k
            ax.loglog(r.tau_s, r.adev[:, col], "o", ms=2.5, color=colours[k],
                      label=f"{'xyz'[k]}")  # fmt: skip
            ax.loglog(t, fits[col].model(t), "-", lw=0.8, color=colours[k], alpha=0.7)
        # each resolved term's line, on the worst axis, labelled with its slope and value
        worst = max(range(3), key=lambda k: fits[3 * s + k].terms["N"].value)
        f = fits[3 * s + worst]
        b = basis(t)
        for j, term in enumerate(("Q", "N", "B", "K", "R")):
            x = f.terms[term]
            if x.lo <= 0.0:
                continue
            line = np.sqrt(b[:, j]) * x.value
            keep = line > 0.3 * f.model(t)  # only where the term matters
            if not keep.any():
                continue
            slope = SLOPE[term]
            label = f"{term} = {x.value:.3g} (slope {slope:+g})"
            if term == "B":
                label = f"B = floor/{B_FLOOR:.3f} = {x.value:.3g}"
            ax.loglog(t[keep], line[keep], "--", lw=1.0, color="0.3")
            i = int(np.flatnonzero(keep)[len(np.flatnonzero(keep)) // 2])
            ax.annotate(label, (t[i], line[i]), fontsize=7, color="0.2",
                        xytext=(4, 4), textcoords="offset points")  # fmt: skip
        if datasheet and name in datasheet:
            n = datasheet[name] / math.sqrt(2.0)
            ax.loglog(t, n / np.sqrt(t), ":", lw=1.2, color="k",
                      label=f"datasheet N = {n:.3g}")  # fmt: skip
        ax.set_xlabel("τ (s)")
        ax.set_ylabel(f"Allan deviation ({unit})")
        ax.set_title(name, fontsize=10)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7, loc="lower left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
