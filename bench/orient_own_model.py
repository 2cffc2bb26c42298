"""The orientation filter's consistency where its model holds: a hovering drone whose holding
accelerations are drawn from the filter's own model of them (a first-order Gauss-Markov process,
1-s time constant, `--sigma` m/s^2 per axis, below the filter's 0.2 m/s^2 ceiling) instead of the
scenario's sinusoidal sway. For one or more source trees side by side (each in its own process).

A filter whose noise estimates are right is consistent here by construction; where it is not,
the fault is in how it learns its noise levels, not in a mismatch between its model and the
platform. Ten draws in two sets (scenario seeds 0-9 with biases from seeds 500-509, and 100-109
with 300-309), biases from the filter's prior. Per set it prints the share of instants
t = 5, 7.5, ... 57.5 s whose tilt NEES averaged over the draws lies inside the 95 % band of
chi2(2 x 10) / 10, above and below it, the NEES averaged over all of them (2 expected), the tilt
RMS from 5 s (mean / worst draw), and, averaged from 20 s on, the linear acceleration's standard
deviation the filter learned (truth: `--sigma`) and the white scatter it took as measurement noise.

    .venv/bin/python bench/orient_own_model.py --batch 25 /tmp/before .
"""

from __future__ import annotations

import argparse

from common import NEES_CHILD_PRELUDE, tables_per_tree

BODY = r"""
batch, sigma = int(sys.argv[2]), float(sys.argv[3])
for name, first, bias_first in (("A", 0, 500), ("B", 100, 300)):
    nees, rms, lin, white = [], [], [], []
    for k in range(runs):
        b = np.degrees(np.random.default_rng(bias_first + k).normal(0.0, 0.01, 3))
        s = sc.drone_hover(seed=first + k, bias_deg_s=tuple(b), hold_sigma=sigma)
        f = OrientationFilter(NoiseModel(s.gyro_density, s.accel_density, bias_walk=1e-7))
        qs, cs = [], []
        for i in range(0, len(s.t_s), batch):
            q, c = f.step(s.gyro[i : i + batch], s.accel[i : i + batch], s.dt)
            qs.append(q)
            cs.append(c)
            if i >= 20000:
                lin.append(f.linear_var)
                white.append(getattr(f, "_white_var", 0.0))
        q, c = np.vstack(qs), np.vstack(cs)
        first_out = int(np.argmax(~np.isnan(q[:, 0])))
        e = M.world_error(q, M.align_heading(q, s.truth, first_out))
        nees.append(M.nees(e[times], c[times], slice(0, 2)))
        rms.append(float(np.sqrt(np.mean(M.tilt_error_deg(q, s.truth)[5000:] ** 2))))
    a = np.mean(nees, axis=0)
    print(f"| {name} | {np.mean((a >= lo) & (a <= hi)):.0%} | {np.mean(a > hi):.0%}"
          f" | {np.mean(a < lo):.0%} | {a.mean():.2f} | {np.mean(rms):.2f} / {max(rms):.2f}"
          f" | {np.sqrt(np.mean(lin)):.3f} | {np.sqrt(np.mean(white)):.3f} |")
"""
CHILD = NEES_CHILD_PRELUDE + BODY  # what each tree's process runs

HEADER = (
    "| set | tilt NEES inside | above | below | mean NEES | tilt RMS, mean / worst (deg)"
    " | learned linear sd (m/s^2) | white sd (m/s^2) |"
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=25, help="samples a batch (default 25)")
    ap.add_argument("--sigma", type=float, default=0.15, help="m/s^2 per axis (default 0.15)")
    ap.add_argument("trees", nargs="*", default=["."], help="source trees (default .)")
    args = ap.parse_args(argv)
    tables_per_tree(
        CHILD,
        args.trees,
        [str(args.batch), str(args.sigma)],
        f"{{tree}}, batches of {args.batch}, holding accelerations {args.sigma} m/s^2",
        HEADER,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
