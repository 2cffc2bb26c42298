"""The orientation filter's correction arithmetic: the interval's sums turned into rotation
sums, the covariance's propagation over an interval, gravity's measurement matrix and a gated
(Schmidt-capable) Kalman update, on the 8-state error covariance.

Each function runs a compiled kernel (`imud._kernels`, docs/performance.md "Compiled kernels")
when one was built, and otherwise its NumPy twin here, which is the reference: the two agree to
rounding (matrix products add in another order; tests/test_compiled.py). The corrections come
about ten times a second, and paced, as the daemon runs them, the fixed cost of their few
dozen NumPy calls on 8 x 8 matrices was most of the orientation stage's cost a sample.

The covariance `p` (float64, C order, 8 x 8), the bias and the linear acceleration are updated
in place, by the kernel and the twin alike, and small vectors go in and out as tuples of
floats: paced, each NumPy call left in a correction costs microseconds of cold caches.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from imud.compiled import load
from imud.rotations import quat_mul_floats

F64 = npt.NDArray[np.float64]
_kernels = load("imud._kernels")

N_STATES = 8  # world rotation error 3, gyro bias 3, horizontal linear acceleration 2
_I2 = np.eye(2)
_I8 = np.eye(N_STATES)


class Learn(IntEnum):
    """What an update may teach beyond the states it measures directly (the kernel's codes)."""

    ALL = 0
    HORIZONTAL = 1  # the bias's components across the body's vertical
    VERTICAL = 2  # the bias's component along the body's vertical
    NOTHING = 3
    # ALL if the innovation is inside `consistent` (its own 95 % region), else NOTHING: before
    # the linear acceleration's level is known, only what plainly agrees with the model
    IF_CONSISTENT = 4


def _rotation_form() -> F64:
    """C (9, 16): R(e).ravel() = C @ (e outer e).ravel() for a unit quaternion e, so sums of
    rotation matrices (and of rotated vectors) over a chunk are sums of e outer e."""
    c = np.zeros((3, 3, 4, 4))
    w, x, y, z = 0, 1, 2, 3

    def put(i: int, j: int, terms: list[tuple[float, int, int]]) -> None:
        for k, a, b in terms:
            c[i, j, a, b] += k / 2 if a != b else k
            if a != b:
                c[i, j, b, a] += k / 2

    put(0, 0, [(1, w, w), (1, x, x), (-1, y, y), (-1, z, z)])
    put(0, 1, [(2, x, y), (-2, w, z)])
    put(0, 2, [(2, x, z), (2, w, y)])
    put(1, 0, [(2, x, y), (2, w, z)])
    put(1, 1, [(1, w, w), (-1, x, x), (1, y, y), (-1, z, z)])
    put(1, 2, [(2, y, z), (-2, w, x)])
    put(2, 0, [(2, x, z), (-2, w, y)])
    put(2, 1, [(2, y, z), (2, w, x)])
    put(2, 2, [(1, w, w), (-1, x, x), (-1, y, y), (1, z, z)])
    return c.reshape(9, 16)


FORM = _rotation_form()
# (3, 48): sum_k R(e_k) v_k = FORM_V @ (sum_k (e_k outer e_k) outer v_k).ravel()
FORM_V = np.einsum("ijp->ipj", FORM.reshape(3, 3, 16)).reshape(3, 48)


def inverse(s: F64) -> F64 | None:
    """The inverse of a small symmetric positive matrix (closed form up to 2 x 2); None if
    singular."""
    if s.shape[0] == 1:
        v = float(s[0, 0])
        return None if not v > 0 else np.array([[1.0 / v]])
    if s.shape[0] == 2:
        (a, b), (c, d) = s.tolist()
        det = a * d - b * c
        if not det > 0:
            return None
        inv: F64 = np.array([[d, -b], [-c, a]]) / det
        return inv
    try:
        out: F64 = np.asarray(np.linalg.inv(s), dtype=np.float64)
    except np.linalg.LinAlgError:
        return None
    return out


def force_sums(qqa: F64, kqqa: F64) -> tuple[float, float, float, float, float, float]:
    """An interval's sums of world-frame specific force, plain then index-weighted (3 + 3), from
    its sums of (q outer q) outer a (16 x 3 each)."""
    if _kernels is not None:
        out: tuple[float, float, float, float, float, float] = _kernels.orient_sums(qqa, kqqa)
        return out
    x, y, z = (FORM_V @ qqa.ravel()).tolist()
    u, v, w = (FORM_V @ kqqa.ravel()).tolist()
    return x, y, z, u, v, w


def _turn(qq: F64, scale: float) -> F64:
    """scale x the rotation-matrix sum of an interval's q outer q sum (16): 3 x 3."""
    out: F64 = (FORM @ qq).reshape(3, 3) * scale
    return out


def propagate(
    p: F64, qq: F64, scale: float, rho: float, q_density: F64, t: float, linear_var: float, a: F64
) -> None:
    """`p` over an interval of `t` seconds, in place: d(dtheta)/dt = -R db, with the interval's
    mean rotation times t as `scale` x the rotation sum of `qq` (its sum of q outer q), white
    gyro noise and the bias's random walk (`q_density`, 8, per second), and the linear
    acceleration `a` (2, in place) decaying by `rho` toward its variance `linear_var`."""
    if _kernels is not None:
        _kernels.orient_propagate(p, qq, scale, rho, q_density, t, linear_var, a)
        return
    phi = _I8.copy()
    phi[:3, 3:6] = -_turn(qq, scale)
    phi[6, 6] = phi[7, 7] = rho
    q = q_density * t
    q[6] = q[7] = linear_var * (1.0 - rho * rho)
    p[:] = phi @ p @ phi.T + np.diag(q)
    a *= rho


def gravity_h(p: F64, qq: F64, scale: float, g: float, h: F64) -> float:
    """Gravity's measurement matrix into `h` (2 x 8): its horizontal components' response to
    the world-frame error (g times the cross product), to the bias through the rotation since
    the window's centre (`scale` x the rotation sum of `qq`) and to the linear acceleration;
    returns the trace of h p h^T."""
    if _kernels is not None:
        trace: float = _kernels.orient_gravity_h(p, qq, scale, g, h)
        return trace
    gm = np.array([[0.0, -g, 0.0], [g, 0.0, 0.0]])
    h[:] = np.hstack([gm, gm @ _turn(qq, scale), _I2])
    hph = h @ p @ h.T
    return float(hph[0, 0] + hph[1, 1])


def update(
    p: F64,
    h: F64,
    y: tuple[float, ...],
    r: tuple[float, ...],
    gate: float,
    learn: Learn,
    consistent: float,
    q: F64,
    keep_heading: bool,
    b: F64,
    a: F64,
) -> tuple[float, float, float, float] | None:
    """A Kalman update of `p` (in place) by innovation `y` (d floats) with measurement matrix
    `h` (d x 8) and diagonal noise `r` (d variances), gated by chi-squared `gate`. Accepted, the
    orientation `q` is turned by the world-frame correction e = exp(dtheta) (q = e x q,
    normalised), the bias's correction is added to `b` (3) and the linear acceleration's to `a`
    (2), all in place, and e is returned; rejected (or singular), nothing changes and it
    returns None. Below Learn.ALL the states it leaves out
    are considered, not estimated (a Schmidt update: their gain is zero and the covariance stays
    consistent); Learn.VERTICAL and HORIZONTAL split the bias along the body's vertical, from
    the orientation `q`; `keep_heading` gives the heading no gain either (with no magnetometer
    it would follow the tilt's errors through their correlation)."""
    if _kernels is not None:
        out: tuple[float, float, float, float] | None = _kernels.orient_update(
            p, h, y, r, gate, int(learn), consistent, q, keep_heading, b, a
        )
        return out
    yv, rm = np.array(y), np.diag(r)
    ph = p @ h.T
    s = h @ ph + rm
    s_inv = inverse(s)
    if s_inv is None:
        return None
    nis = float(yv @ s_inv @ yv)
    if not nis <= gate:
        return None
    k = ph @ s_inv
    if learn is Learn.IF_CONSISTENT:
        learn = Learn.ALL if nis <= consistent else Learn.NOTHING
    if learn is Learn.ALL:
        new = p - k @ ph.T
    else:
        if learn is Learn.NOTHING:
            k[3:6] = 0.0
        else:
            w, x, yq, z = q.tolist()
            up = np.array([2 * (x * z - w * yq), 2 * (yq * z + w * x), 1 - 2 * (x * x + yq * yq)])
            along = np.outer(up, up @ k[3:6])
            k[3:6] = along if learn is Learn.VERTICAL else k[3:6] - along
        if keep_heading:
            k[2] = 0.0
        ikh = _I8 - k @ h
        new = ikh @ p @ ikh.T + k @ rm @ k.T
    dx = k @ yv
    p[:] = 0.5 * (new + new.T)
    b += dx[3:6]
    a += dx[6:8]
    e = rotation_quat(*dx[:3].tolist())
    q[:] = turned(e, q.tolist())
    return e


def turned(e: tuple[float, ...], q: list[float]) -> tuple[float, float, float, float]:
    """e x q, normalised: the orientation q turned by the world-frame rotation e."""
    w, x, y, z = quat_mul_floats(e, q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


def rotation_quat(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """exp of the rotation vector (x, y, z): the unit quaternion turning by it."""
    th = math.sqrt(x * x + y * y + z * z)
    s = math.sin(0.5 * th) / th if th > 1e-12 else 0.5
    return math.cos(0.5 * th), x * s, y * s, z * s
