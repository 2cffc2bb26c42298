"""A fixed stretch of acquisition at virtual time, to count instructions with callgrind.

Wall-clock figures on a shared VM move by 10 % from run to run; instruction counts do not depend
on the machine's load. Run the loop for two lengths under callgrind and divide the difference by
the samples between them, so start-up and imports cancel out:

    for s in 2 12; do PYTHONHASHSEED=0 valgrind --tool=callgrind --callgrind-out-file=/dev/null \\
        .venv/bin/python bench/instructions_per_sample.py --chip mpu6050 --seconds $s; done

`--chip mpu6050`: section 1's benchmark loop (1 kHz, calibration on, null publisher).
`--chip icm42688p`: an ICM-42688-P at 32 kHz over simulated SPI, wired by `tests.helpers`.
It prints the samples delivered; callgrind prints the instructions ("Collected").
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chip", choices=["mpu6050", "icm42688p"], default="mpu6050")
    ap.add_argument("--seconds", type=float, default=2.0, help="virtual seconds measured")
    a = ap.parse_args()
    if a.chip == "mpu6050":
        import pipeline_throughput as pt

        cal = Path(tempfile.mkdtemp()) / "cal.toml"
        cal.write_text(pt.CALIBRATION_TOML)
        b = pt.Bench(1000.0, None, cal, lambda p: None)
        b.run("warmup", 1.0)
        print("samples", b.run("measured", a.seconds).samples)
        return
    from tests.helpers import make_rig

    rig = make_rig(
        {"chip": "icm42688p", "odr_hz": 32000,
         "bus": {"kind": "sim", "transport": "spi", "speed_hz": 10_000_000}},
        {"truth": False, "motion": {"kind": "tumble", "rate_dps": [0, 0, 100]}},
    )  # fmt: skip
    rig.run(0.3)
    before = rig.runner.samples
    rig.run(a.seconds)
    print("samples", rig.runner.samples - before)


if __name__ == "__main__":
    main()
