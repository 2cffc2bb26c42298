"""The orientation filter's correction arithmetic: the interval's sums turned into rotation
sums, the covariance's propagation over an interval, gravity's measurement matrix and a gated
(Schmidt-capable) Kalman update, on the 8-state error covariance.

Each function runs a compiled kernel (`imud._kernels`, docs/performance.md "Compiled kernels")
when one was built, and otherwise its NumPy twin here, which is the reference: the two agree to
rounding (matrix products add in another order; tests/test_compiled.py). The corrections come
about ten times a second, and paced, as the daemon runs them, the fixed cost of their few
dozen NumPy calls on 8 x 8 matrices was most of the orientation stage's cost a sample.

The covariance `p` is updated in place (float64, C order, 8 x 8), by the kernel and the twin
alike, so a caller never holds a stale one.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
import numpy.typing as npt

from imud.compiled import load

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


def interval_sums(qq: F64, qqa: F64, kqqa: F64) -> F64:
    """(15,): an interval's sum of rotation matrices (3 x 3, row-major) from its sum of q outer q
    (16), and its sums of rotated specific force, plain and index-weighted, from (q outer q)
    outer a (16 x 3 each)."""
    if _kernels is not None:
        out = np.empty(15)
        _kernels.orient_sums(qq, qqa, kqqa, out)
        return out
    return np.concatenate([FORM @ qq, FORM_V @ qqa.ravel(), FORM_V @ kqqa.ravel()])


def propagate(p: F64, turn: F64, rho: float, q_density: F64, t: float, linear_var: float) -> None:
    """`p` over an interval of `t` seconds, in place: d(dtheta)/dt = -R db, with `turn` the
    interval's mean rotation matrix times t (3 x 3, row-major, 9), white gyro noise and the
    bias's random walk (`q_density`, 8, per second), and the linear acceleration decaying by
    `rho` toward its variance `linear_var`."""
    if _kernels is not None:
        _kernels.orient_propagate(p, turn, rho, q_density, t, linear_var)
        return
    phi = _I8.copy()
    phi[:3, 3:6] = -turn.reshape(3, 3)
    phi[6, 6] = phi[7, 7] = rho
    q = q_density * t
    q[6] = q[7] = linear_var * (1.0 - rho * rho)
    p[:] = phi @ p @ phi.T + np.diag(q)


def gravity_h(p: F64, turn: F64, g: float, h: F64) -> float:
    """Gravity's measurement matrix into `h` (2 x 8): its horizontal components' response to
    the world-frame error (g times the cross product), to the bias through `turn` (the rotation
    since the window's centre, 3 x 3, 9) and to the linear acceleration; returns the trace of
    h p h^T."""
    if _kernels is not None:
        trace: float = _kernels.orient_gravity_h(p, turn, g, h)
        return trace
    gm = np.array([[0.0, -g, 0.0], [g, 0.0, 0.0]])
    h[:] = np.hstack([gm, gm @ turn.reshape(3, 3), _I2])
    hph = h @ p @ h.T
    return float(hph[0, 0] + hph[1, 1])


def update(
    p: F64,
    h: F64,
    y: F64,
    r: F64,
    gate: float,
    learn: Learn,
    consistent: float,
    up: F64 | None,
    keep_heading: bool,
    dx: F64,
) -> bool:
    """A Kalman update of `p` (in place) by innovation `y` (d) with measurement matrix `h`
    (d x 8) and noise `r` (d x d), gated by chi-squared `gate`; the state's correction into `dx`
    (8). False, with nothing changed, if rejected or singular. Below Learn.ALL the states it
    leaves out are considered, not estimated (a Schmidt update: their gain is zero and the
    covariance stays consistent); `up` is the body's vertical in the body frame for
    Learn.VERTICAL and HORIZONTAL; `keep_heading` gives the heading no gain either (with no
    magnetometer it would follow the tilt's errors through their correlation)."""
    if _kernels is not None:
        ok: bool = _kernels.orient_update(
            p, h, y, r, gate, int(learn), consistent, up, keep_heading, dx
        )
        return ok
    ph = p @ h.T
    s = h @ ph + r
    s_inv = inverse(s)
    if s_inv is None:
        return False
    nis = float(y @ s_inv @ y)
    if not nis <= gate:
        return False
    k = ph @ s_inv
    if learn is Learn.IF_CONSISTENT:
        learn = Learn.ALL if nis <= consistent else Learn.NOTHING
    if learn is Learn.ALL:
        new = p - k @ ph.T
    else:
        if learn is Learn.NOTHING:
            k[3:6] = 0.0
        else:
            assert up is not None
            along = np.outer(up, up @ k[3:6])
            k[3:6] = along if learn is Learn.VERTICAL else k[3:6] - along
        if keep_heading:
            k[2] = 0.0
        ikh = _I8 - k @ h
        new = ikh @ p @ ikh.T + k @ r @ k.T
    dx[:] = k @ y
    p[:] = 0.5 * (new + new.T)
    return True
