"""Files imud writes survive a kill at any moment: the reader finds the old file or the new one,
complete, never a torn one.

Each case runs a real writer in a process of its own that rewrites the same path in a loop (two
contents, alternately), and SIGKILLs it after a random delay, a number of times. Where in the
write the kill lands is up to the scheduler; what is asserted holds wherever it lands: the path
reads back as exactly one of the two contents. The writers are the ones the daemon and the CLI
use: `write_calibration` (calibration files, through `imud.atomicfile.write_atomic`, which the
BNO055's saved offsets use too) and `CsvWriter` (`imud record --csv`, `imud calibrate apply`).
"""

from __future__ import annotations

import multiprocessing
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imud.calib.csvio import read_csv
from imud.calib.file import read_calibration

pytestmark = pytest.mark.slow  # kill loops: a dozen writers killed per case

KILLS = 12


def calibration_writer(path: Path, ready: Any) -> None:
    """Rewrite `path` with two calibrations in turn, for ever."""
    from imud.calib.file import CalibrationFile, SensorTable, write_calibration

    files = [
        CalibrationFile(chip="mpu6050", accel=SensorTable(bias=(k, -k, 2 * k)))
        for k in (0.125, 0.25)
    ]
    i = 0
    while True:
        write_calibration(path, files[i % 2])
        if i == 0:
            ready.set()  # one file whole: every kill from here finds one
        i += 1


def csv_writer(path: Path, ready: Any) -> None:
    """Rewrite `path` with two recordings in turn, for ever, in chunks as `imud record` does."""
    from imud.calib.csvio import CsvWriter

    n = 20000  # rows per file: long enough that a kill often lands mid-write
    t = np.arange(n, dtype=np.int64) * 1_000_000
    i = 0
    while True:
        fill = 5.0 + i % 2  # every value 5 in one content, 6 in the other (|accel| near g)
        with CsvWriter(path, has_temp=True) as w:
            for a in range(0, n, 2000):
                b = a + 2000
                w.write(t[a:b], np.full((2000, 3), fill), np.full((2000, 3), fill),
                        np.full(2000, 25.0))  # fmt: skip
        if i == 0:
            ready.set()  # one file whole: every kill from here finds one
        i += 1


def kill_at_random(
    writer: Callable[[Path, Any], None], path: Path, seed: int, check: Callable[[Path], None]
) -> None:
    """Run `writer` on `path` in a process of its own and SIGKILL it at a random moment after
    its first whole file, KILLS times, checking the path after each kill. The writers are forked
    from a server that imported imud once (an interpreter per writer would spend more on its
    imports than on writing)."""
    rng = np.random.default_rng(seed)
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["imud.calib.file", "imud.calib.csvio"])
    for _ in range(KILLS):
        ready = ctx.Event()
        p = ctx.Process(target=writer, args=(path, ready))
        p.start()
        assert ready.wait(60), "the writer never wrote a whole file"
        time.sleep(float(rng.uniform(0.0, 0.3)))
        p.kill()  # SIGKILL
        p.join(10)
        assert p.exitcode == -signal.SIGKILL
        check(path)  # a file was whole before the kill: the path holds one, old or new


def check_calibration(path: Path) -> None:
    cf = read_calibration(path)
    assert cf.accel is not None
    k = cf.accel.bias[0]
    assert k in (0.125, 0.25) and tuple(cf.accel.bias) == (k, -k, 2 * k)


def check_csv(path: Path) -> None:
    rec = read_csv(path)
    assert rec.n == 20000  # whole: every row of one file
    values = np.unique(rec.accel)
    assert values.size == 1 and values[0] in (5.0, 6.0)  # one content, not a mix
    np.testing.assert_array_equal(rec.gyro, rec.accel)


def test_a_calibration_file_killed_mid_write_is_old_or_new(tmp_path: Path) -> None:
    path = tmp_path / "imu0.cal.toml"
    kill_at_random(calibration_writer, path, 1, check_calibration)


def test_a_recording_killed_mid_write_is_old_or_new(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    kill_at_random(csv_writer, path, 2, check_csv)
    # a kill never leaves a torn file at the path (checked after each kill); what it leaves
    # are the unfinished temporary files beside it, named so nothing mistakes them for one
    for left in tmp_path.iterdir():
        assert left == path or (left.name.startswith(".rec.csv.") and left.suffix == ".tmp")


def test_a_killed_writers_leftover_is_removed_by_the_next_write(tmp_path: Path) -> None:
    """A SIGKILL between creating the temporary file and renaming it leaves `.NAME.*.tmp`
    behind; the next write of the same file removes such leftovers once they are old enough
    not to be another writer's write in progress, and nothing else."""
    import os

    from imud.atomicfile import STALE_S, write_atomic

    target = tmp_path / "imu[0].cal.toml"  # a name with glob metacharacters
    old = tmp_path / f".{target.name}.abc123.tmp"
    young = tmp_path / f".{target.name}.def456.tmp"
    other = tmp_path / ".other.cal.toml.zzz.tmp"
    for p in (old, young, other):
        p.write_text("half a file")
    long_ago = time.time() - 2 * STALE_S
    for p in (old, other):
        os.utime(p, (long_ago, long_ago))
    write_atomic(target, "version = 2\n")
    assert target.read_text() == "version = 2\n"
    assert not old.exists()  # a leftover: removed
    assert young.exists()  # may be a write in progress: kept
    assert other.exists()  # another file's: not ours
