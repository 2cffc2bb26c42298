"""imud's orientation filter against imufusion (Fusion) and ahrs (Madgwick, Mahony, EKF) on the
simulated scenarios with known truth: tilt error, yaw drift, the consistency of imud's stated
covariance (NEES) and the cost per sample of each filter's loop. Prints Markdown to stdout.

    .venv/bin/python bench/orient_compare.py --seeds 5 --plots docs/img

Frames: the scenarios are ENU (z up), body FLU. imufusion runs with CONVENTION_NWU; its
quaternions are turned into ENU by the fixed rotation Rz(+90 deg) (north is NWU's x and ENU's
y), so with a magnetometer its heading is compared with the truth's as it is. ahrs Madgwick and
Mahony (no magnetometer) and ahrs EKF (frame='NED', the setting that converges on +g-on-z data)
return body -> z-up world quaternions whose heading starts wherever the filter started it: tilt
is unaffected, and the yaw drift (the change of the wrapped ZYX yaw error from 5 s to the end)
does not see a constant heading offset.
"""

from __future__ import annotations

import argparse
import inspect
import math
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path

import numpy as np
import numpy.typing as npt

import imud
from imud.orient.ekf import NoiseModel, OrientationFilter
from imud.orient.metrics import align_heading, nees, tilt_error_deg, world_error, yaw_deg
from imud.rotations import quat_mul
from imud.sim import scenarios
from imud.sim.scenarios import G, Scenario

F64 = npt.NDArray[np.float64]

T_FROM = 5.0  # s: metrics cover t >= T_FROM
NEES_EVERY = 2.5  # s: NEES sample times
BATCH = 32  # the daemon's batch for a 1 kHz ICM-42688-P
# imud corrects once a batch has taken the interval past 1/update_hz: 1 and 25 divide its 100
# samples (corrections at 10 Hz), 8 gives 104, 32 and 128 give 128 (7.8 Hz)
BATCH_SWEEP = (1, 8, 25, 32, 128)
REPEATS = 3  # throughput: median of this many runs
# NWU -> ENU: north (NWU x) is ENU y, a quarter turn about z
NWU_TO_ENU = np.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])

Bias = tuple[float, float, float] | None
SCENARIOS: list[tuple[str, Callable[[int, Bias], Scenario]]] = [
    ("reference", lambda seed, b=None: scenarios.reference(seed, bias_deg_s=b)),
    ("drone_hover", lambda seed, b=None: scenarios.drone_hover(seed, bias_deg_s=b)),
    ("car", lambda seed, b=None: scenarios.car(seed, bias_deg_s=b)),
    ("drone_hover+mag", lambda seed, b=None: scenarios.drone_hover(seed, mag=True, bias_deg_s=b)),
    ("car+mag", lambda seed, b=None: scenarios.car(seed, mag=True, bias_deg_s=b)),
]
# the NEES runs: each truth a draw from imud's own prior (a Monte Carlo NEES tests consistency
# only then): its gyro bias from N(0, bias_sigma) per axis, constant, so the model's bias walk
# is set near zero; the accuracy runs keep the scenarios' fixed 0.3-0.5 deg/s
NEES_BIAS_WALK = 1e-7


def prior_bias(seed: int) -> tuple[float, float, float]:
    sigma = inspect.signature(OrientationFilter).parameters["bias_sigma"].default
    b = np.degrees(np.random.default_rng(10_000 + seed).normal(0.0, sigma, 3))
    return (float(b[0]), float(b[1]), float(b[2]))


FILTERS = ["imud", "imufusion", "ahrs Madgwick", "ahrs Mahony", "ahrs EKF"]
# not a filter of its own: imufusion with its rejections off, to tell the setting from the method
FUSION_NO_REJECTION = "imufusion, rejection 0"
ACCURACY = [*FILTERS[:2], FUSION_NO_REJECTION, *FILTERS[2:]]
# the car's speed changes and turns (imud.sim.scenarios.car, including their 1-s ramps), s
CAR_MANOEUVRES = [(2, 6), (8, 16), (20, 23), (30, 34), (36, 44), (50, 54)]
COLOURS = {"imud": "C0", "imufusion": "C1", FUSION_NO_REJECTION: "C1", "ahrs Madgwick": "C3",
           "ahrs Mahony": "C4", "ahrs EKF": "C2"}  # fmt: skip


