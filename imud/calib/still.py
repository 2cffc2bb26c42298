"""Still intervals in a recording, found with no user tuning, and the noise of their means.

Detection. A window of ~0.5 s (long enough that the variance of a window of noise is well
determined, short enough to resolve a pose change), sliding in steps of a tenth of its length,
gives the variance of the accelerometer vector and of the gyro vector (sums over axes, from
per-step sums and their running totals: O(N), no per-sample loop; an hour at 1 kHz takes a few
tenths of a second). Motion raises both by orders of magnitude over the sensor's
noise. The noise floor is read from the data itself: the logarithm of a still window's variance is
close to normal (a scaled chi-squared), so its centre and spread follow from two low quantiles
(2 % and 10 %) of all windows, which lie in still data whenever at least ~10 % of the recording
is still. A window enters "still" below centre + 3 spreads and leaves it only above
centre + 6 spreads (hysteresis: noise alone crosses neither). The spread is floored at 0.15 in
log (+-15 %) so a nearly white sensor with a very tight distribution is not cut by its own
slow temperature or vibration wander. A window is still when it is still for both sensors;
runs of still windows are trimmed by one window at each end (the onset and settling of motion
lie below the thresholds) and kept when they last at least `min_s` (2 s by default).

A floor read from the data is the floor of whatever the data holds: a board held in a shaking
hand has the tremor's variance everywhere, and a smooth tip from one pose to the next can stay
below three spreads of it, joining two poses into one interval whose mean lies between them.
So each run is also cut where the mean jumps: the accel and gyro means of consecutive
non-overlapping windows move beyond the windows' own variance (chi-squared, 3 dof, p = 1e-6)
and by more than 5 times the run's median step (a hold's slow wobble moves the mean a little
at every step; a tip moves it by metres per second squared at once). The windows on either
side of a jump are dropped and the pieces kept as poses of their own when they still last
`min_s`.

Noise of a mean. MEMS outputs are low-pass filtered and drift, so consecutive samples are
correlated and sigma/sqrt(n) underestimates the error of a mean. Block averaging (Flyvbjerg &
Petersen 1989) repeatedly averages pairs; the variance of the block means times the block
length over n converges to the true variance of the mean once blocks are longer than the
correlation time. The level is chosen automatically as in Jonsson (Phys. Rev. E 98, 043304,
2018): the first level from which the lag-1 correlations of all coarser levels are jointly
consistent with zero (their sum of n_i * rho_i^2 is chi-squared; p > 0.01).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.calib.recording import Recording
from imud.calib.stats import chi2_sf, f_sf

F64 = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

WINDOW_S = 0.5
MIN_WINDOW = 8
ENTER_SPREADS = 3.0
LEAVE_SPREADS = 6.0
MIN_LOG_SPREAD = 0.15
# two low quantiles of the log window variance and their standard-normal z values
Q_LOW, Z_LOW = 0.02, -2.0537489
Q_HIGH, Z_HIGH = 0.10, -1.2815516
BLOCK_MIN_LEN = 16  # coarsest blocking level keeps at least this many block means
BLOCK_START_KEEP = 8192  # finest blocking level examined keeps at least this many (see below)
WINDOW_HOPS = 10  # window positions per window length
SATURATION_MIN_FRACTION = 0.01  # of an interval's samples sitting on the recording's extreme
SATURATION_MIN_COUNT = 5
CHI2_3DOF_P1E6 = 30.66  # chi-squared quantile, 3 degrees of freedom, upper tail 1e-6
JUMP_TO_TYPICAL = 5.0  # a jump between windows is this many times the run's median step


class CalibrationRefused(ValueError):
    """The data cannot give an estimate at all (too short, too few poses, missing faces, no still
    data). The message is one sentence naming the cause and what to do."""


@dataclass(frozen=True)
class StillInterval:
    """One still pose: samples [start, end) of the recording.

    accel, gyro: means (3,); accel_cov, gyro_cov: covariance (3, 3) of those means from the
    data's own noise by block averaging. temp_c: mean temperature; temp_change_c: the change
    across the interval from a straight-line fit (None without temperature). saturated: some
    sample sat on full scale (flagged by the source, or repeated extreme readings)."""

    start: int
    end: int
    t0_s: float  # start time from the beginning of the recording
    duration_s: float
    accel: F64
    gyro: F64
    accel_cov: F64
    gyro_cov: F64
    temp_c: float | None = None
    temp_change_c: float | None = None
    saturated: bool = False

    @property
    def n(self) -> int:
        return self.end - self.start

    @property
    def accel_se(self) -> F64:
        out: F64 = np.sqrt(np.diag(self.accel_cov))
        return out

    @property
    def gyro_se(self) -> F64:
        out: F64 = np.sqrt(np.diag(self.gyro_cov))
        return out


@dataclass(frozen=True)
class StillCheck:
    """Whether a whole recording is still; `moved` lists the spans (seconds from its start)
    where it was not, and `reason` says so in one sentence with the fix (empty when still)."""

    still: bool
    moved: tuple[tuple[float, float], ...]
    reason: str = ""


def mean_and_cov(x: F64) -> tuple[F64, F64]:
    """Mean of x (n, k) and the covariance (k, k) of that mean, by automatic block averaging
    (see mean_cov_dof)."""
    mean, cov, _ = mean_cov_dof(x)
    return mean, cov


def mean_cov_dof(x: F64) -> tuple[F64, F64, int]:
    """Mean of x (n, k), the covariance (k, k) of that mean, by automatic block averaging
    (see the module docstring): correct for coloured noise, unlike cov / n; and the degrees of
    freedom that covariance was estimated with (block means less one): a test that divides by
    it follows Hotelling's T^2, not chi2, when they are few.

    Blocking starts at the finest level that still leaves BLOCK_START_KEEP block means (a long
    capture's first levels only cost time: the standard error from that many blocks is already
    good to ~1.6 %, and correlations shorter than a block are absorbed by it)."""
    x = np.asarray(x, dtype=np.float64)
    n, k = x.shape
    if n < 2:
        raise ValueError("a mean's noise needs at least two samples")
    mean: F64 = np.einsum("nk->k", x) / n
    start = 0
    while n >> (start + 1) >= BLOCK_START_KEEP:
        start += 1
    size = 1 << start
    m = n // size * size
    y = np.einsum("bsk->bk", x[:m].reshape(-1, size, k)) / size - mean
    levels = [y]
    while levels[-1].shape[0] // 2 >= BLOCK_MIN_LEN:
        z = levels[-1]
        h = z.shape[0] // 2 * 2
        levels.append(0.5 * (z[0:h:2] + z[1:h:2]))
    stats = np.empty((len(levels), k))
    for i, z in enumerate(levels):
        c = z - np.einsum("nk->k", z) / z.shape[0]
        var = np.einsum("nk,nk->k", c, c)
        lag1 = np.einsum("nk,nk->k", c[:-1], c[1:])
        rho = np.divide(lag1, var, out=np.zeros_like(var), where=var > 0)
        stats[i] = z.shape[0] * rho * rho
    tail = np.cumsum(stats[::-1], axis=0)[::-1]  # M_j = sum over levels >= j
    chosen = 0
    for ch in range(k):
        for j in range(len(levels)):
            if chi2_sf(float(tail[j, ch]), len(levels) - j) > 0.01:
                chosen = max(chosen, j)
                break
        else:
            chosen = len(levels) - 1
    blocks = levels[chosen]
    cov = np.atleast_2d(np.cov(blocks, rowvar=False)) * (size << chosen) / n
    return mean, cov, blocks.shape[0] - 1


def window_len(rate_hz: float) -> int:
    return max(MIN_WINDOW, round(WINDOW_S * rate_hz))


def _block_sums(x: F64, hop: int) -> tuple[F64, F64]:
    """Per block of `hop` samples and channel: sum and sum of squares about a reference (the
    recording's median, so the sums keep their precision)."""
    nb = x.shape[0] // hop
    xr = x[: nb * hop].reshape(nb, hop, x.shape[1])
    ref = np.median(x[:: max(1, x.shape[0] // 4096)], axis=0)
    s1 = np.einsum("bhk->bk", xr)
    s2 = np.einsum("bhk,bhk->bk", xr, xr)
    s2 = s2 - 2.0 * ref * s1 + hop * ref * ref
    s1 = s1 - hop * ref
    return s1, s2


def _window_var(x: F64, hop: int, blocks: int) -> F64:
    """For each window of `blocks` consecutive blocks of `hop` samples (window j starts at sample
    j * hop), the sum over channels of the samples' variance."""
    s1, s2 = _block_sums(x, hop)
    if s1.shape[0] < blocks:
        return np.zeros(0)
    c1 = np.concatenate((np.zeros((1, s1.shape[1])), np.cumsum(s1, axis=0)))
    c2 = np.concatenate((np.zeros((1, s2.shape[1])), np.cumsum(s2, axis=0)))
    w1 = c1[blocks:] - c1[:-blocks]
    w2 = c2[blocks:] - c2[:-blocks]
    n = hop * blocks
    out: F64 = np.maximum(np.sum(w2 - w1 * w1 / n, axis=1) / (n - 1), 0.0)
    return out


def _thresholds(var: F64) -> tuple[float, float]:
    """Enter and leave thresholds (variances) from the log-variance's low quantiles."""
    positive = var[var > 0]
    if positive.size == 0:  # perfectly constant signal: every window is still
        return math.inf, math.inf
    logv = np.log(np.maximum(var, positive.min()))
    q_lo, q_hi = np.quantile(logv, [Q_LOW, Q_HIGH])
    spread = max(float(q_hi - q_lo) / (Z_HIGH - Z_LOW), MIN_LOG_SPREAD)
    centre = float(q_hi) - Z_HIGH * spread
    return math.exp(centre + ENTER_SPREADS * spread), math.exp(centre + LEAVE_SPREADS * spread)


def _hysteresis(v: F64, enter: float, leave: float) -> BoolArray:
    """Still where the last decisive window (below enter or above leave) was below enter."""
    low = v < enter
    decisive = low | (v > leave)
    idx = np.where(decisive, np.arange(v.shape[0]), -1)
    np.maximum.accumulate(idx, out=idx)
    if idx[-1] < 0:  # nothing decisive anywhere: all between the thresholds, call it moving
        return np.zeros(v.shape[0], dtype=bool)
    first = int(np.argmax(idx >= 0))
    idx[:first] = first  # before the first decisive window, take its state
    state: BoolArray = low[idx]
    return state


def _runs(mask: BoolArray) -> list[tuple[int, int]]:
    d = np.diff(mask.astype(np.int8), prepend=np.int8(0), append=np.int8(0))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


@dataclass(frozen=True)
class Activity:
    """Per-window stillness of a recording. Windows hop by `hop` samples (a tenth of a window:
    boundaries to ~50 ms, at a tenth of the cost of a per-sample slide); window j covers samples
    [j * hop, j * hop + window)."""

    hop: int
    window: int
    still: BoolArray
    accel_var: F64
    gyro_var: F64
    accel_leave: float
    gyro_leave: float

    @classmethod
    def of(cls, rec: Recording) -> Activity:
        if rec.n < 2 * MIN_WINDOW:
            raise CalibrationRefused(
                f"{rec.source or 'the recording'} has {rec.n} samples, too few to tell still "
                "from moving: record for at least a few seconds"
            )
        w = min(window_len(rec.rate_hz), rec.n // 2)
        hop = max(1, w // WINDOW_HOPS)
        blocks = max(2, w // hop)
        if np.isnan(rec.accel).all():  # a gyro-only recording: the gyro's own floor alone
            vg = _window_var(rec.gyro, hop, blocks)
            g_in, g_out = _thresholds(vg)
            still = _hysteresis(vg, g_in, g_out)
            return cls(hop, hop * blocks, still, np.zeros_like(vg), vg, math.inf, g_out)
        va = _window_var(rec.accel, hop, blocks)
        a_in, a_out = _thresholds(va)
        still = _hysteresis(va, a_in, a_out)
        if np.isnan(rec.gyro).all():  # an accelerometer-only recording: its own floor alone
            vg = np.zeros_like(va)
            return cls(hop, hop * blocks, still, va, vg, a_out, math.inf)
        vg = _window_var(rec.gyro, hop, blocks)
        g_in, g_out = _thresholds(vg)
        still &= _hysteresis(vg, g_in, g_out)
        return cls(hop, hop * blocks, still, va, vg, a_out, g_out)

    def covered(self, j0: int, j1: int, n: int) -> tuple[int, int]:
        """Samples covered by windows j0..j1-1."""
        return j0 * self.hop, min(n, (j1 - 1) * self.hop + self.window)

    def moving_windows(self, start: int, end: int) -> list[tuple[int, int]]:
        """Sample spans [a, b) of windows lying inside [start, end) whose variance is above the
        leave threshold: motion (a bump, a slip) inside what should be one still pose."""
        j0 = -(-start // self.hop)
        j1 = min(self.still.shape[0], (end - self.window) // self.hop + 1)
        if j0 >= j1:
            return []
        loud = (self.accel_var[j0:j1] > self.accel_leave) | (self.gyro_var[j0:j1] > self.gyro_leave)
        return [self.covered(j0 + a, j0 + b, end) for a, b in _runs(loud)]


def _seconds(rec: Recording, i: int) -> float:
    return float(rec.t_ns[min(i, rec.n - 1)] - rec.t_ns[0]) * 1e-9


def _spans_text(rec: Recording, spans: list[tuple[int, int]], limit: int = 5) -> str:
    parts = [f"{_seconds(rec, a):.1f}-{_seconds(rec, b - 1):.1f} s" for a, b in spans[:limit]]
    more = f" and {len(spans) - limit} more" if len(spans) > limit else ""
    return ", ".join(parts) + more


def _saturated(rec: Recording, start: int, end: int, rails: tuple[F64, F64] | None) -> bool:
    if rec.saturated is not None:
        return bool(np.any(rec.saturated[start:end]))
    if rails is None:
        return False
    hi, lo = rails
    need = max(SATURATION_MIN_COUNT, SATURATION_MIN_FRACTION * (end - start))
    for k, x in enumerate((rec.accel[start:end], rec.gyro[start:end])):
        top, bottom = hi[3 * k : 3 * k + 3], lo[3 * k : 3 * k + 3]
        # cheap first: most intervals never touch the recording's extremes
        if np.any(_column_reduce(x, np.max) == top) or np.any(_column_reduce(x, np.min) == bottom):
            count = np.count_nonzero((x == top) | (x == bottom), axis=0)
            if np.any(count >= need):
                return True
    return False


def _rails(rec: Recording) -> tuple[F64, F64]:
    """Per-axis extremes of the whole recording: a clipped sensor sits on them repeatedly, which
    noise alone (a continuous distribution's tail) does not do."""
    hi = np.concatenate((_column_reduce(rec.accel, np.max), _column_reduce(rec.gyro, np.max)))
    lo = np.concatenate((_column_reduce(rec.accel, np.min), _column_reduce(rec.gyro, np.min)))
    # a column that never moves has no rails to clip at: it is stuck, or not recorded (zeros
    # where a tool had no gyro), and says so elsewhere; its samples are not saturated
    stuck = hi == lo
    return np.where(stuck, np.inf, hi), np.where(stuck, -np.inf, lo)


def _column_reduce(x: F64, fn: Any) -> F64:
    """fn over axis 0 of an (n, k) array, many times faster than fn(x, axis=0) (which strides
    across rows): reduce a wide reshaped view first."""
    n, k = x.shape
    rows = 128
    m = n // rows * rows
    head = fn(fn(x[:m].reshape(-1, rows * k), axis=0).reshape(rows, k), axis=0) if m else None
    parts = [p for p in (head, fn(x[m:], axis=0) if m < n else None) if p is not None]
    out: F64 = fn(np.array(parts), axis=0)
    return out


def interval_stats(
    rec: Recording, start: int, end: int, rails: tuple[F64, F64] | None = None
) -> StillInterval:
    """The StillInterval of samples [start, end) (no check that they are still)."""
    if end - start < 2:
        raise ValueError(f"interval [{start}, {end}) has fewer than two samples")
    accel, accel_cov = mean_and_cov(rec.accel[start:end])
    gyro, gyro_cov = mean_and_cov(rec.gyro[start:end])
    temp_c = temp_change = None
    if rec.temp is not None:
        t = (rec.t_ns[start:end] - rec.t_ns[start]).astype(np.float64) * 1e-9
        temp = rec.temp[start:end]
        temp_c = float(np.mean(temp))
        tc = t - t.mean()
        denom = float(np.dot(tc, tc))
        slope = float(np.dot(tc, temp - temp_c)) / denom if denom > 0 else 0.0
        temp_change = slope * float(t[-1] - t[0])
    return StillInterval(
        start=start,
        end=end,
        t0_s=_seconds(rec, start),
        duration_s=float(rec.t_ns[end - 1] - rec.t_ns[start]) * 1e-9,
        accel=accel,
        gyro=gyro,
        accel_cov=accel_cov,
        gyro_cov=gyro_cov,
        temp_c=temp_c,
        temp_change_c=temp_change,
        saturated=_saturated(rec, start, end, rails),
    )


def _mean_jumps(x: F64, m: int) -> BoolArray:
    """For consecutive windows of `m` samples of x (k, m, 3): whether the mean moved between
    window i and i + 1 beyond the windows' own noise (chi-squared, 3 dof, p = 1e-6), and by
    more than JUMP_TO_TYPICAL times the run's median step. The second test keeps a held pose's
    slow wobble (a hand's, a few mrad: significant against white noise, yet the pose is one
    pose, and its mean's noise is counted by block averaging) from cutting it: a tip between
    poses moves the mean by tens of times the steps of a hold. A window's variance is floored
    at a tenth of the run's median, so a quantised, nearly constant channel does not make one
    LSB a jump."""
    mu = x.mean(axis=1)
    var = x.var(axis=1, ddof=1)
    var = np.maximum(var, 0.1 * np.median(var, axis=0) + 1e-300)
    d = np.diff(mu, axis=0)
    step = np.sqrt(np.sum(d * d, axis=1))
    chi2 = np.sum(d * d / ((var[1:] + var[:-1]) / m), axis=1)
    jump: BoolArray = (chi2 > CHI2_3DOF_P1E6) & (step > JUMP_TO_TYPICAL * np.median(step))
    return jump


def _split_on_mean_change(rec: Recording, start: int, end: int, m: int) -> list[tuple[int, int]]:
    """[start, end) cut where the accel or gyro mean jumps between windows of m samples (see
    the module docstring); the two windows around each jump are dropped."""
    k = (end - start) // m
    if k < 3:
        return [(start, end)]
    used = k * m
    a = rec.accel[start : start + used].reshape(k, m, 3)
    g = rec.gyro[start : start + used].reshape(k, m, 3)
    jump = _mean_jumps(a, m) | _mean_jumps(g, m)
    if not jump.any():
        return [(start, end)]
    keep = np.ones(k, dtype=bool)
    keep[:-1] &= ~jump  # the window before a jump
    keep[1:] &= ~jump  # and the one after it
    pieces = []
    for w0, w1 in _runs(keep):
        a0 = start + w0 * m
        a1 = end if w1 == k else start + w1 * m
        pieces.append((a0, a1))
    return pieces


def find_still(
    rec: Recording, min_s: float = 2.0, activity: Activity | None = None
) -> list[StillInterval]:
    """Every still interval of at least `min_s` seconds, in time order (see module docstring)."""
    act = activity or Activity.of(rec)
    rails = None if rec.saturated is not None else _rails(rec)
    out = []
    period_s = 1.0 / rec.rate_hz if rec.rate_hz > 0 else 0.0
    last = act.still.shape[0]
    for j0, j1 in _runs(act.still):
        # trim a window at each end of what the still windows cover: motion's onset and its
        # settling lie below the thresholds; not at the recording's own ends (nothing to trim)
        start, end = act.covered(j0, j1, rec.n)
        start = start + act.window if j0 > 0 else 0
        end = end - act.window if j1 < last else rec.n
        if end - start < 2 or (end - start) * period_s < min_s:
            continue
        for a, b in _split_on_mean_change(rec, start, end, act.window):
            # a mean's noise needs a few samples to estimate at all (a 1 Hz recording's 2 s)
            if b - a >= MIN_WINDOW and (b - a) * period_s >= min_s:
                out.append(interval_stats(rec, a, b, rails))
    return out


def check_still(rec: Recording, significance: float = 0.01) -> StillCheck:
    """Is the whole recording still (as a gyro-bias capture must be)? Two tests:

    - motion: windows whose variance rises far above the recording's own noise floor;
    - a slow turn (invisible to a variance test): the accelerometer's direction at the start and
      at the end (first and last 10 %) must agree within their noise; a turn of angle theta over
      dt would otherwise sit in the gyro bias as theta / dt. A turn about the vertical cannot be
      seen this way: a gyro-bias capture must not be made on a turning table.

    The slow-turn test refuses a still recording with probability `significance`. The noise of a
    tenth's mean is taken from the whole recording at a twentieth's scale (block means, a linear
    drift removed): blocking within one tenth's few hundred samples picks too fine a level for a
    low-passed accelerometer and reads that noise ~30 % low, which refused still recordings two
    to three times as often as stated."""
    act = Activity.of(rec)
    spans = [act.covered(a, b, rec.n) for a, b in _runs(~act.still)]
    if spans:
        return StillCheck(
            False,
            tuple((_seconds(rec, a), _seconds(rec, b - 1)) for a, b in spans),
            f"the sensor moved at {_spans_text(rec, spans)} (variance far above the recording's "
            "own noise floor): record again without touching it, or cut the still part out",
        )
    if np.isnan(rec.accel).all():  # no accelerometer: a slow turn cannot be seen (docstring)
        return StillCheck(True, ())
    tenth = max(rec.n // 10, 2)
    m0 = np.einsum("nk->k", rec.accel[:tenth]) / tenth
    m1 = np.einsum("nk->k", rec.accel[-tenth:]) / tenth
    c, nu = _tenth_mean_cov(rec.accel, tenth)
    if nu <= 2:  # too few blocks to know the noise: nothing to test against
        return StillCheck(True, ())
    u = (m0 + m1) / np.linalg.norm(m0 + m1)
    # the direction change, in the plane perpendicular to gravity (rad), and its noise
    proj = np.eye(3) - np.outer(u, u)
    d = proj @ (m1 / np.linalg.norm(m1) - m0 / np.linalg.norm(m0))
    cov = proj @ (c / float(m0 @ m0) + c / float(m1 @ m1)) @ proj.T
    basis = np.linalg.svd(proj)[0][:, :2]
    d2 = basis.T @ d
    c2 = basis.T @ cov @ basis
    chi2 = float(d2 @ np.linalg.solve(c2, d2)) if np.linalg.det(c2) > 0 else math.inf
    # the noise is estimated with nu dof: Hotelling's T^2, not chi2
    if f_sf(chi2 * (nu - 1) / (2 * nu), 2, nu - 1) < significance:
        dt = _seconds(rec, rec.n - tenth // 2) - _seconds(rec, tenth // 2)
        angle = float(np.linalg.norm(d))
        _, gyro_cov = mean_and_cov(rec.gyro)
        gyro_se = float(np.sqrt(np.max(np.diag(gyro_cov))))
        if angle / max(dt, 1e-9) > gyro_se:
            t_end = _seconds(rec, rec.n - 1)
            return StillCheck(
                False,
                ((0.0, t_end),),
                f"the sensor turned slowly by {math.degrees(angle):.3f} deg over {dt:.0f} s "
                f"(gravity's direction moved {math.sqrt(chi2):.1f} times its noise), which would "
                f"put {angle / dt:.2e} rad/s into the gyro bias: put it on a firm, level support",
            )
    return StillCheck(True, ())


def _tenth_mean_cov(x: F64, tenth: int) -> tuple[F64, int]:
    """The covariance (k, k) of the mean of `tenth` consecutive samples of x (n, k), and the
    degrees of freedom it was estimated with: the scatter of block means half as long, over
    the whole recording, about a straight line (a slow turn is what the test looks for, so it
    must not count as noise). Correlations much shorter than the blocks (a low-pass filter's)
    are inside their means; slower noise (bias instability) is inside their scatter."""
    n, k = x.shape
    size = max(tenth // 2, 1)
    blocks = n // size
    y = np.einsum("bsk->bk", x[: blocks * size].reshape(blocks, size, k)) / size
    t = np.arange(blocks) - (blocks - 1) / 2
    r = y - np.einsum("bk->k", y) / blocks
    r = r - np.outer(t, (t @ r) / max(float(t @ t), 1e-300))
    nu = blocks - 2
    return (r.T @ r) / max(nu, 1) * size / tenth, nu
