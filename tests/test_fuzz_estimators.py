"""Every calibration procedure fed garbage that a recording file can hold (issue 20): what passes
the CSV reader's own checks (finite numbers, increasing time) but is no calibration: one
sample, constant columns, values in the wrong units, random numbers, a few identical rows,
irregular time, a temperature that never moves. Each procedure returns an outcome (accepted or
refused with its reasons) or refuses with `CalibrationRefused` and a message; whatever it
accepts or refuses, its file update writes a file that reads back. Never another exception:
the CLI would show it as a traceback."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imud.calib.file import CalibrationError, CalibrationFile, read_calibration, write_calibration
from imud.calib.procedure import run_accel, run_gyro, run_mag, run_temp
from imud.calib.recording import Recording
from imud.calib.still import CalibrationRefused

KINDS = ("random", "constant", "wrong_units", "repeated", "still", "steps", "shaking", "two_poses")


@st.composite
def recordings(draw: Any) -> Recording:
    n = draw(st.sampled_from([1, 2, 3, 7, 50, 400, 3000]))
    kind = draw(st.sampled_from(KINDS))
    seed = draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    rate = draw(st.sampled_from([1.0, 50.0, 100.0, 1000.0]))
    dt = 1e9 / rate
    steps = np.full(n, dt)
    if draw(st.booleans()):  # irregular time: jitter and a few long gaps
        steps = steps * rng.uniform(0.5, 1.5, n)
        steps[rng.integers(0, n, max(1, n // 50))] *= 40
    t_ns = np.cumsum(np.maximum(steps, 1.0)).astype(np.int64)
    shape = (n, 3)
    if kind == "random":
        scale = draw(st.sampled_from([1e-9, 1.0, 1e6]))
        accel, gyro = rng.standard_normal(shape) * scale, rng.standard_normal(shape) * scale
    elif kind == "constant":
        accel = np.tile(draw(st.sampled_from([[0.0, 0.0, 0.0], [0.0, 0.0, 9.81]])), (n, 1))
        gyro = np.zeros(shape)
    elif kind == "wrong_units":  # counts, or g and deg/s read as SI
        f = draw(st.sampled_from([1 / 9.81, 4096 / 9.81]))
        accel = (np.array([0.0, 0.0, 9.81]) + rng.standard_normal(shape) * 0.02) * f
        gyro = rng.standard_normal(shape) * 0.01 * draw(st.sampled_from([57.3, 16.4 * 57.3]))
    elif kind == "repeated":
        accel = np.repeat(rng.standard_normal((max(1, n // 10), 3)), 10, axis=0)[:n]
        accel = np.vstack([accel, np.tile(accel[-1:], (n - accel.shape[0], 1))])
        gyro = np.zeros(shape)
    elif kind == "still":
        accel = np.array([0.0, 0.0, 9.81]) + rng.standard_normal(shape) * 0.02
        gyro = rng.standard_normal(shape) * 1e-3
    elif kind == "shaking":  # a hand that never holds still
        accel = np.array([0.0, 0.0, 9.81]) + rng.standard_normal(shape) * 3.0
        gyro = rng.standard_normal(shape) * 1.0
    elif kind == "two_poses":
        accel = np.where(np.arange(n)[:, None] < n // 2, [0.0, 0.0, 9.81], [9.81, 0.0, 0.0])
        accel = accel + rng.standard_normal(shape) * 0.02
        gyro = rng.standard_normal(shape) * 1e-3 + np.linspace(0, 0.05, n)[:, None]
    else:  # "steps": poses that jump between random directions with no motion between
        dirs = rng.standard_normal((max(1, n // 100), 3))
        dirs = dirs / np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-12) * 9.81
        accel = np.repeat(dirs, 100, axis=0)[:n]
        accel = np.vstack([accel, np.tile(accel[-1:], (n - accel.shape[0], 1))])
        accel = accel + rng.standard_normal(shape) * 0.02
        gyro = rng.standard_normal(shape) * 1e-3
    temp = None
    if draw(st.booleans()):
        temp = np.full(n, 25.0) if draw(st.booleans()) else np.linspace(10, 50, n)
    mag = None
    if draw(st.booleans()):  # directions all round, an offset, or noise alone
        u = rng.standard_normal(shape)
        u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        mag = u * 50e-6 + draw(st.sampled_from([0.0, 20e-6])) + rng.standard_normal(shape) * 1e-7
    return Recording(t_ns, accel, gyro, temp=temp, mag=mag, source=f"fuzz {kind}")


def _outcome(fn: Any, *args: Any, **kwargs: Any) -> Any:
    try:
        return fn(*args, **kwargs)
    except CalibrationRefused as e:
        assert str(e).strip(), "a refusal without a message"
        return None


def _writes(outcome: Any) -> None:
    """Whatever was concluded, the update writes a file that reads back, or says why not."""
    if outcome is None:
        return
    try:
        cf = outcome.update(CalibrationFile(chip="mpu6050"), "fuzz")
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "cal.toml"
            write_calibration(path, cf)
            read_calibration(path)
    except CalibrationError as e:
        assert str(e).strip()


EXAMPLES = int(os.environ.get("IMUD_FUZZ_EXAMPLES", "60"))  # bench/fuzz_long.py-style runs: more


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rec=recordings(), model=st.sampled_from(["full", "axes"]))
def test_no_procedure_throws_on_garbage(rec: Recording, model: str) -> None:
    for fn, args in [
        (run_accel, (rec, 9.81, model)),
        (run_gyro, (rec, model == "full")),
        (run_temp, (rec, ("accel", "gyro"), 3)),
    ]:
        _writes(_outcome(fn, *args))
    # each row a still pose's reading (--shots): the same garbage read as a shot list
    _writes(_outcome(run_accel, rec, 9.81, model, shots=True))
    if rec.mag is not None:
        _writes(_outcome(run_mag, rec, None))
        _writes(_outcome(run_mag, rec, None, shots=True))