@dataclass
class Run:
    q: F64  # (n, 4) body -> world (z up; ENU for imud and imufusion)
    seconds: float  # the filter's loop alone (time.perf_counter)
    cpu: float  # the same, time.process_time: what another process's load does not inflate
    cov: F64 | None = None  # imud: (n, 6) world-frame covariance
    counters: dict[str, int] = field(default_factory=dict)


# --- the filters ---------------------------------------------------------------------------
def run_imud(s: Scenario, batch: int = BATCH, bias_walk: float | None = None) -> Run:
    noise = NoiseModel(gyro=s.gyro_density, accel=s.accel_density, mag=s.mag_sigma)
    if bias_walk is not None:
        noise = NoiseModel(noise.gyro, noise.accel, bias_walk, noise.mag)
    f = OrientationFilter(noise)
    n = s.gyro.shape[0]
    q = np.empty((n, 4))
    cov = np.empty((n, 6))
    gyro, accel, mag, dt = s.gyro, s.accel, s.mag, s.dt
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(0, n, batch):
        j = min(i + batch, n)
        q[i:j], cov[i:j] = f.step(gyro[i:j], accel[i:j], dt, None if mag is None else mag[i:j])
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return Run(q, seconds, cpu, cov, dict(vars(f.counters)))


def run_imufusion(s: Scenario, rejection: float = 10.0) -> Run:
    import imufusion

    rate = s.rate_hz
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(
        imufusion.AhrsSettings(
            sample_rate=rate,
            convention=imufusion.CONVENTION_NWU,
            gain=0.5,
            gyroscope_range=2000,
            acceleration_rejection=rejection,
            magnetic_rejection=rejection if s.mag is not None else 0,
            rejection_timeout=5.0,
        )
    )
    bias = imufusion.Bias()
    bias.set_settings(imufusion.BiasSettings(sample_rate=rate))
    gyro = np.ascontiguousarray(np.degrees(s.gyro))  # deg/s
    accel = np.ascontiguousarray(s.accel / G)  # g
    n = gyro.shape[0]
    q = np.empty((n, 4))
    t0, c0 = time.perf_counter(), time.process_time()
    if s.mag is None:
        for k in range(n):
            ahrs.update_no_magnetometer(bias.update(gyro[k]), accel[k])
            q[k] = ahrs.get_quaternion()
    else:
        mag = np.ascontiguousarray(s.mag * 1e6)  # uT
        for k in range(n):
            ahrs.update(bias.update(gyro[k]), accel[k], mag[k])
            q[k] = ahrs.get_quaternion()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    q = quat_mul(np.broadcast_to(NWU_TO_ENU, q.shape), q)
    q /= np.linalg.norm(q, axis=1, keepdims=True)  # float32 from the library
    return Run(q, seconds, cpu)


def run_ahrs(kind: str, s: Scenario) -> Run:
    from ahrs.filters import EKF, Madgwick, Mahony

    t0, c0 = time.perf_counter(), time.process_time()
    if kind == "ahrs Madgwick":
        q = Madgwick(gyr=s.gyro, acc=s.accel, frequency=s.rate_hz).Q
    elif kind == "ahrs Mahony":
        q = Mahony(gyr=s.gyro, acc=s.accel, frequency=s.rate_hz).Q
    else:
        q = EKF(gyr=s.gyro, acc=s.accel, frequency=s.rate_hz, frame="NED").Q
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return Run(np.asarray(q, dtype=np.float64), seconds, cpu)


def run(name: str, s: Scenario) -> Run:
    if name == "imud":
        return run_imud(s)
    if name == "imufusion":
        return run_imufusion(s)
    if name == FUSION_NO_REJECTION:
        return run_imufusion(s, rejection=0.0)
    return run_ahrs(name, s)


# --- metrics -------------------------------------------------------------------------------
def wrap(deg: F64) -> F64:
    out: F64 = (deg + 180.0) % 360.0 - 180.0
    return out


@dataclass
class Metrics:
    tilt_rms: float
    tilt_max: float
    yaw_drift: float
    heading_rms: float  # absolute (ZYX yaw) error: meaningful with a magnetometer only
    heading_max: float
    nan_after: int  # NaN orientations at t >= T_FROM (should be 0)


