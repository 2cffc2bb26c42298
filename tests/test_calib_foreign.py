"""Recordings made with other tools' procedures go through the offline commands unchanged apart
from the unit options (issue 9; docs/recording-csv.md, imud/calib/csvio.py).

- Real rows: the head of imucal's example Ferraris session (tests/data/foreign/, MIT, see the
  README there), a still segment: the gyro bias is the column means, with a verdict.
- A Ferraris session made here from physics, written in imucal's format (sample counter, gyro
  in deg/s, accel in m/s^2, 204.8 Hz, the chip's quantisation): six still faces, then a whole
  turn about each axis done as four 90 deg steps with short stops.
- A hand-held session (a person holding the board in 14 orientations, with hand tremor) in g
  and deg/s with a time column in seconds.
- Other tools' headers (EuRoC/ASL, Kalibr, ROS, phyphox, an Arduino logger), and refusals that
  name the line or column and the fix.

The end-to-end cases run the real CLI in a subprocess, as a user would.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imud.calib.accel import fit_accel
from imud.calib.acceptance import Acceptance
from imud.calib.csvio import CsvError, read_csv
from imud.calib.gyro import fit_gyro_full
from imud.calib.stats import chi2_sf

HEAD = Path(__file__).resolve().parent / "data" / "foreign" / "imucal_still_head.csv"
G = 9.80665  # the gravity the generated sessions live in (the CLI's default)

# imucal's example session: 204.8 Hz; the steps visible in its values: gyro 2000 dps / 32768,
# accel 16 g / 32768 with g taken as 9.81 by whatever converted the counts
IMUCAL_RATE = 204.8
GYRO_LSB_DPS = 2000.0 / 32768.0
ACCEL_LSB = 16.0 * 9.81 / 32768.0
C_NAMES = [f"C_{a}{b}" for a in "xyz" for b in "xyz"]
B_NAMES = ["b_x", "b_y", "b_z"]


def imud(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", *args], capture_output=True, text=True, timeout=120
    )


def report(*args: str) -> tuple[int, dict[str, Any]]:
    r = imud(*args, "--json")
    assert r.stdout.strip(), r.stderr
    out: dict[str, Any] = json.loads(r.stdout)
    return r.returncode, out


def off_by_sigma(rep: dict[str, Any], names: list[str], truth: np.ndarray) -> dict[str, float]:
    """(estimate - truth) / reported sigma, per parameter."""
    p = rep["parameters"]
    return {n: (p[n]["value"] - v) / p[n]["sigma"] for n, v in zip(names, truth, strict=True)}


# --- the real rows -----------------------------------------------------------------------------


def test_real_imucal_rows_give_the_column_means_as_the_gyro_bias() -> None:
    with HEAD.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 300 and [r["n_samples"] for r in rows[:3]] == ["0", "1", "2"]
    axes = ("gyr_x", "gyr_y", "gyr_z")
    dps = {a: [float(r[a]) for r in rows] for a in axes}
    means = [math.radians(statistics.fmean(dps[a])) for a in axes]

    code, rep = report(
        "calibrate", "gyro", "--from", str(HEAD), "--gyro-units", "dps", "--rate", "204.8",
        "--dry-run",
    )  # fmt: skip
    sig = [rep["parameters"][b]["sigma"] for b in B_NAMES]
    for k in range(3):
        assert abs(rep["bias"][k] - means[k]) <= sig[k], (k, rep["bias"][k], means[k], sig[k])

    # The quantiser: one gyro step (0.061 deg/s) against the noise of a sample. Noise of half a
    # step or more dithers it: its error is then nearly uniform (step^2 / 12), independent of
    # the signal and white, and a mean resolves far below one step (a simulated quantised white
    # noise at the data's own sd shows no lag-1 correlation). The data do have one, ~0.25 on
    # every gyro axis: the chip's low-pass filter, not the quantiser. Block averaging sees it:
    # the bias's sigma exceeds the white value sd / sqrt(n) by about an AR(1)'s
    # sqrt((1 + rho) / (1 - rho)), and the segment means' chi-squared stays consistent.
    n = len(rows)
    rng = np.random.default_rng(0)
    lines = []
    for k, a in enumerate(axes):
        x = np.array(dps[a])
        sd = float(np.std(x, ddof=1))
        rho = float(np.corrcoef(x[:-1], x[1:])[0, 1])
        q = quantise(statistics.fmean(dps[a]) + rng.normal(0, sd, n), GYRO_LSB_DPS)
        rho_q = float(np.corrcoef(q[:-1], q[1:])[0, 1])
        white = math.radians(sd) / math.sqrt(n)
        ar1 = math.sqrt((1 + rho) / (1 - rho))
        lines.append(
            f"{a}: sd {sd:.4f} deg/s = {sd / GYRO_LSB_DPS:.2f} steps over {len(set(dps[a]))} "
            f"levels; lag-1 rho {rho:+.3f} (quantised white noise: {rho_q:+.3f}); sigma "
            f"{sig[k]:.3g} rad/s = {sig[k] / white:.2f} x sd/sqrt(n) (AR(1): {ar1:.2f}) = "
            f"{math.degrees(sig[k]) / GYRO_LSB_DPS:.3f} steps"
        )
        assert sd / GYRO_LSB_DPS > 0.5  # dithered: the premise of the quantiser being white
        assert abs(rho_q) < 3.5 / math.sqrt(n) < abs(rho)  # the correlation is the chip's
        assert 0.7 < sig[k] / white / ar1 < 1.4
    res = rep["residuals"]
    verdict = "accepted" if rep["accepted"] else f"refused: {rep['reasons']}"
    print(
        f"\nimucal still head, {n} samples at 204.8 Hz: {verdict}; chi2 of the segment means "
        f"{res['chi2']:.2f} on {res['dof']:.0f} dof (p {res['p_value']:.2f})\n  "
        + "\n  ".join(lines)
    )
    assert code == 0 and rep["accepted"] is True and rep["procedure"] == "gyro-bias"


# --- physics for the generated sessions --------------------------------------------------------

UP = np.array([0.0, 0.0, 1.0])  # world z, up; gravity's reaction (what an accelerometer reads)


def rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations (N, 3, 3) by angles (N,) about one axis (3,)."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    out: np.ndarray = np.eye(3) + s * kx + (1 - c) * (kx @ kx)
    return out


def small_rotations(theta: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) by rotation vectors (N, 3)."""
    angle = np.linalg.norm(theta, axis=1)
    k = theta / np.maximum(angle, 1e-300)[:, None]
    kx = np.zeros((theta.shape[0], 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx -= np.swapaxes(kx, 1, 2)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    out: np.ndarray = np.eye(3) + s * kx + (1 - c) * (kx @ kx)
    return out


@dataclass
class Motion:
    """A board's attitude over time (body to world), built from holds and turns about world
    axes. A turn's rate is a raised cosine: zero rate and zero angular acceleration at both
    ends, as a hand starts and stops."""

    start: np.ndarray
    segments: list[tuple[float, np.ndarray, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.now = self.start.copy()

    def hold(self, seconds: float) -> None:
        self.segments.append((seconds, UP, 0.0))

    def turn(self, axis: np.ndarray, degrees: float, seconds: float) -> None:
        self.segments.append((seconds, axis, math.radians(degrees)))
        self.now = rotation(axis, np.array([math.radians(degrees)]))[0] @ self.now

    def tip_up(self, body_axis: np.ndarray, seconds: float) -> None:
        """Tip the board about the horizontal world axis that brings body_axis up."""
        now = self.now @ body_axis  # where it points in the world
        axis = np.cross(now, UP)
        if np.linalg.norm(axis) < 1e-9:  # pointing straight down: half a turn about world x
            axis = np.array([1.0, 0.0, 0.0])
        angle = math.degrees(math.atan2(float(np.linalg.norm(np.cross(now, UP))), float(now @ UP)))
        self.turn(axis / np.linalg.norm(axis), angle, seconds)

    @property
    def duration(self) -> float:
        return sum(s[0] for s in self.segments)

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Attitude (N, 3, 3) and body angular rate (N, 3) at times t."""
        rot = np.empty((t.size, 3, 3))
        rate = np.zeros((t.size, 3))
        r0, t0 = self.start, 0.0
        for seconds, axis, angle in self.segments:
            m = (t >= t0) & (t < t0 + seconds)
            tau = (t[m] - t0) / seconds
            theta = angle * (tau - np.sin(2 * math.pi * tau) / (2 * math.pi))
            rot[m] = rotation(axis, theta) @ r0
            # a turn about a fixed world axis is a turn about a fixed body axis, r0^T axis
            rate[m] = np.outer(angle / seconds * (1 - np.cos(2 * math.pi * tau)), r0.T @ axis)
            r0 = rotation(axis, np.array([angle]))[0] @ r0
            t0 += seconds
        return rot, rate


def sensor(
    a: np.ndarray, b: np.ndarray, x: np.ndarray, sd: float, rng: np.random.Generator
) -> np.ndarray:
    """raw = A x + b + white noise: the calibration that undoes it is C = A^-1 with bias b."""
    out: np.ndarray = x @ a.T + b + rng.normal(0.0, sd, x.shape)
    return out


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    out: np.ndarray = np.round(x / step) * step
    return out


ACC_MIS = np.radians(1.0) * np.array([[0, 0.6, -0.8], [0.4, 0, 0.9], [-0.7, 0.5, 0]])
ACC_A = (np.eye(3) + ACC_MIS) @ np.diag([1.021, 0.984, 1.012])  # misalignment, scale
ACC_B = np.array([0.31, -0.22, 0.18])  # m/s^2
GYR_MIS = np.radians(1.0) * np.array([[0, -0.9, 0.5], [0.7, 0, -0.6], [0.8, 0.4, 0]])
GYR_A = (np.eye(3) + GYR_MIS) @ np.diag([0.975, 1.018, 1.026])
GYR_B = np.radians([-0.59, -0.36, 0.055])  # rad/s, near the real head's bias
EARTH_RATE = 7.292115e-5  # rad/s (WGS84)


# --- an imucal Ferraris session ----------------------------------------------------------------

AXIS = {"x": np.array([1.0, 0, 0]), "y": np.array([0, 1.0, 0]), "z": np.array([0, 0, 1.0])}


def ferraris_motion(hold_s: float = 4.0) -> Motion:
    """imucal's sequence: the faces x_p, x_a, y_p, y_a, z_p, z_a held still on a level table,
    then a whole turn about x, y and z, each axis up on the table so that the turn is about the
    vertical, each done as four 90 deg steps with short stops (shorter than any still pose the
    procedures take), with a still hold before and after."""
    m = Motion(rotation(AXIS["y"], np.array([-math.pi / 2]))[0])  # body x up
    m.hold(hold_s)
    for face in ("-x", "+y", "-y", "+z", "-z"):
        m.tip_up(AXIS[face[1]] * (1.0 if face[0] == "+" else -1.0), 1.5)
        m.hold(hold_s)
    for axis in "xyz":
        m.tip_up(AXIS[axis], 1.5)
        m.hold(hold_s)
        for step in range(4):
            m.turn(UP, 90.0, 1.0)
            if step < 3:
                m.hold(0.6)
        m.hold(hold_s)
    return m


def imucal_session(earth_latitude_deg: float | None, seed: int) -> np.ndarray:
    """The samples (N, 7) as imucal writes them: counter, gyro in deg/s, accel in m/s^2, each
    on its chip's steps. With earth_latitude_deg the gyro also feels Earth's rotation (the
    table's heading is north: the ENU frame)."""
    m = ferraris_motion()
    t = np.arange(0.0, m.duration, 1.0 / IMUCAL_RATE)
    rot, rate = m.sample(t)
    if earth_latitude_deg is not None:
        lat = math.radians(earth_latitude_deg)
        earth = EARTH_RATE * np.array([0.0, math.cos(lat), math.sin(lat)])  # east, north, up
        rate = rate + np.einsum("nji,j->ni", rot, earth)
    f = np.einsum("nji,j->ni", rot, G * UP)  # specific force in the body: R^T (g up)
    rng = np.random.default_rng(seed)
    acc = quantise(sensor(ACC_A, ACC_B, f, 0.02, rng), ACCEL_LSB)
    gyr = quantise(np.degrees(sensor(GYR_A, GYR_B, rate, math.radians(0.045), rng)), GYRO_LSB_DPS)
    out: np.ndarray = np.column_stack([np.arange(t.size), gyr, acc])
    return out


def write_imucal(path: Path, table: np.ndarray) -> None:
    """imucal's header and column order; %.17g reads back as the same doubles."""
    header = "n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"
    np.savetxt(path, table, fmt=["%d"] + ["%.17g"] * 6, delimiter=",", header=header, comments="")


@pytest.fixture(scope="module")
def ferraris_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("imucal") / "ferraris_session.csv"
    write_imucal(path, imucal_session(None, seed=3))
    return path


def test_imucal_ferraris_session_calibrates_accel_then_gyro(
    ferraris_csv: Path, tmp_path: Path
) -> None:
    cal = tmp_path / "imu.cal.toml"
    src = ("--from", str(ferraris_csv), "--gyro-units", "dps", "--rate", "204.8", "--out", str(cal))
    code, acc = report("calibrate", "accel", *src, "--model", "axes")
    assert code == 0 and acc["accepted"] is True and acc["procedure"] == "accel-axes", acc
    z_acc = off_by_sigma(acc, C_NAMES + B_NAMES, np.append(np.linalg.inv(ACC_A).ravel(), ACC_B))
    assert max(map(abs, z_acc.values())) < 4, z_acc

    # the bias's sigma against the Cramer-Rao bound of the six-face model for the poses found:
    # per output axis rows [g e_k, 1] weighted by n_i / sd^2 (white noise and the quantiser's
    # step^2 / 12); the bias is the fourth coefficient
    sd2 = 0.02**2 + ACCEL_LSB**2 / 12
    info = np.zeros((4, 4))
    for pose in acc["poses"]:
        row = np.zeros(4)
        k = int(np.argmax(np.abs(pose["mean"])))
        row[k], row[3] = math.copysign(G, pose["mean"][k]), 1.0
        info += (pose["duration_s"] * IMUCAL_RATE + 1) / sd2 * np.outer(row, row)
    crb_bias = math.sqrt(np.linalg.inv(info)[3, 3])
    for name in B_NAMES:
        assert 0.6 < acc["parameters"][name]["sigma"] / crb_bias < 1.6, name

    # the gyro, with the accelerometer calibration just written correcting gravity's directions
    code, gyr = report("calibrate", "gyro", *src, "--full-turns")
    assert code == 0 and gyr["accepted"] is True and gyr["procedure"] == "gyro-full", gyr
    z_gyr = off_by_sigma(gyr, C_NAMES + B_NAMES, np.append(np.linalg.inv(GYR_A).ravel(), GYR_B))
    assert max(map(abs, z_gyr.values())) < 4, z_gyr
    print(
        f"\nimucal-format Ferraris session: accel {len(acc['poses'])} poses, chi2 "
        f"{acc['residuals']['chi2']:.1f}/{acc['residuals']['dof']:.0f}, worst "
        f"{max(map(abs, z_acc.values())):.1f} sigma; gyro chi2 {gyr['residuals']['chi2']:.1f}/"
        f"{gyr['residuals']['dof']:.0f}, worst {max(map(abs, z_gyr.values())):.1f} sigma"
    )


EARTH_SEEDS = (1, 2, 3, 4, 5, 6)


def test_earth_rotation_in_a_ferraris_session(tmp_path: Path) -> None:
    """The same session as a real one at imucal's lab (latitude 49.6 N) would record it: the
    gyro also measures Earth's rotation, 7.3e-5 rad/s, which a 6 s whole turn integrates to
    4e-4 rad (three times the turn's noise at this grade) and which each still pose's gyro mean
    holds as seen from that pose. Given the latitude, the fit models it (one more parameter, the
    table's heading: imud/calib/gyro.py) and holds the truth within its uncertainty; the table
    faces north with body y north in the first pose, so the heading reported is 0 deg. Without
    the latitude (imu_tk's and imucal's model) the same data are refused in most seeds, and
    pooled over the seeds its chi-squared is far off: the model error is real (--strict; by
    default it is accepted as the small model error it is)."""
    truth = np.append(np.linalg.inv(GYR_A).ravel(), GYR_B)
    chi2 = {"with": 0.0, "without": 0.0}
    dof = {"with": 0.0, "without": 0.0}
    refused = []
    lines = []
    for seed in EARTH_SEEDS:
        path = tmp_path / f"ferraris_earth_{seed}.csv"
        write_imucal(path, imucal_session(49.6, seed=seed))
        rec = read_csv(path, gyro_units="dps", rate_hz=IMUCAL_RATE)
        acc = fit_accel(rec, G, "axes").estimate
        gyr = fit_gyro_full(rec, full_turns=True, accel=acc, latitude_deg=49.6)
        assert gyr.verdict.accepted, (seed, gyr.verdict.reasons)
        z = (gyr.fit.values - truth) / gyr.fit.sigma()
        assert np.max(np.abs(z)) < 4, (seed, dict(zip(C_NAMES + B_NAMES, z, strict=True)))
        earth = gyr.fit.details["earth"]
        assert earth["heading_of"].startswith("body y axis")
        off = (earth["heading_deg"] + 180.0) % 360.0 - 180.0
        assert abs(off) < 4 * earth["heading_sigma_deg"], (seed, earth)

        flat = fit_gyro_full(rec, full_turns=True, accel=acc, acceptance=Acceptance(strict=True))
        z_flat = (flat.fit.values - truth) / flat.fit.sigma()
        # by default the unmodelled Earth rate is a model error far below a degree: accepted
        loose = fit_gyro_full(rec, full_turns=True, accel=acc)
        assert loose.verdict.accepted, loose.verdict.reasons
        assert loose.fit.residuals["model_error"] < np.radians(0.1)
        if not flat.verdict.accepted:
            refused.append(seed)
            assert "give the latitude, --latitude" in " ".join(flat.verdict.reasons)
        for key, est in (("with", gyr), ("without", flat)):
            chi2[key] += est.fit.residuals["chi2"]
            dof[key] += est.fit.residuals["dof"]
        lines.append(
            f"seed {seed}: with the latitude chi2 {gyr.fit.residuals['chi2']:.1f}/"
            f"{gyr.fit.residuals['dof']:.0f}, worst {np.max(np.abs(z)):.1f} sigma, heading "
            f"{off:+.1f} +- {earth['heading_sigma_deg']:.1f} deg; without: "
            f"{'accepted' if flat.verdict.accepted else 'refused'}, chi2 "
            f"{flat.fit.residuals['chi2']:.1f}/{flat.fit.residuals['dof']:.0f}, worst "
            f"{np.max(np.abs(z_flat)):.1f} sigma"
        )
    print("\nEarth's rotation in a Ferraris session at 49.6 N:\n  " + "\n  ".join(lines))
    assert chi2_sf(chi2["with"], dof["with"]) > 0.01
    assert chi2_sf(chi2["without"], dof["without"]) < 1e-6
    assert len(refused) > len(EARTH_SEEDS) // 2, refused


# --- a hand-held session -----------------------------------------------------------------------

HAND_RATE = 100.0
HAND_ACC_SD = 400e-6 * G * math.sqrt(HAND_RATE)  # 400 ug/sqrt(Hz), per sample
HAND_GYR_SD = math.radians(0.005) * math.sqrt(HAND_RATE)  # 0.005 deg/s/sqrt(Hz)
LEVER_M = np.array([-0.08, 0.0, 0.02])  # the board's centre from the wrist, body axes
HAND_UP = [[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, -1], [1, 1, 0],
           [1, 0, 1], [0, 1, 1], [-1, 1, 1], [1, -1, 1], [1, 1, -1], [-1, -1, 0],
           [0, -1, -1]]  # fmt: skip  # the body direction a person holds up, in turn


def band(
    t: np.ndarray, rms: float, hz: tuple[float, float], rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rotation-vector wobble (N, 3): 24 sinusoids per axis at random frequencies in the band
    and random phases, rms per axis, with its first and second derivatives, exactly."""
    w = rng.uniform(*hz, (24, 3)) * 2 * math.pi
    arg = t[:, None, None] * w + rng.uniform(0, 2 * math.pi, (24, 3))
    amp = rms * math.sqrt(2.0 / 24)
    return (
        amp * np.sin(arg).sum(axis=1),
        amp * (w * np.cos(arg)).sum(axis=1),
        -amp * (w * w * np.sin(arg)).sum(axis=1),
    )


def hand_session(tremor_rad: float, seed: int) -> np.ndarray:
    """(N, 7): time in seconds from a logger's clock (with jitter), accel in g, gyro in deg/s.

    A person holds each direction of HAND_UP up for 3-4 s (short holds) and tips the board to
    the next over 1.2 s. The hand adds, all the time, tremor at 8-12 Hz (tremor_rad rms per
    axis) and a slow wander (0.1-0.6 Hz, 3 mrad rms): imperfect holds. The board sits LEVER_M
    from the wrist, so the wobble also accelerates it: alpha x r + w x (w x r)."""
    rng = np.random.default_rng(seed)
    m = Motion(np.eye(3))
    m.hold(float(rng.uniform(3.0, 4.0)))
    for d in HAND_UP[1:]:
        m.tip_up(np.array(d, float) / np.linalg.norm(d), 1.2)
        m.hold(float(rng.uniform(3.0, 4.0)))
    t = np.arange(0.0, m.duration, 1.0 / HAND_RATE)
    rot, rate = m.sample(t)
    th1, w1, a1 = band(t, tremor_rad, (8.0, 12.0), rng)
    th2, w2, a2 = band(t, 3e-3, (0.1, 0.6), rng)
    wobble = small_rotations(th1 + th2)
    w_t, a_t = w1 + w2, a1 + a2  # small angles: the wobble's body rate and acceleration
    w_body = np.einsum("nji,nj->ni", wobble, rate) + w_t
    lever = np.cross(a_t, LEVER_M) + np.cross(w_t, np.cross(w_t, LEVER_M))
    f = np.einsum("nji,j->ni", rot @ wobble, G * UP) + lever
    acc_g = quantise(sensor(ACC_A, ACC_B, f, HAND_ACC_SD, rng) / G, 4.0 / 32768)  # +-4 g
    gyr = quantise(np.degrees(sensor(GYR_A, GYR_B, w_body, HAND_GYR_SD, rng)), 500.0 / 32768)
    stamp = 1_700_000_000.0 + t + rng.normal(0, 2e-4, t.size)
    out: np.ndarray = np.column_stack([stamp, acc_g, gyr])
    return out


def write_hand(path: Path, table: np.ndarray) -> None:
    header = "timestamp,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z"
    np.savetxt(path, table, fmt=["%.6f"] + ["%.7g"] * 6, delimiter=",", header=header, comments="")


def accel_truth_9() -> tuple[list[str], np.ndarray]:
    """The 9-parameter model ties the frame to the chip: its C is the upper-triangular R of
    A^-1 = Q R (positive diagonal), its bias b."""
    _q, r = np.linalg.qr(np.linalg.inv(ACC_A))
    r = np.diag(np.sign(np.diag(r))) @ r
    upper = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    names = [f"C_{'xyz'[i]}{'xyz'[j]}" for i, j in upper] + B_NAMES
    return names, np.append([r[i, j] for i, j in upper], ACC_B)


HAND_UNITS = ("--accel-units", "g", "--gyro-units", "dps", "--time-units", "s", "--dry-run")


def test_hand_held_session_with_physiological_tremor_is_accepted(tmp_path: Path) -> None:
    """0.5 mrad of tremor (physiological tremor, a steady hand): every hold is found and the
    fit holds the truth within its uncertainty."""
    path = tmp_path / "hand.csv"
    write_hand(path, hand_session(5e-4, seed=2))
    code, rep = report("calibrate", "accel", "--from", str(path), *HAND_UNITS)
    assert code == 0 and rep["accepted"] is True, rep
    assert rep["orientations"] == len(HAND_UP) and len(rep["poses"]) == len(HAND_UP)
    names, truth = accel_truth_9()
    z = off_by_sigma(rep, names, truth)
    assert max(map(abs, z.values())) < 4, z


@pytest.mark.parametrize("tremor_rad", [2e-3, 4e-3])
def test_hand_held_session_with_a_few_mrad_of_tremor_keeps_its_poses_apart(
    tmp_path: Path, tremor_rad: float
) -> None:
    """2-4 mrad of tremor at 8-12 Hz, 8 cm from the wrist: the board shakes by 0.6-1.2 m/s^2
    and 0.13-0.26 rad/s rms per axis, far above the sensor's noise. The still detector reads
    its floor from the data, so the floor is the tremor's, and a smooth 35 deg tip between two
    poses (from [0,1,1] up to [-1,1,1] up) stays inside its hysteresis band. The run is cut
    where the window means jump (imud/calib/still.py): no interval spans two holds (each lasts
    3-4 s), and the fit holds the truth within its uncertainty."""
    path = tmp_path / "hand.csv"
    write_hand(path, hand_session(tremor_rad, seed=2))
    code, rep = report("calibrate", "accel", "--from", str(path), *HAND_UNITS)
    assert code == 0 and rep["accepted"] is True, rep
    assert all(p["duration_s"] < 4.0 for p in rep["poses"]), rep["poses"]
    assert rep["orientations"] >= 12
    names, truth = accel_truth_9()
    z = off_by_sigma(rep, names, truth)
    assert max(map(abs, z.values())) < 4, z


# --- other tools' headers ----------------------------------------------------------------------


def put(tmp_path: Path, name: str, header: str, rows: list[str]) -> Path:
    path = tmp_path / name
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize(
    ("header", "row", "options", "accel", "gyro"),
    [
        # EuRoC / ASL: the header is a comment line, units in brackets (SI), time in ns
        ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
         "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]",
         "{ns},0.01,0.02,0.03,0.1,0.2,9.8", {}, [0.1, 0.2, 9.8], [0.01, 0.02, 0.03]),
        # Kalibr's imu0.csv: timestamp (ns), omega (rad/s), alpha (m/s^2)
        ("timestamp,omega_x,omega_y,omega_z,alpha_x,alpha_y,alpha_z",
         "{ns},0.01,0.02,0.03,0.1,0.2,9.8", {"time_units": "ns"}, [0.1, 0.2, 9.8],
         [0.01, 0.02, 0.03]),
        # rostopic echo -p of sensor_msgs/Imu: %time (the bag's) is not read, the stamp is
        ("%time,field.header.seq,field.header.stamp,field.header.frame_id,field.orientation.x,"
         "field.angular_velocity.x,field.angular_velocity.y,field.angular_velocity.z,"
         "field.linear_acceleration.x,field.linear_acceleration.y,field.linear_acceleration.z",
         "{ns2},{i},{ns},imu_link,0,0.01,0.02,0.03,0.1,0.2,9.8", {"time_units": "ns"},
         [0.1, 0.2, 9.8], [0.01, 0.02, 0.03]),
        # phyphox-style names with units in parentheses; the gyro in deg/s says so
        ("Time (s),Acceleration x (m/s^2),Acceleration y (m/s^2),Acceleration z (m/s^2),"
         "Gyroscope x (deg/s),Gyroscope y (deg/s),Gyroscope z (deg/s)",
         "{s},0.1,0.2,9.8,90,-45,180", {"gyro_units": "dps"}, [0.1, 0.2, 9.8],
         [math.pi / 2, -math.pi / 4, math.pi]),
        # an Arduino logger: millis() and AccX in g, GyroX in deg/s, a temperature
        ("millis,AccX,AccY,AccZ,GyroX,GyroY,GyroZ,Temp",
         "{ms},0,0.6,0.8,90,-45,180,25.5", {"accel_units": "g", "gyro_units": "dps"},
         [0.0, 0.6 * G, 0.8 * G], [math.pi / 2, -math.pi / 4, math.pi]),
    ],
)  # fmt: skip
def test_other_tools_headers_are_read(
    tmp_path: Path,
    header: str,
    row: str,
    options: dict[str, str],
    accel: list[float],
    gyro: list[float],
) -> None:
    t0 = 1_403_636_579_758_555_392
    rows = [
        row.format(ns=t0 + i * 5_000_000, ns2=t0 + i * 5_000_000 + 731, i=i,
                   s=f"{i * 0.005:.3f}", ms=1000 + 5 * i)
        for i in range(4)
    ]  # fmt: skip
    rec = read_csv(put(tmp_path, "other.csv", header, rows), **options)  # type: ignore[arg-type]
    assert rec.n == 4 and rec.rate_hz == pytest.approx(200.0)
    np.testing.assert_allclose(rec.accel[0], accel, rtol=1e-12)
    np.testing.assert_allclose(rec.gyro[0], gyro, rtol=1e-12)


def test_a_counter_gives_the_times_and_its_gaps_stay_gaps(tmp_path: Path) -> None:
    rows = [f"{i},0.1,0.2,0.3,0,0,9.8" for i in (0, 1, 2, 5, 6)]  # 3 and 4 were lost
    path = put(tmp_path, "c.csv", "n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z", rows)
    rec = read_csv(path, gyro_units="dps", rate_hz=204.8)
    np.testing.assert_array_equal(np.diff(rec.t_ns), [4882812, 4882813, 14648437, 4882813])


def test_seconds_keep_their_resolution_and_must_increase(tmp_path: Path) -> None:
    head = "time,ax,ay,az,gx,gy,gz"
    rows = [f"{1_700_000_000 + i / 200:.6f},0,0,9.8,0,0,0" for i in range(5)]
    rec = read_csv(put(tmp_path, "s.csv", head, rows), time_units="s")
    assert np.abs(np.diff(rec.t_ns) - 5_000_000).max() < 1000  # epoch seconds: ~0.2 us steps
    with pytest.raises(CsvError) as info:
        read_csv(put(tmp_path, "b.csv", head, rows[:3] + rows[1:2]), time_units="s")
    assert (info.value.line, info.value.column) == (5, "time")
    assert "is not after" in str(info.value)


# --- refusals, through the CLI -----------------------------------------------------------------

IMUCAL_HEAD = "n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"


def imucal_rows(acc: str = "9.8,0.1,0.2") -> list[str]:
    return [f"{i},0.5,-0.3,0.06,{acc}" for i in range(50)]


@pytest.mark.parametrize(
    ("header", "rows", "options", "where", "says"),
    [
        # a counter without the rate
        (IMUCAL_HEAD, imucal_rows(), ["--gyro-units", "dps"], ":1: column n_samples:",
         "pass the rate it counts at, --rate HZ"),
        # two columns for one quantity
        ("timestamp_ns,ax,ay,az,gx,gy,gz,acc_x",
         [f"{i * 5_000_000},0,0,9.8,0,0,0,9.8" for i in range(50)], [],
         ":1: column ax, acc_x:", "both read as ax (fields 2 and 8)"),
        # accel in g read as m/s^2
        (IMUCAL_HEAD, imucal_rows("0.999,0.01,0.02"), ["--gyro-units", "dps", "--rate", "204.8"],
         ": column acc_x, acc_y, acc_z:", "looks like g: pass --accel-units g"),
        # a time whose unit nothing says
        ("time,ax,ay,az,gx,gy,gz", [f"{i * 0.005:.3f},0,0,9.8,0,0,0" for i in range(50)], [],
         ":1: column time:", "pass --time-units s, ms, us or ns: looks like s (200 Hz)"),
        # seconds declared as milliseconds
        ("time,ax,ay,az,gx,gy,gz", [f"{i * 0.005:.3f},0,0,9.8,0,0,0" for i in range(50)],
         ["--time-units", "ms"], ": column time:",
         "outside any IMU's (0.5 Hz .. 50000 Hz): looks like s (200 Hz): pass --time-units s"),
        # a time that goes back
        ("time,ax,ay,az,gx,gy,gz",
         [f"{i * 0.005:.3f},0,0,9.8,0,0,0" for i in (0, 1, 2, 3, 2, 5)], ["--time-units", "s"],
         ":6: column time:", "0.01 is not after 0.015 on line 5"),
        # the rate given for a file that has a time column
        ("timestamp_ns,ax,ay,az,gx,gy,gz",
         [f"{i * 5_000_000},0,0,9.8,0,0,0" for i in range(50)], ["--rate", "200"],
         ":1: column timestamp_ns:", "drop --rate"),
    ],
)  # fmt: skip
def test_refusals_name_the_line_or_column_and_the_fix(
    tmp_path: Path, header: str, rows: list[str], options: list[str], where: str, says: str
) -> None:
    path = put(tmp_path, "rec.csv", header, rows)
    r = imud("calibrate", "gyro", "--from", str(path), "--dry-run", *options)
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"{path}{where}" in r.stderr and says in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
