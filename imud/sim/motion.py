"""The simulated board's motion: its true orientation, angular rate and specific force.

Frames: body axes as REP-103 (x forward, y left, z up), world ENU; orientations are unit
quaternions (w, x, y, z), Hamilton product, rotating body vectors into the world. The sensor sits
at the centre of rotation, so the specific force is gravity's reaction alone, f = R(t)^T (0, 0, g):
no centripetal or tangential term (a board turned about its own centre; an offset lever arm r
would add w x (w x r) + dw/dt x r, which a calibration has to avoid anyway).

Three profiles (`imud.sim.settings`): still, a constant-rate tumble, and `poses` - the profile a
calibration runs against without a human: still poses joined by smooth rotations, then a sweep
through all directions for the magnetometer. Every profile is a pure function of time, so the
value at t does not depend on how a simulator chunks time.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from imud.rotations import quat_conj, quat_from_euler_zyx, quat_mul, quat_rotate, rotation_zyx
from imud.sim.settings import PosesMotion, StillMotion, TumbleMotion
from imud.units import STANDARD_GRAVITY as G

F64 = npt.NDArray[np.float64]


def _turn(axis: F64, angle: F64) -> F64:
    """Quaternions (N, 4) of rotations by `angle` (N,) about one unit `axis` (3,)."""
    half = 0.5 * angle
    out = np.empty((angle.shape[0], 4))
    out[:, 0] = np.cos(half)
    out[:, 1:] = np.sin(half)[:, None] * axis
    return out


# --- time profiles ------------------------------------------------------------------------------
def min_jerk(x: F64) -> tuple[F64, F64]:
    """The minimum-jerk path 10x^3 - 15x^4 + 6x^5 from 0 to 1 and its slope, for x in [0, 1]:
    zero velocity and acceleration at both ends, as a hand moves (Flash & Hogan). Peak slope
    1.875, at x = 1/2."""
    x = np.clip(x, 0.0, 1.0)
    x2 = x * x
    return x2 * x * (10.0 - 15.0 * x + 6.0 * x2), 30.0 * x2 * (1.0 - x) ** 2


def plateau(u: F64, duration: float, ramp: float) -> tuple[F64, F64]:
    """A path from 0 to 1 over `duration` at constant speed, with smooth-step speed ramps of
    `ramp` at both ends (speed and acceleration continuous, zero at the ends): the same coverage
    as a minimum-jerk path with a peak rate 1/(1 - ramp/duration) of the mean, not 1.875x.
    Returns the position and its time derivative."""
    v = 1.0 / (duration - ramp)
    u = np.clip(u, 0.0, duration)
    head = np.clip(u / ramp, 0.0, 1.0)
    tail = np.clip((duration - u) / ramp, 0.0, 1.0)
    rise = v * ramp * head**3 * (1.0 - 0.5 * head)  # the integrals of the smooth-step speeds
    fall = 1.0 - v * ramp * tail**3 * (1.0 - 0.5 * tail)
    pos = np.where(u < ramp, rise, np.where(u > duration - ramp, fall, v * (u - 0.5 * ramp)))
    edge = np.minimum(head, tail)
    speed = v * edge * edge * (3.0 - 2.0 * edge)
    return pos, speed


# --- the poses profile ---------------------------------------------------------------------------
SWEEP_SPINS = 5  # whole spins about the spin axis per sweep part
SWEEP_RAMP = 0.1  # fraction of a sweep part spent speeding up, and again slowing down
# (spin axis, tilt axis) of the three sweep parts: z then x then y, each tilted about the next
SWEEP_AXES = ((2, 0), (0, 1), (1, 2))
_E = np.eye(3)
_UP = np.array([0.0, 0.0, G])


class StillSpan(NamedTuple):
    """A time span (s) over which the motion is exactly still, in the orientation of `pose` (an
    index into the profile's poses; 0 for a still motion)."""

    start_s: float
    end_s: float
    pose: int


class _Segment:
    """One piece of a profile: the rotation from its start orientation `q0` after u seconds and
    the body rate, both analytic."""

    still = False
    pose = -1

    def __init__(self, q0: F64, duration: float) -> None:
        self.q0 = q0
        self.f0 = quat_rotate(quat_conj(q0), _UP)
        self.duration = duration

    def at(self, u: F64) -> tuple[F64 | None, F64]:
        """Rotation since the start (N, 4), None when there is none, and body rate (N, 3)."""
        raise NotImplementedError

    def peak_rate(self) -> float:
        """The largest body rate on the segment, rad/s."""
        raise NotImplementedError


class _Hold(_Segment):
    still = True

    def __init__(self, q0: F64, duration: float, pose: int) -> None:
        super().__init__(q0, duration)
        self.pose = pose

    def at(self, u: F64) -> tuple[F64 | None, F64]:
        return None, np.zeros((u.shape[0], 3))

    def peak_rate(self) -> float:
        return 0.0


class _Move(_Segment):
    """The shortest rotation from q0 to q1 (plus `turns` whole turns about the same axis) on a
    minimum-jerk profile: a slerp, so the axis is fixed in the body and the body rate is the
    profile's slope times that axis. A move between equal orientations turns about body z."""

    def __init__(self, q0: F64, q1: F64, duration: float, turns: int) -> None:
        super().__init__(q0, duration)
        rel = quat_mul(quat_conj(q0), q1)
        if rel[0] < 0:
            rel = -rel
        s = float(np.linalg.norm(rel[1:]))
        self.axis = rel[1:] / s if s > 1e-12 else _E[2].copy()
        self.angle = 2.0 * math.atan2(s, float(rel[0])) + 2.0 * math.pi * turns
        self.still = self.angle == 0.0

    def at(self, u: F64) -> tuple[F64 | None, F64]:
        h, dh = min_jerk(u / self.duration)
        rate = (self.angle / self.duration) * dh
        return _turn(self.axis, self.angle * h), rate[:, None] * self.axis

    def peak_rate(self) -> float:
        return 1.875 * self.angle / self.duration


class _SweepPart(_Segment):
    """Spin about body axis s while the spin axis tilts once about a perpendicular axis t:
    P = Rt(beta) Rs(gamma), beta = 2 pi sigma, gamma = 2 pi k sigma, sigma on a `plateau`
    profile; it ends where it started. Body rate (P^T dP/dt) = beta' Rs(gamma)^T e_t +
    gamma' e_s, with Rs(gamma)^T e_t = cos(gamma) e_t - sin(gamma) (e_s x e_t).

    A field direction u (body, at the start) seen through the part traces circles about e_s at
    latitudes u . Rt(beta) e_s, which span [-r, r], r = sqrt(1 - (u . e_t)^2): everything but
    caps about +-e_s of radius asin|u . e_t|. Over the three parts (spin z tilt x, spin x tilt
    y, spin y tilt z) the missed caps are about z, x and y with radii asin|u_x|, asin|u_y|,
    asin|u_z|; two of them would only meet if u_x^2 + u_y^2 > 1 (and so on), so every direction
    is covered whatever the field and the start orientation."""

    def __init__(self, q0: F64, duration: float, spin: int, tilt: int) -> None:
        super().__init__(q0, duration)
        self.es, self.et = _E[spin], _E[tilt]
        self.ex = np.cross(self.es, self.et)
        self.ramp = SWEEP_RAMP * duration

    def at(self, u: F64) -> tuple[F64 | None, F64]:
        sigma, dsigma = plateau(u, self.duration, self.ramp)
        beta, gamma = 2.0 * math.pi * sigma, 2.0 * math.pi * SWEEP_SPINS * sigma
        q = quat_mul(_turn(self.et, beta), _turn(self.es, gamma))
        c, s = np.cos(gamma)[:, None], np.sin(gamma)[:, None]
        w = (2.0 * math.pi * dsigma)[:, None] * (c * self.et - s * self.ex + SWEEP_SPINS * self.es)
        return q, w

    def peak_rate(self) -> float:
        return 2.0 * math.pi * math.hypot(1.0, SWEEP_SPINS) / (self.duration - self.ramp)


class PosesProfile:
    """Still poses joined by rotations, then a sweep through all directions, then back to the
    first pose; repeated, or held there after one cycle.

    One cycle: hold pose 0, move to pose 1, hold pose 1, ..., hold the last pose, the sweep's
    three parts (each starting and ending in the last pose), the move back to pose 0. Every joint
    has zero rate, so the path is smooth (continuous rate and angular acceleration)."""

    def __init__(self, m: PosesMotion) -> None:
        qs = [quat_from_euler_zyx(*p) for p in m.poses]
        segs: list[_Segment] = []
        for i, q in enumerate(qs):
            segs.append(_Hold(q, m.hold_s, i))
            if i + 1 < len(qs):
                segs.append(_Move(q, qs[i + 1], m.move_s, m.turns_between))
        if m.sweep_s > 0:
            segs += [_SweepPart(qs[-1], m.sweep_s / 3, s, t) for s, t in SWEEP_AXES]
        segs.append(_Move(qs[-1], qs[0], m.move_s, m.turns_between))
        self.period_s = float(sum(s.duration for s in segs))
        self.repeat = m.repeat
        self.peak_rate_dps = math.degrees(max(s.peak_rate() for s in segs))
        if not self.repeat:
            segs.append(_Hold(qs[0], math.inf, 0))
        self._segs = segs
        self._starts = np.cumsum([0.0] + [s.duration for s in segs[:-1]])

    def _locate(self, t_s: F64) -> tuple[F64, npt.NDArray[np.intp]]:
        """Time within the cycle and the segment index of each t."""
        tau = np.mod(t_s, self.period_s) if self.repeat else t_s
        idx = np.searchsorted(self._starts, tau, side="right") - 1
        return tau, np.clip(idx, 0, len(self._segs) - 1)

    def _evaluate(self, t_s: F64, want_q: bool) -> tuple[F64, F64]:
        """(orientation if want_q else specific force, body rate), one pass per segment the
        times touch."""
        n = t_s.shape[0]
        tau, idx = self._locate(t_s)
        first = np.empty((n, 4 if want_q else 3))
        w = np.empty((n, 3))
        for k in np.unique(idx):
            seg = self._segs[int(k)]
            sel = idx == k
            rel, w[sel] = seg.at(tau[sel] - self._starts[k])
            if want_q:
                first[sel] = seg.q0 if rel is None else quat_mul(seg.q0, rel)
            else:
                first[sel] = seg.f0 if rel is None else quat_rotate(quat_conj(rel), seg.f0)
        return first, w

    def sample(self, t_s: F64) -> tuple[F64, F64]:
        return self._evaluate(t_s, want_q=False)

    def orientation(self, t_s: F64) -> F64:
        return self._evaluate(t_s, want_q=True)[0]

    def still_spans(self, t_end_s: float) -> list[StillSpan]:
        """The still spans that start before `t_end_s` (clipped to it), adjacent ones merged."""
        spans: list[StillSpan] = []
        cycles = math.ceil(t_end_s / self.period_s) if self.repeat else 1
        for c in range(max(cycles, 0)):
            off = c * self.period_s
            for seg, start in zip(self._segs, self._starts, strict=True):
                a = off + float(start)
                if not seg.still or a >= t_end_s:
                    continue
                b = min(a + seg.duration, t_end_s)
                if spans and spans[-1].end_s == a:
                    spans[-1] = spans[-1]._replace(end_s=b)
                else:
                    spans.append(StillSpan(a, b, seg.pose))
        return spans


class MotionModel:
    """True specific force (m/s^2) and angular rate (rad/s) in the body frame at times t (s).

    World frame ENU: a body at rest feels +g along world up.
    """

    def __init__(self, motion: StillMotion | TumbleMotion | PosesMotion) -> None:
        self._poses: PosesProfile | None = None
        if isinstance(motion, PosesMotion):
            self._poses = PosesProfile(motion)
            roll, pitch, yaw = motion.poses[0]
            rate = np.zeros(3)
        else:
            roll, pitch, yaw = motion.roll_deg, motion.pitch_deg, motion.yaw_deg
            rate = np.radians(motion.rate_dps) if isinstance(motion, TumbleMotion) else np.zeros(3)
        # the cycle of a repeating poses profile, s; None for the other motions
        self.period_s = self._poses.period_s if self._poses and self._poses.repeat else None
        r0 = rotation_zyx(roll, pitch, yaw)
        self._f0 = r0.T @ np.array([0.0, 0.0, G])
        self._w = np.asarray(rate, dtype=np.float64)
        speed = float(np.linalg.norm(self._w))
        u = self._w / speed if speed else self._w
        self._uxv = np.cross(u, self._f0)  # Rodrigues terms, constant for a constant rate
        self._uuv = u * float(u @ self._f0)
        # the true orientation (body -> world), for chips that estimate it: R(t) = R0 exp(t [w]x)
        self._q0 = quat_from_euler_zyx(roll, pitch, yaw)
        self._u = u
        self._speed = speed

    def sample(self, t_s: F64) -> tuple[F64, F64]:
        if self._poses is not None:
            return self._poses.sample(t_s)
        n = t_s.shape[0]
        w = np.broadcast_to(self._w, (n, 3)).copy()
        speed = float(np.linalg.norm(self._w))
        if speed == 0.0:
            return np.broadcast_to(self._f0, (n, 3)).copy(), w
        # A world-fixed vector seen from a body turning at w rotates by -|w| t about w (Rodrigues)
        a = -speed * t_s[:, None]
        return self._f0 * np.cos(a) + self._uxv * np.sin(a) + self._uuv * (1 - np.cos(a)), w

    def orientation(self, t_s: F64) -> F64:
        """True orientation at times t: unit quaternions (w, x, y, z), body -> world (ENU),
        shape (N, 4); the same rotation `sample` applies to gravity. The sign may flip between
        the segments of a poses profile (q and -q are the same rotation)."""
        if self._poses is not None:
            return self._poses.orientation(t_s)
        n = t_s.shape[0]
        if self._speed == 0.0:
            return np.broadcast_to(self._q0, (n, 4)).copy()
        half = 0.5 * self._speed * t_s
        turn = np.empty((n, 4))
        turn[:, 0] = np.cos(half)
        turn[:, 1:] = self._u * np.sin(half)[:, None]
        return quat_mul(self._q0, turn)

    def still_spans(self, t_end_s: float) -> list[StillSpan]:
        """Where the motion is exactly still in [0, t_end_s]: for tests and ground truth."""
        if self._poses is not None:
            return self._poses.still_spans(t_end_s)
        return [] if self._speed else [StillSpan(0.0, t_end_s, 0)]