def metrics(q: F64, s: Scenario) -> Metrics:
    i0 = int(np.searchsorted(s.t_s, T_FROM - 1e-9))
    tilt = tilt_error_deg(q, s.truth)[i0:]
    yaw_err = wrap(yaw_deg(q) - yaw_deg(s.truth))[i0:]
    bad = int(np.isnan(tilt).sum())
    return Metrics(
        tilt_rms=float(np.sqrt(np.nanmean(tilt**2))),
        tilt_max=float(np.nanmax(tilt)),
        yaw_drift=float(wrap(np.array(yaw_err[-1] - yaw_err[0]))),
        heading_rms=float(np.sqrt(np.nanmean(yaw_err**2))),
        heading_max=float(np.nanmax(np.abs(yaw_err))),
        nan_after=bad,
    )


def nees_samples(r: Run, s: Scenario) -> tuple[F64, F64]:
    """imud's tilt (2-dof) and full (3-dof) NEES at t = 5, 7.5, ... s. Without a magnetometer
    the heading is a free gauge: the truth is turned about the vertical to agree with the
    estimate at the filter's first output (where it states a zero heading variance)."""
    assert r.cov is not None
    idx = np.searchsorted(s.t_s, np.arange(T_FROM, s.t_s[-1] + 1e-9, NEES_EVERY) - 1e-9)
    truth = s.truth
    if s.mag is None:
        first = int(np.argmax(~np.isnan(r.q[:, 0])))
        truth = align_heading(r.q, truth, at=first)
    err = world_error(r.q[idx], truth[idx])
    return nees(err, r.cov[idx], slice(0, 2)), nees(err, r.cov[idx])


def chi2_quantile(p: float, k: float) -> float:
    try:
        from scipy.stats import chi2

        return float(chi2.ppf(p, k))
    except ImportError:  # Wilson-Hilferty
        z = statistics.NormalDist().inv_cdf(p)
        a = 2.0 / (9.0 * k)
        return k * (1.0 - a + z * math.sqrt(a)) ** 3


def nees_row(samples: list[F64], dof: int) -> tuple[str, ...]:
    """ANEES over seeds at each time against the 95 % band of chi2(dof * seeds) / seeds."""
    m = len(samples)
    avg = np.mean(np.vstack(samples), axis=0)
    lo = chi2_quantile(0.025, dof * m) / m
    hi = chi2_quantile(0.975, dof * m) / m
    inside = float(np.mean((avg >= lo) & (avg <= hi)))
    above = float(np.mean(avg > hi))
    below = float(np.mean(avg < lo))
    return (
        f"{dof}",
        f"{lo:.2f}-{hi:.2f}",
        f"{np.median(avg):.2f}",
        f"{avg.min():.2f} / {avg.max():.2f}",
        f"{inside:.0%}",
        f"{above:.0%}",
        f"{below:.0%}",
    )


