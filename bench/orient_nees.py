"""The orientation filter's consistency and accuracy across draws and batch sizes, for one or more
source trees side by side (each in its own process, so each imports its own `imud`).

Ten draws of each of drone_hover, car and their magnetometer variants, in two sets: scenario
seeds 0-9 with gyro biases from seeds 500-509, and seeds 100-109 with biases from 300-309 (the
second a set no tuning has looked at). Each bias is drawn from the filter's own prior, N(0, 0.01
rad/s) per axis, constant, and the model's bias walk is set near zero, so the truth is a draw
from the filter's model and the averaged NEES can be held to its chi-squared band. Per set and
scenario it prints the share of the instants t = 5, 7.5, ... 57.5 s whose tilt NEES, averaged
over the draws, lies inside the 95 % band of chi2(2 x 10) / 10, above it (overconfident) and
below it (cautious), the largest average, and the tilt RMS from 5 s, mean and worst draw.

    .venv/bin/python bench/orient_nees.py --batch 32 .
    .venv/bin/python bench/orient_nees.py --batch 25 /tmp/before .

Batches of 1, 25 and 100 give corrections every 100 samples at 1 kHz, batches of 32 every 128:
the two cases a vibration sees differently.
"""

from __future__ import annotations

import argparse

from common import NEES_CHILD_PRELUDE, tables_per_tree

BODY = r"""
batch = int(sys.argv[2])
for name, first, bias_first in (("A", 0, 500), ("B", 100, 300)):
    for scenario, mag in (("drone_hover", False), ("car", False), ("drone_hover", True),
                          ("car", True)):
        nees, rms = [], []
        for k in range(runs):
            b = np.degrees(np.random.default_rng(bias_first + k).normal(0.0, 0.01, 3))
            s = getattr(sc, scenario)(seed=first + k, mag=mag, bias_deg_s=tuple(b))
            f = OrientationFilter(NoiseModel(s.gyro_density, s.accel_density, bias_walk=1e-7,
                                             mag=s.mag_sigma))
            qs, cs = [], []
            for i in range(0, len(s.t_s), batch):
                m = None if s.mag is None else s.mag[i : i + batch]
                q, c = f.step(s.gyro[i : i + batch], s.accel[i : i + batch], s.dt, m)
                qs.append(q)
                cs.append(c)
            q, c = np.vstack(qs), np.vstack(cs)
            first_out = int(np.argmax(~np.isnan(q[:, 0])))
            truth = s.truth if mag else M.align_heading(q, s.truth, first_out)
            e = M.world_error(q, truth)
            nees.append(M.nees(e[times], c[times], slice(0, 2)))
            rms.append(float(np.sqrt(np.mean(M.tilt_error_deg(q, s.truth)[5000:] ** 2))))
        a = np.mean(nees, axis=0)
        label = scenario + ("+mag" if mag else "")
        print(f"| {name} | {label} | {np.mean((a >= lo) & (a <= hi)):.0%} | {np.mean(a > hi):.0%}"
              f" | {np.mean(a < lo):.0%} | {a.max():.1f} | {np.mean(rms):.2f} / {max(rms):.2f} |")
"""
CHILD = NEES_CHILD_PRELUDE + BODY  # what each tree's process runs


HEADER = "| set | scenario | tilt NEES inside | above | below | max | tilt RMS, mean / worst |"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=32, help="samples a batch (default 32)")
    ap.add_argument("trees", nargs="*", default=["."], help="source trees (default .)")
    args = ap.parse_args(argv)
    tables_per_tree(
        CHILD, args.trees, [str(args.batch)], "{tree}, batches of " + str(args.batch), HEADER
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