# --- output --------------------------------------------------------------------------------
def table(header: list[str], rows: list[tuple[str, ...]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def mean_worst(values: list[float], signed: bool = False) -> str:
    mean = statistics.fmean(values)
    worst = max(values, key=abs) if signed else max(values)
    return f"{mean:.2f} / {worst:.2f}" if len(values) > 1 else f"{mean:.2f}"


def plot(path: Path, title: str, s: Scenario, runs: dict[str, Run]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w = 20  # samples: each point is the largest error of its 20 ms (vibration aliases otherwise)
    n = (s.t_s.size // w) * w
    t = s.t_s[:n].reshape(-1, w)[:, -1]
    fig, ax = plt.subplots(figsize=(9, 4.4), dpi=90)
    for name, r in runs.items():
        e = tilt_error_deg(r.q[:n], s.truth[:n]).reshape(-1, w)
        worst = np.max(np.where(np.isnan(e), -np.inf, e), axis=1)
        worst[~np.isfinite(worst)] = np.nan  # imud's first second: no orientation, not drawn
        style = "--" if name == FUSION_NO_REJECTION else "-"
        ax.plot(t, worst, style, lw=0.8, color=COLOURS.get(name), label=name)
    ax.axvline(T_FROM, color="0.6", lw=0.6, ls="--")
    if s.name == "car":  # its manoeuvres (imud.sim.scenarios.car): sustained linear acceleration
        for a, b in CAR_MANOEUVRES:
            ax.axvspan(a, b, color="0.92", lw=0, zorder=0)
    ax.set_yscale("log")
    ax.set_ylim(1e-2, 30)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("tilt error (deg), max per 20 ms")
    fig.suptitle(title, fontsize=10)
    ax.grid(True, which="major", lw=0.4, alpha=0.5)
    ax.legend(fontsize=8, ncol=len(runs), loc="lower center", bbox_to_anchor=(0.5, 1.0),
              frameon=False, handlelength=1.5, columnspacing=1.0)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def provenance() -> str:
    """Where imud came from: its commit, and whether the filter and the scenarios differ from it."""
    root = Path(imud.__file__).resolve().parent.parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
            check=True,
        ).stdout.strip()  # fmt: skip
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--", "imud/orient", "imud/sim", "imud/rotations.py"],
            cwd=root, capture_output=True, text=True, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return f"imud from {root} (not a git checkout)"
    state = "modified in the working tree" if dirty else "as committed"
    return f"imud at {head} (imud/orient, imud/sim: {state})"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--quick", action="store_true", help="one seed")
    p.add_argument("--plots", type=Path, metavar="DIR", help="write orient-*.png here")
    args = p.parse_args(argv)
    seeds = list(range(1 if args.quick else args.seeds))

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    # throughput first, on the reference, seed 0; its first runs are also its accuracy runs
    ref0 = scenarios.reference(0)
    cache: dict[tuple[str, int, str], Run] = {}
    cost: list[tuple[str, float, float]] = []  # label, median wall and CPU seconds
    load = [os.getloadavg()[0]]

    def timed(label: str, key: tuple[str, int, str], fn: Callable[[], Run]) -> None:
        say(f"throughput: {label}")
        rs = [fn() for _ in range(REPEATS)]
        cache.setdefault(key, rs[0])
        cost.append((label, statistics.median(r.seconds for r in rs),
                     statistics.median(r.cpu for r in rs)))  # fmt: skip

    for b in (1, 8, 32, 128):
        key = ("reference", 0, "imud" if b == BATCH else f"imud {b}")
        timed(f"imud, batches of {b}", key, lambda b=b: run_imud(ref0, b))
    for name in FILTERS[1:]:
        label = "imufusion (Bias, update, get_quaternion)" if name == "imufusion" else name
        timed(label, ("reference", 0, name), lambda name=name: run(name, ref0))
    mag0 = scenarios.drone_hover(0, mag=True)
    for name in ("imud", "imufusion"):
        timed(f"{name} with magnetometer (drone_hover+mag)", ("drone_hover+mag", 0, name),
              lambda name=name: run(name, mag0))  # fmt: skip
    load.append(os.getloadavg()[0])
    n_ref = ref0.gyro.shape[0]

    acc_rows: list[tuple[str, ...]] = []
    head_rows: list[tuple[str, ...]] = []
    nees_rows: list[tuple[str, ...]] = []
    count_rows: list[tuple[str, ...]] = []
    sweep_rows: list[tuple[str, ...]] = []
    nan_notes: list[str] = []
    for scen, make in SCENARIOS:
        per: dict[str, list[Metrics]] = {f: [] for f in ACCURACY}
        by_batch: dict[int, list[Metrics]] = {b: [] for b in BATCH_SWEEP}
        tilt_n: list[F64] = []
        full_n: list[F64] = []
        counters: dict[str, int] = {}
        for seed in seeds:
            say(f"{scen} seed {seed}")
            s = ref0 if (scen == "reference" and seed == 0) else make(seed)
            runs: dict[str, Run] = {}
            for name in ACCURACY:
                if name == "ahrs EKF" and (scen != "reference" or seed != 0):
                    continue  # slow: the reference's seed 0 only
                r = cache.pop((scen, seed, name), None) or run(name, s)
                runs[name] = r
                m = metrics(r.q, s)
                per[name].append(m)
                if m.nan_after:
                    nan_notes.append(f"{name} on {scen} seed {seed}: {m.nan_after} NaN at t >= 5 s")
            imud = runs["imud"]
            for b in BATCH_SWEEP:
                key = (scen, seed, "imud" if b == BATCH else f"imud {b}")
                rb = imud if b == BATCH else cache.pop(key, None) or run_imud(s, b)
                by_batch[b].append(metrics(rb.q, s))
            sn = make(seed, prior_bias(seed))
            t2, t3 = nees_samples(run_imud(sn, bias_walk=NEES_BIAS_WALK), sn)
            tilt_n.append(t2)
            full_n.append(t3)
            for k, v in imud.counters.items():
                counters[k] = counters.get(k, 0) + v
            if args.plots and seed == 0 and scen in ("car", "drone_hover"):
                args.plots.mkdir(parents=True, exist_ok=True)
                path = args.plots / f"orient-{scen.replace('_', '-')}.png"
                plot(path, f"tilt error, {scen} scenario, seed 0 (metrics from t = 5 s)", s, runs)
                say(f"wrote {path}")
        for name in ACCURACY:
            ms = per[name]
            if not ms:
                continue
            acc_rows.append((
                scen, name, str(len(ms)),
                mean_worst([m.tilt_rms for m in ms]),
                mean_worst([m.tilt_max for m in ms]),
                mean_worst([m.yaw_drift for m in ms], signed=True),
            ))  # fmt: skip
            if scen.endswith("+mag") and name in ("imud", "imufusion", FUSION_NO_REJECTION):
                head_rows.append((
                    scen, name, mean_worst([m.heading_rms for m in ms]),
                    mean_worst([m.heading_max for m in ms]),
                ))  # fmt: skip
        update_hz = inspect.signature(OrientationFilter).parameters["update_hz"].default
        per_interval = round(1.0 / (update_hz * ref0.dt))
        for b, ms in by_batch.items():
            sweep_rows.append((
                scen, str(b), str(-(-per_interval // b) * b),
                mean_worst([m.tilt_rms for m in ms]),
                mean_worst([m.tilt_max for m in ms]),
                mean_worst([m.yaw_drift for m in ms], signed=True),
            ))  # fmt: skip
        nees_rows.append((scen, "tilt", *nees_row(tilt_n, 2)))
        nees_rows.append((scen, "full", *nees_row(full_n, 3)))
        keys = ("accel_updates", "accel_rejected", "recoveries", "mag_updates", "mag_rejected")
        count_rows.append((scen, *(str(counters.get(k, 0)) for k in keys)))

    ns = len(seeds)
    print(f"{provenance()}; imufusion {version('imufusion')}, ahrs {version('ahrs')}, "
          f"numpy {np.__version__}, Python {sys.version.split()[0]}\n")  # fmt: skip
    print(f"## Accuracy (t >= {T_FROM:g} s, degrees; mean / worst over {ns} seed(s))\n")
    print(table(
        ["scenario", "filter", "seeds", "tilt RMS", "tilt max", "yaw drift 5->60 s"], acc_rows
    ))  # fmt: skip
    print(f"\n## imud against its batch size (mean / worst over {ns} seed(s), degrees)\n")
    print(table(
        ["scenario", "batch", "correction every (samples)", "tilt RMS", "tilt max",
         "yaw drift 5->60 s"], sweep_rows,
    ))  # fmt: skip
    print(f"\n## Absolute heading with a magnetometer (ZYX yaw error, t >= {T_FROM:g} s, deg)\n")
    print(table(["scenario", "filter", "RMS", "max abs error"], head_rows))
    print(
        f"\n## imud's NEES (mean over {ns} seed(s) at t = {T_FROM:g}, "
        f"{T_FROM + NEES_EVERY:g}, ... s; band: 95 % of chi2(dof x seeds) / seeds)\n"
    )
    print(table(
        ["scenario", "NEES", "dof", "95 % band", "median", "min / max", "inside", "above",
         "below"], nees_rows,
    ))  # fmt: skip
    print(f"\n## imud's counters (summed over {ns} seed(s))\n")
    print(table(
        ["scenario", "accel updates", "accel rejected", "recoveries", "mag updates",
         "mag rejected"], count_rows,
    ))  # fmt: skip
    print(f"\n## Throughput (the filter's loop alone; median of {REPEATS}, 60 s at 1 kHz)\n")
    rows = []
    for label, wall, cpu in cost:
        us, us_cpu = wall / n_ref * 1e6, cpu / n_ref * 1e6
        rows.append((label, f"{us:.2f}", f"{us_cpu:.2f}", f"{1e6 / us / 1e3:,.1f} k",
                     f"{1e3 / us:,.0f}", f"{us / 10:.2f} %"))  # fmt: skip
    print(table(["filter", "µs / sample", "CPU µs / sample", "samples/s",
                 "x real time at 1 kHz", "one core at 1 kHz"], rows))  # fmt: skip
    print(f"\nµs / sample: time.perf_counter; CPU: time.process_time over the same loop. "
          f"1-minute load average {load[0]:.2f} before the timing, {load[1]:.2f} after "
          f"({os.cpu_count()} CPUs).")  # fmt: skip
    if nan_notes:
        print("\nNaN after the start:\n")
        print("\n".join(f"- {n}" for n in nan_notes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
